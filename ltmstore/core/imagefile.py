"""Image files that appear whole or not at all.

Every image the product writes (relit PNGs, GIF previews, surface maps) is encoded in memory,
written to a temporary file beside its place, flushed to disk and renamed over it. A full disk
or an unwritable folder leaves no file behind (not even an empty one) and raises one
:class:`~ltmstore.core.errors.LtmError`; no encoder is left holding an open file that complains
when the interpreter exits.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ltmstore.core.errors import LtmError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp", ".gif")


def check_image_path(path: str | os.PathLike) -> Path:
    """``path`` as a :class:`~pathlib.Path` whose suffix names an image format we write.

    Raises
    ------
    LtmError
        When the suffix is missing or not one of :data:`IMAGE_SUFFIXES`.
    """
    path = Path(path)
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        found = f"suffix {path.suffix!r}" if path.suffix else "no suffix"
        raise LtmError(f"output {str(path)!r} has {found}; expected an image file ending in "
                       f"{', '.join(IMAGE_SUFFIXES)}")
    return path


def encode_image(image: np.ndarray, suffix: str, **kwargs) -> bytes:
    """The bytes of ``image`` (``(y, x[, c])``, or ``(n, y, x[, c])`` frames for a GIF) in
    the format named by ``suffix``; ``kwargs`` go to the encoder (``duration``, ``loop``)."""
    import imageio.v3 as iio

    try:
        return iio.imwrite("<bytes>", np.asarray(image), extension=suffix.lower(), **kwargs)
    except (OSError, ValueError, TypeError) as exc:
        raise LtmError(f"cannot encode a {suffix} image of shape {np.shape(image)}: "
                       f"{' '.join(str(exc).split()) or type(exc).__name__}") from None


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, what: str = "image") -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder: written,
    flushed with ``fsync`` and renamed into place. On failure the temporary file is removed,
    ``path`` is left as it was and an :class:`LtmError` naming ``what`` is raised.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise LtmError(f"cannot write {what} {str(path)!r}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # as an ordinary new file, not mkstemp's 0600
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise LtmError(f"cannot write {what} {str(path)!r}: {exc.strerror or exc}") \
                from None
        raise
    return path


def write_image(path: str | os.PathLike, image: np.ndarray, *, what: str = "image",
                **kwargs) -> Path:
    """Encode ``image`` in the format of ``path``'s suffix and write it atomically
    (:func:`write_bytes_atomic`); ``kwargs`` go to the encoder.

    Returns
    -------
    Path
        ``path``.
    """
    path = check_image_path(path)
    return write_bytes_atomic(path, encode_image(image, path.suffix, **kwargs), what=what)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
