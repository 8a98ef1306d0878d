"""One writer at a time: an advisory lock file holding its owner's pid and host.

The lock is :func:`fcntl.flock` on a file beside what it guards, at its resolved path (two names
of one store meet at one lock); the kernel releases it when its owner dies (even by SIGKILL), so
the lock of a dead process is simply taken over. The file records who holds it, for the second
writer's one-line error.

A reader that must see the store at rest (``ltm check``) holds the same lock shared
(:func:`reading`): any number of readers together, no writer meanwhile. Readers write nothing
in the file, so a writer refused by readers alone names no writer; the last reader out removes
the file, as a writer does.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ltmstore.core.errors import LtmError


class LockHeld(LtmError):
    """The lock is held by another process; ``owner`` names it (``process PID on host H``, or
    ``another process``)."""

    def __init__(self, message: str, owner: str) -> None:
        super().__init__(message)
        self.owner = owner


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
    fd = _acquire(file, path, what, fcntl.LOCK_EX)
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


@contextmanager
def reading(path: str | os.PathLike, *, what: str = "store") -> Iterator[Path | None]:
    """Hold the lock of ``path`` shared for the body: no writer can start meanwhile; refuse at
    once (:class:`LockHeld`) while a writer holds it.

    Where the lock file cannot be made (a read-only folder, where no writer of ours can make
    one either) the body runs unlocked and gets None; otherwise it gets the lock file.

    Raises
    ------
    LockHeld
        When another live process holds the write lock (its pid and host are named).
    """
    file = lock_path(path)
    try:
        fd = _acquire(file, path, what, fcntl.LOCK_SH)
    except LockHeld:
        raise
    except LtmError:  # the lock file cannot be made here: nobody writes through it
        fd = None
    if fd is None:
        yield None
        return
    try:
        _forget_dead_writer(fd)
        yield file
    finally:
        try:  # the last reader out (nobody else holds the lock) removes the file
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if _same_file(fd, file):
                file.unlink()
        except OSError:
            pass
        os.close(fd)


def _forget_dead_writer(fd: int) -> None:
    """Empty a lock file that a killed writer left naming itself (a reader holds it now, so
    that writer is gone), so that a writer refused by readers names nobody."""
    try:
        if os.fstat(fd).st_size:
            os.ftruncate(fd, 0)
    except OSError:  # opened read-only: left as it is
        pass


def _acquire(file: Path, path: str | os.PathLike, what: str, mode: int) -> int:
    flags = os.O_RDWR | os.O_CREAT
    patience = time.monotonic() + UNNAMED_WAIT_S
    while True:
        try:
            fd = os.open(file, flags, 0o644)
        except PermissionError as exc:  # a reader may lock an existing file it cannot write
            if mode == fcntl.LOCK_EX or flags == os.O_RDONLY:
                raise _cannot(file, path, what, exc) from exc
            flags = os.O_RDONLY
            continue
        except OSError as exc:
            raise _cannot(file, path, what, exc) from exc
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(fd)
            os.close(fd)
            if owner == NO_OWNER and time.monotonic() < patience:
                time.sleep(0.01)  # a writer about to name itself, a last reader leaving
                continue
            if owner == NO_OWNER and mode == fcntl.LOCK_EX:
                raise LockHeld(f"{what} {str(path)!r} is in use by another process (a writer, "
                               f"or ltm check reading it; lock {str(file)!r}); wait for it to "
                               "finish", owner) from None
            raise LockHeld(f"{what} {str(path)!r} is being written by {owner} (lock "
                           f"{str(file)!r}); wait for it to finish", owner) from None
        if _same_file(fd, file):  # not unlinked by its previous owner meanwhile
            return fd
        os.close(fd)


def _cannot(file: Path, path: str | os.PathLike, what: str, exc: OSError) -> LtmError:
    return LtmError(f"cannot lock {what} {str(path)!r}: {exc.strerror or exc} ({str(file)!r})")


NO_OWNER = "another process"  # a lock file that names nobody: readers, or a writer just starting
UNNAMED_WAIT_S = 1.0  # how long a lock held by nobody named is tried again before refusing


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
        return NO_OWNER
