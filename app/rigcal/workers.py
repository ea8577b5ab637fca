"""Worker processes for detection and rendering.

Not fork: a forked worker inherits locks held by the parent's threads (OpenBLAS,
OpenCV) and was seen to hang. forkserver forks workers from a clean process that has
imported the working module once, so they start in milliseconds. Like any
multiprocessing code, a script that calls this needs `if __name__ == "__main__":`.
Ctrl-C and SIGTERM reach only the main process, which stops the pool in order.
"""

from __future__ import annotations

import contextlib
import signal


def pool_context(preload: str):
    """A multiprocessing context whose workers have `preload` (a module name) imported."""
    import multiprocessing as mp

    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload([preload])
        start_forkserver_deaf_to_ctrl_c()
        return ctx
    return mp.get_context("spawn")  # pragma: no cover - platforms without forkserver


def start_forkserver_deaf_to_ctrl_c() -> None:
    """Start this process's forkserver with SIGINT ignored, which it and every worker it
    forks keep. Ctrl-C signals the whole process group: the server or a worker still
    importing would print its own KeyboardInterrupt traceback, and a worker would die
    mid-task; this way only the main process sees it and stops the pool in order."""
    from multiprocessing import forkserver

    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: signals are not ours to change
        forkserver.ensure_running()
        return
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def interrupts_deferred():
    """Hold SIGINT and SIGTERM for the duration, then act on them as their handlers would
    have (KeyboardInterrupt, the CLI's Terminated, or the default action)."""
    caught: list[int] = []
    wanted = (signal.SIGINT, signal.SIGTERM)
    try:
        previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in wanted}
    except ValueError:  # not the main thread: signals are not ours to change
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            handler = previous[caught[0]]
            if callable(handler):
                handler(caught[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(caught[0])


@contextlib.contextmanager
def worker_pool(max_workers: int, preload: str, initializer, initargs: tuple):
    """A ProcessPoolExecutor of `preload` workers (pool_context), stopped in order.

    Submit inside `interrupts_deferred()`: a worker interrupted while it starts prints a
    traceback. On any exception, Ctrl-C included, queued work is cancelled and the pool is
    waited for before the exception goes on: workers finish their chunk and exit, where a
    process still starting when this one exits would find its queue's semaphore gone and
    print a traceback."""
    from concurrent.futures import ProcessPoolExecutor

    pool = None
    try:
        with interrupts_deferred():
            pool = ProcessPoolExecutor(max_workers=max_workers, mp_context=pool_context(preload),
                                       initializer=initializer, initargs=initargs)
        yield pool
    except BaseException:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
