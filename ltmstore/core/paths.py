"""Outputs apart from inputs: the one rule every command that writes checks at its boundary.

A command never writes to a path that *is* one of its inputs, lies *inside* one (a file in the
acquisition folder, in the store it reads) or *holds* one (``--overwrite`` of the folder around
its input replaces the folder, the input and everything beside it). Paths are compared resolved
(``..``, the working folder and symbolic links, of the output's existing part too), and two
existing paths that are one file or folder under two names (a hard link, a bind mount) are the
same path.

Callers: :func:`ltmstore.core.store.new_store` (``inputs``), ``ingest``, ``ingest_rti``,
``export``, ``maps``, ``render_previews``, ``compare_stores`` (``maps_png``), ``track`` and
``track_painting``, ``share.atomic.check_output`` (``inputs``), and the CLI where only it knows
an input's path (``relight -o``, ``calibrate -o``, ``track -o``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from ltmstore.core.errors import LtmError

PathLike = str | os.PathLike


def check_output(output: PathLike, inputs: Iterable[PathLike | object], *,
                 what: str = "output") -> Path:
    """Refuse an ``output`` that would land on one of ``inputs``; return it resolved.

    Parameters
    ----------
    output : path-like
        What the command is about to write (a file, a folder or a store), existing or not.
    inputs : iterable of path-like or None
        What the command reads (files and folders); entries that are no path (``None`` for an
        option not given, an open store or dataset) are skipped.
    what : str
        How the message names ``output`` ("output", "store", ...).

    Returns
    -------
    Path
        ``output`` resolved (symbolic links followed).

    Raises
    ------
    LtmError
        When ``output`` is an input, lies inside one or holds one: one line naming both;
        nothing has been written.
    """
    out = Path(os.path.realpath(output))
    for given in inputs:
        if not isinstance(given, str | os.PathLike):
            continue
        source = Path(os.path.realpath(given))
        if out == source or _same_file(out, source):
            how = "is the input"
        elif source in out.parents:
            how = "lies inside the input"
        elif out in source.parents:
            how = "holds the input"
        else:
            continue
        shown = ("" if out == Path(os.path.abspath(output))
                 else f" (resolves to {str(out)!r})")
        raise LtmError(f"{what} {str(output)!r}{shown} {how} {str(given)!r}; nothing was "
                       "written (choose a path outside the inputs)")
    return out


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


SIMULATION_RECORDS = ("acquisition.json", "truth/raw.json")  # what says `ltm simulate` wrote it


def check_simulation_folder(folder: PathLike, overwrite: bool) -> None:
    """Refuse an output ``folder`` of ``ltm simulate`` that is a file, or is not empty and was
    not written by the simulator, or is one and ``overwrite`` is not given. Nothing is removed
    here.

    The simulator's folders are known by its own records (:data:`SIMULATION_RECORDS`): an
    ``acquisition.json`` with a ``simulation`` record, or the two-phone simulation's
    ``truth/raw.json``; a capture's folder has neither, and ``--overwrite`` never empties it.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise LtmError(f"output {str(folder)!r} exists and is not a folder")
    try:
        if not folder.is_dir() or not any(folder.iterdir()):
            return
    except OSError as exc:
        raise LtmError(f"output folder {str(folder)!r} cannot be read: {exc.strerror}") from exc
    if not (_simulated(folder / SIMULATION_RECORDS[0]) or (folder / SIMULATION_RECORDS[1])
            .is_file()):
        raise LtmError(f"folder {str(folder)!r} is not empty and is not an earlier ltm simulate "
                       "output (no acquisition.json with a 'simulation' record); --overwrite "
                       "replaces only a simulation's own files: choose a new or empty folder")
    if not overwrite:
        raise LtmError(f"output folder {str(folder)!r} is not empty; pass --overwrite to "
                       "replace an earlier simulation there")


def _simulated(acquisition: Path) -> bool:
    import json

    try:
        record = json.loads(acquisition.read_text())
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(record, dict) and isinstance(record.get("simulation"), dict)
