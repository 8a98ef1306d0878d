"""Classic RTI captures: the ``.lp`` light file (its photographs are decoded by
:mod:`ltmstore.capture.photographs`).

:mod:`ltmstore.stages.ingest_rti` turns what these modules read into a store.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from ltmstore.capture.acquisition import is_file, resolve_inside
from ltmstore.core.errors import LtmError, LtmWarning

MAX_LP_BYTES = 16 * 1024 * 1024  # a light file is a few kB; refuse anything this large


class LpWarning(LtmWarning):
    """A light file entry was skipped or its image found under another path (one line)."""


def hidden_lights(n: int, every: int) -> np.ndarray:
    """Which of ``n`` lights the ``every = k`` protocol hides: ``(n,)`` bool, true at lights
    ``k-1, 2k-1, ...``; :class:`LtmError` unless ``k`` is a whole number from 2 to ``n``."""
    if isinstance(every, bool) or int(every) != every or every < 2 or every > n:
        raise LtmError(f"--holdout-lights {every!r} must be a whole number from 2 to the "
                       f"number of lights ({n})")
    return np.arange(n) % int(every) == int(every) - 1


def read_lp(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Read an RTI light file.

    The first line holds the number of images ``N``; each of the next ``N`` non-blank lines an
    image file name (relative to the ``.lp`` file) and a direction ``lx ly lz`` towards the light.

    A light at or below the horizon (``lz <= 0``) is skipped with one :class:`LpWarning` for
    the whole file. An image path written on another machine (absolute, Windows backslashes,
    leaving the folder, RTIBuilder's ``assembly-files/`` beside ``jpeg-exports/``) is found by
    its file name inside the capture's folder tree (:func:`find_image`), with one warning.

    Parameters
    ----------
    path : str or PathLike
        The ``.lp`` file.

    Returns
    -------
    names : list of str
        Image paths relative to the ``.lp`` file's folder (as written when they resolve there).
    directions : ndarray, shape (N, 3)
        Unit vectors (normalised), ``lz > 0``.

    Raises
    ------
    LtmError
        With a one-line message naming the line for a malformed file, an image that cannot be
        found inside the capture's folder tree, or a file with no light above the horizon.
    """
    path = Path(path)
    lines = _lines(path)
    count = _count(path, lines[0][1] if lines else "")
    entries = lines[1:]
    if len(entries) != count:
        raise LtmError(f"{str(path)} declares {count} images but lists {len(entries)}")
    names, directions, below, moved = [], [], [], []
    for number, text in entries:
        name, direction = _entry(path, number, text)
        if not direction[2] > 0:
            below.append(f"line {number} (lz = {direction[2]:g})")
            continue
        image, by_name = find_image(path, name, number)
        names.append(os.path.relpath(image, path.parent.resolve()))
        directions.append(direction)
        moved += [name] if by_name else []
    directions = np.array(directions, dtype=np.float64).reshape(-1, 3)
    directions /= np.abs(directions).max(axis=1, keepdims=True)  # no overflow in the norm
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    flat = ~(directions[:, 2] > 0)  # lz so small beside lx, ly that it rounds to 0
    below += [f"'{names[i]}' (lz negligible)" for i in np.flatnonzero(flat)]
    if below:
        warnings.warn(f"{str(path)}: skipped {len(below)} light(s) at or below the horizon: "
                      f"{', '.join(below)}", LpWarning, stacklevel=2)
    if moved:
        warnings.warn(f"{str(path)}: {len(moved)} image path(s) written on another machine "
                      f"found by file name (first: {moved[0]!r})", LpWarning, stacklevel=2)
    keep = ~flat
    if not keep.any():
        raise LtmError(f"{str(path)} has no light above the horizon (every lz <= 0); expected "
                       "directions towards lights above the object")
    kept = [n for n, k in zip(names, keep, strict=True) if k]
    _refuse_repeated(path, kept)
    return kept, directions[keep]


def _refuse_repeated(path: Path, names: list[str]) -> None:
    """One photograph per light: an image that the file names for two lights or more is
    refused, naming it and how often it is named."""
    from collections import Counter

    name, times = next(iter(Counter(names).most_common(1)), ("", 0))
    if times > 1:
        raise LtmError(f"{str(path)} names the image {name!r} for {times} lights; expected one "
                       "photograph per light (each line its own image)")


IMAGE_FOLDERS = ("jpeg-exports", "jpg", "images", "img")


def find_image(lp: Path, name: str, number: int) -> tuple[Path, bool]:
    """The image ``name`` of line ``number`` and whether it was found by file name alone.

    As written when that resolves to a file inside the ``.lp`` file's folder; else the file
    name (after the last ``/`` or ``\\``) beside the ``.lp`` file, in one of its subfolders, or,
    for an ``.lp`` in RTIBuilder's ``assembly-files/``, in a sibling folder of it. Nothing outside
    that tree is read.
    """
    where = f"{str(lp)} line {number}: image"
    folder = lp.parent
    try:
        image = resolve_inside(folder, name, where)
        if is_file(image):
            return image, False
    except LtmError:
        pass
    base = name.replace("\\", "/").rstrip("/").split("/")[-1]
    if base in ("", ".", ".."):
        raise LtmError(f"{where} {name!r} names no file")
    root = folder.parent if folder.name.lower() == "assembly-files" else folder
    places = [folder, *(folder / sub for sub in IMAGE_FOLDERS),
              *(root / sub for sub in IMAGE_FOLDERS)]
    places += sorted(p for p in _subfolders(root) if p not in places)
    for place in places:
        image = place / base
        if is_file(image) and image.resolve().is_relative_to(root.resolve()):
            return image.resolve(), True
    raise LtmError(f"{where} {name!r} does not exist (nor {base!r} beside the .lp file or in "
                   "a sibling image folder)")


def _subfolders(root: Path) -> list[Path]:
    try:
        return [p for p in root.iterdir() if p.is_dir()]
    except OSError:
        return []


def _lines(path: Path) -> list[tuple[int, str]]:
    """Numbered non-blank lines, stripped."""
    try:
        if path.stat().st_size > MAX_LP_BYTES:
            raise LtmError(f"light file {str(path)!r} is {path.stat().st_size} bytes; expected "
                           f"a text file of at most {MAX_LP_BYTES} bytes")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise LtmError(f"light file {str(path)!r} cannot be read: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise LtmError(f"light file {str(path)!r} is not text: {exc.reason}") from exc
    return [(i, line.strip()) for i, line in enumerate(text.splitlines(), 1) if line.strip()]


def _count(path: Path, first: str) -> int:
    try:
        count = int(first)
    except ValueError:
        count = 0
    if count < 1:
        raise LtmError(f"{str(path)} line 1: {first!r} must be the number of images "
                       "(a positive integer)")
    return count


def _entry(path: Path, number: int, text: str) -> tuple[str, list[float]]:
    parts = text.rsplit(maxsplit=3)
    try:
        direction = [float(v) for v in parts[1:]]
    except ValueError:
        direction = []
    if len(direction) != 3 or not all(math.isfinite(v) for v in direction):
        raise LtmError(f"{str(path)} line {number}: {text!r} must be 'image lx ly lz' with "
                       "three finite numbers")
    return parts[0], direction
