"""The one-line error for an :class:`OSError` that reaches the command line: the system refused
a read or a write (a full disk, a file too large, ``/proc``, a folder that cannot be written).

The line names the path the user gave where the failing path is one of the hidden temporary
names an atomic write uses beside it (``.out.ptm.x1y2z3``), and what the system said.
"""

from __future__ import annotations

import argparse
import errno
import os
from pathlib import Path


def os_error(exc: OSError, args: argparse.Namespace | None = None) -> str:
    """``exc`` as one line: ``cannot write 'OUT': No space left on device (ENOSPC)``.

    Parameters
    ----------
    exc : OSError
        The error, with or without a ``filename``.
    args : argparse.Namespace, optional
        The parsed command: a path among its values names the failing one (the output a
        temporary name was written for), or, where the error names no file, the output.
    """
    code = errno.errorcode.get(exc.errno or 0, "")
    why = f"{exc.strerror or str(exc) or type(exc).__name__}" + (f" ({code})" if code else "")
    given = _given_paths(args)
    name = _named(exc.filename, given) if exc.filename is not None else _output(args)
    if name is None:
        return f"the system refused a read or write: {why}"
    return f"cannot read or write {name!r}: {why}"


def _given_paths(args: argparse.Namespace | None) -> list[str]:
    if args is None:
        return []
    return [v for v in vars(args).values() if isinstance(v, str) and v]


def _named(filename, given: list[str]) -> str:
    """The user's path behind ``filename``: itself, or the path a hidden temporary name beside
    it (``.NAME.`` ...) stands for."""
    path = Path(os.fsdecode(filename))
    for value in given:
        out = Path(value)
        same_folder = os.path.abspath(path.parent) == os.path.abspath(out.parent)
        if same_folder and path.name.startswith(f".{out.name}."):
            return value
        if os.path.abspath(path.parent) == os.path.abspath(out) and out.name and \
                path.name.startswith("."):  # a temporary name inside an output folder
            return value
    return str(path)


def _output(args: argparse.Namespace | None) -> str | None:
    """The command's output path, where it has one."""
    for name in ("output", "out"):
        value = getattr(args, name, None)
        if isinstance(value, str) and value:
            return value
    return None
