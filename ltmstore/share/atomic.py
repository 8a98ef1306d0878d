"""Outputs that appear whole or not at all: written beside their place, then renamed."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from ltmstore.core import paths
from ltmstore.core.errors import LtmError


def check_output(out: str | os.PathLike, overwrite: bool,
                 inputs: Iterable[str | os.PathLike | None] = ()) -> Path:
    """``out`` as a path, refused when it is, lies in or holds one of ``inputs``
    (:func:`ltmstore.core.paths.check_output`), when it exists and ``overwrite`` is not given,
    or when its folder does not exist."""
    paths.check_output(out, inputs)
    out = Path(out)
    if out.exists() and not overwrite:
        raise LtmError(f"output {str(out)!r} already exists; pass --overwrite to replace it")
    if not out.parent.is_dir():
        raise LtmError(f"output folder {str(out.parent)!r} does not exist")
    return out


@contextlib.contextmanager
def atomic_output(out: str | os.PathLike, *, overwrite: bool = False, folder: bool = False,
                  inputs: Iterable[str | os.PathLike | None] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``out`` (a file, or a folder with ``folder=True``); on
    success it replaces ``out``, on failure it is removed and ``out`` is left as it was.
    ``out`` is refused as :func:`check_output` refuses it (``inputs`` are what the caller read)."""
    out = check_output(out, overwrite, inputs)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # a published folder, not mkdtemp's private 0700
    target = tmp if folder else tmp / out.name
    old = out.parent / f"{tmp.name}.old"
    try:
        yield target
        if out.exists():
            out.rename(old)
        target.rename(out)
    except BaseException:
        if old.exists() and not out.exists():
            old.rename(out)
        raise
    finally:
        for leftover in (tmp, old):
            if leftover.is_dir():
                shutil.rmtree(leftover, ignore_errors=True)
            elif leftover.exists():
                leftover.unlink()
