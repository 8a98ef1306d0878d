"""One writer at a time: an advisory lock file holding its owner's pid and host.

The lock is :func:`fcntl.flock` on a file beside what it guards, at its resolved path (two names
of one store meet at one lock); the kernel releases it when its owner dies (even by SIGKILL), so
the lock of a dead process is simply taken over. The file records who holds it, for the second
writer's one-line error.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ltmstore.core.errors import LtmError


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of the store (or folder) at ``path``: a hidden file beside it.

    ``path`` is resolved first (symbolic links, ``..``, the working folder), so every name of
    one store (a link to it, a relative path) has the same lock file.
    """
    path = Path(os.path.realpath(path))
    return path.parent / f".{path.name}.lock"


@contextmanager
def locked(path: str | os.PathLike, *, what: str = "store",
           file: Path | None = None) -> Iterator[Path]:
    """Hold the write lock of ``path`` for the body; refuse at once when another process has it.

    Parameters
    ----------
    path : path-like
        What is guarded (a store, an archive root); the lock file is :func:`lock_path`.
    what : str
        How the error names ``path``.
    file : Path, optional
        The lock file (default :func:`lock_path`).

    Raises
    ------
    LtmError
        When another live process holds the lock (its pid and host are named), or the lock file
        cannot be created.
    """
    file = file or lock_path(path)
    fd = _acquire(file, path, what)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode())
        yield file
    finally:
        try:
            file.unlink()
        except OSError:
            pass
        os.close(fd)


def _acquire(file: Path, path: str | os.PathLike, what: str) -> int:
    while True:
        try:
            fd = os.open(file, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise LtmError(f"cannot lock {what} {str(path)!r}: {exc.strerror or exc} "
                           f"({str(file)!r})") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(fd)
            os.close(fd)
            raise LtmError(f"{what} {str(path)!r} is being written by {owner} (lock "
                           f"{str(file)!r}); wait for it to finish") from None
        if _same_file(fd, file):  # not unlinked by its previous owner meanwhile
            return fd
        os.close(fd)


def _same_file(fd: int, file: Path) -> bool:
    try:
        return os.fstat(fd).st_ino == file.stat().st_ino
    except FileNotFoundError:
        return False


def _owner(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0) or b"{}")
        return f"process {info['pid']} on host {info['host']}"
    except (OSError, ValueError, KeyError):
        return "another process"
