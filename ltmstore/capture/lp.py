"""Classic RTI captures: the ``.lp`` light file and the decoding of its photographs.

:mod:`ltmstore.stages.ingest_rti` turns what this module reads into a store.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import is_file, resolve_inside
from ltmstore.core.errors import LtmError

MAX_IMAGE_PIXELS = 100_000_000  # a declared image size above this is refused before decoding
MAX_LP_BYTES = 16 * 1024 * 1024  # a light file is a few kB; refuse anything this large


def read_lp(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Read an RTI light file.

    The first line holds the number of images ``N``; each of the next ``N`` non-blank lines an
    image file name (relative to the ``.lp`` file) and a direction ``lx ly lz`` towards the light.

    Parameters
    ----------
    path : str or PathLike
        The ``.lp`` file.

    Returns
    -------
    names : list of str
        Image file names as written in the file.
    directions : ndarray, shape (N, 3)
        Unit vectors (normalised), ``lz > 0``.

    Raises
    ------
    LtmError
        With a one-line message naming the line for a malformed file, a light at or below the
        horizon, or an image that is missing or outside the folder.
    """
    path = Path(path)
    lines = _lines(path)
    count = _count(path, lines[0][1] if lines else "")
    entries = lines[1:]
    if len(entries) != count:
        raise LtmError(f"{str(path)} declares {count} images but lists {len(entries)}")
    names, directions = [], []
    for number, text in entries:
        name, direction = _entry(path, number, text)
        image = resolve_inside(path.parent, name, f"{str(path)} line {number}: image")
        if not is_file(image):
            raise LtmError(f"{str(path)} line {number}: image {name!r} does not exist")
        names.append(name)
        directions.append(direction)
    directions = np.array(directions, dtype=np.float64)
    directions /= np.abs(directions).max(axis=1, keepdims=True)  # no overflow in the norm
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    flat = ~(directions[:, 2] > 0)  # lz so small beside lx, ly that it rounds to 0
    if flat.any():
        number, text = entries[int(np.argmax(flat))]
        raise LtmError(f"{str(path)} line {number}: {text!r} points at the horizon (lz is "
                       "negligible beside lx, ly); expected a light above the object")
    return names, directions


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
    if direction[2] <= 0:
        raise LtmError(f"{str(path)} line {number}: lz = {direction[2]!r} for {parts[0]!r}; "
                       "expected lz > 0 (a light above the object)")
    return parts[0], direction


def _declared_size(data: bytes, name: str) -> tuple[int, int]:
    """Width and height from the image header (Pillow reads the header only); (0, 0) when
    Pillow does not know the format (OpenCV then decides)."""
    import io
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as image:
                return image.size
    except Image.DecompressionBombError as exc:
        raise LtmError(f"image {name!r} declares too many pixels ({exc}); expected at most "
                       f"{MAX_IMAGE_PIXELS} pixels") from exc
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return 0, 0


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Decode one image file's bytes as (H, W, 3) uint8 RGB.

    The header's declared size is checked first (:data:`MAX_IMAGE_PIXELS`), so a corrupt or
    hostile header never makes the decoder allocate gigabytes.
    """
    width, height = _declared_size(data, name)
    if width * height > MAX_IMAGE_PIXELS:
        raise LtmError(f"image {name!r} declares {width} x {height} pixels; expected at most "
                       f"{MAX_IMAGE_PIXELS} pixels")
    try:
        bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    except cv2.error:  # empty data, or a header declaring more pixels than OpenCV accepts
        bgr = None
    if bgr is None:
        raise LtmError(f"image {name!r} cannot be decoded (expected a JPEG or PNG file)")
    return bgr[..., ::-1]
