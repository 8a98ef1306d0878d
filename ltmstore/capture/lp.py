"""Classic RTI captures: the ``.lp`` light file and the decoding of its photographs.

:mod:`ltmstore.stages.ingest_rti` turns what this module reads into a store.

The ``.lp`` directions are given in the frame the photographs were taken in, the camera
sensor's: every photograph is read as its pixels are stored, and an EXIF orientation tag (a
phone or camera turned for portrait shots) is ignored, consistently for every image, with one
warning line naming the files that carry one (:func:`warn_orientations`). Turning some of
them would put their pixels, but not their light directions, in another frame.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import is_file, resolve_inside
from ltmstore.core.errors import LtmError, LtmWarning

MAX_IMAGE_PIXELS = 100_000_000  # a declared image size above this is refused before decoding
MAX_LP_BYTES = 16 * 1024 * 1024  # a light file is a few kB; refuse anything this large


class LpWarning(LtmWarning):
    """A light file entry was skipped or its image found under another path (one line)."""


class OrientationWarning(LpWarning):
    """Photographs carry an EXIF orientation tag, ignored: read as stored (one line)."""


ORIENTATION_TAG = 0x0112  # EXIF Orientation; 1 (or absent) is upright as stored


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


def _header(data: bytes, name: str) -> tuple[int, int, int]:
    """Width, height and EXIF orientation from the image header (Pillow reads the header
    only); ``(0, 0, 1)`` when Pillow does not know the format (OpenCV then decides)."""
    import io
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as image:
                try:
                    orientation = int(image.getexif().get(ORIENTATION_TAG, 1))
                except (OSError, ValueError, TypeError, SyntaxError):  # a damaged EXIF block
                    orientation = 1
                return (*image.size, orientation)
    except Image.DecompressionBombError as exc:
        raise LtmError(f"image {name!r} declares too many pixels ({exc}); expected at most "
                       f"{MAX_IMAGE_PIXELS} pixels") from exc
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return 0, 0, 1


def image_orientation(data: bytes, name: str) -> int:
    """The EXIF orientation of one image file's bytes (1, upright, when it has none)."""
    return _header(data, name)[2]


def image_size(data: bytes, name: str) -> tuple[int, int]:
    """``(width, height)`` of one image file's bytes from its header (``(0, 0)`` where Pillow
    does not know the format)."""
    return _header(data, name)[:2]


def warn_orientations(tagged: dict[str, int], total: int) -> None:
    """One :class:`OrientationWarning` line for the images of ``tagged`` (name: EXIF
    orientation other than 1) among ``total`` images; nothing when it is empty."""
    if not tagged:
        return
    shown = ", ".join(f"{name!r} ({value})" for name, value in list(tagged.items())[:3])
    more = f" and {len(tagged) - 3} more" if len(tagged) > 3 else ""
    warnings.warn(f"{len(tagged)} of {total} image(s) carry an EXIF orientation tag, ignored: "
                  f"{shown}{more}; every image is read as stored, in the camera's frame that "
                  "the .lp directions are given in", OrientationWarning, stacklevel=2)


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Decode one image file's bytes as (H, W, 3) RGB: uint8, or uint16 for a 16-bit image.

    The header's declared size is checked first (:data:`MAX_IMAGE_PIXELS`), so a corrupt or
    hostile header never makes the decoder allocate gigabytes. The pixels are returned as
    stored: an EXIF orientation tag is ignored (see the module's note); the callers that read a
    whole capture say so once (:func:`warn_orientations`).
    """
    width, height, _ = _header(data, name)
    if width * height > MAX_IMAGE_PIXELS:
        raise LtmError(f"image {name!r} declares {width} x {height} pixels; expected at most "
                       f"{MAX_IMAGE_PIXELS} pixels")
    try:
        # 16-bit images keep 16 bits; pixels as stored, never turned by an EXIF orientation
        flags = cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
        bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:  # empty data, or a header declaring more pixels than OpenCV accepts
        bgr = None
    if bgr is None:
        raise LtmError(f"image {name!r} cannot be decoded (expected a JPEG or PNG file)")
    return bgr[..., ::-1]
