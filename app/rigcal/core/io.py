"""Whole-or-nothing output: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Iterator

from rigcal.errors import OutputError


def output_target(path: str | Path) -> Path:
    """The file an output to `path` replaces: `path`, or through a symbolic link the file it
    names (the link stays a link). OutputError when that exists and is not a regular file: a
    rename over a device, pipe or folder would replace it (as root, /dev/stdout or /dev/full
    itself), and a stream cannot take a whole-or-nothing write."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError:
        st = None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a pipe" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
        raise OutputError(f"{path}: is {kind}; expected a file path (outputs are written whole to a temporary "
                          f"file and renamed into place, never streamed)")
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def _tmp_beside(path: Path, suffix: str = "") -> tuple[int, str]:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix + ".tmp", dir=path.parent)
    except OSError as e:
        raise OutputError(f"{path}: cannot write here ({e.strerror or e})") from None


def _default_file_mode() -> int:
    """What open() would give a new file: 0666 less the process umask."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write_files(items: list[tuple[str | Path, bytes]]) -> None:
    """Write one or several files as one: every temporary is written and synced first (where
    a full disk or a permission shows), and only then are they renamed into place, so a
    failure leaves none of them rather than some."""
    staged: list[tuple[str, Path]] = []
    path = None
    try:
        for path, data in items:
            path = output_target(path)
            fd, tmp = _tmp_beside(path)
            staged.append((tmp, path))
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, _default_file_mode())  # mkstemp makes 0600; outputs are meant to be shared
        for tmp, path in staged:
            os.replace(tmp, path)
    except OSError as e:
        _remove(staged)
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from None
    except BaseException:
        _remove(staged)
        raise


def _remove(staged: list[tuple[str, Path]]) -> None:
    for tmp, _ in staged:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    atomic_write_files([(path, data)])


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_files([(path, text.encode("utf-8"))])


def atomic_write_texts(items: list[tuple[str | Path, str]]) -> None:
    atomic_write_files([(p, t.encode("utf-8")) for p, t in items])


@contextlib.contextmanager
def atomic_dir(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Build a directory in a temporary sibling and move it into place at the end.

    On any exception (including KeyboardInterrupt) the temporary tree is removed and
    nothing appears at `path`. With force, an existing `path` is replaced."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a directory")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise OutputError(f"{path}: directory exists and is not empty (use --force to replace it)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except OSError as e:
        raise OutputError(f"{path}: cannot write here ({e.strerror or e})") from None
    try:
        yield tmp
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
