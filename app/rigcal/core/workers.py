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
import threading


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


# ----------------------------------------------------------------------------- a Dask cluster

# The token of the pool whose initializer last ran in this worker process: tasks of one
# pool carry the same token, so each worker process initialises once per pool, whenever it
# joined. The lock covers workers started with several threads (the README asks for
# `--nthreads 1`: the detectors are per process, as in the local pool).
_CLUSTER_INIT: str | None = None
_CLUSTER_LOCK = threading.Lock()


def _cluster_chunk(token: str, initializer, initargs: tuple, fn, items: list) -> list:
    global _CLUSTER_INIT
    with _CLUSTER_LOCK:
        if _CLUSTER_INIT != token:
            initializer(*initargs)
            _CLUSTER_INIT = token
    return [fn(x) for x in items]


class ClusterPool:
    """A Dask cluster's workers behind ProcessPoolExecutor.map's interface (results in
    order). What goes over the wire: `initargs` once per worker (scattered), then chunks
    of items (image paths and small task records) and their results (corner arrays); the
    functions themselves travel by reference, so every worker needs the same rigcal."""

    def __init__(self, client, initializer, initargs: tuple):
        import uuid

        self.client, self.initializer = client, initializer
        self.token = uuid.uuid4().hex
        [self.initargs] = client.scatter([initargs], broadcast=True)

    def map(self, fn, items, chunksize: int = 1):
        items = list(items)
        futures = [self.client.submit(_cluster_chunk, self.token, self.initializer, self.initargs, fn,
                                      items[i:i + chunksize], pure=False)
                   for i in range(0, len(items), chunksize)]
        return (r for f in futures for r in f.result())


def connect(scheduler: str):
    """A distributed.Client on `scheduler` (an address such as tcp://host:8786), or one
    InputError line saying what is missing."""
    from rigcal.errors import InputError

    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler: needs the 'distributed' package (pip install 'rigcal[dask]')") from None
    try:
        return Client(scheduler, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there "
                         f"({e.__class__.__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None


@contextlib.contextmanager
def pool(jobs: int, preload: str, initializer, initargs: tuple, scheduler: str | None = None):
    """worker_pool(jobs, ...) on this machine, or a ClusterPool on the Dask cluster at
    `scheduler`; either has .map(fn, items, chunksize) with results in order."""
    if scheduler is None:
        with worker_pool(jobs, preload, initializer, initargs) as ex:
            yield ex
        return
    client = connect(scheduler)
    try:
        yield ClusterPool(client, initializer, initargs)
    finally:
        client.close()
