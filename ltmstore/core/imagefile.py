"""Image files that appear whole or not at all.

Every image the product writes (relit PNGs, GIF previews, surface maps) is encoded in memory,
written to a temporary file beside its place, flushed to disk and renamed over it. A full disk
or an unwritable folder leaves no file behind (not even an empty one) and raises one
:class:`~ltmstore.core.errors.LtmError`; no encoder is left holding an open file that complains
when the interpreter exits.

The depth of an image is its dtype: ``uint8`` (any format of :data:`IMAGE_SUFFIXES`),
``uint16`` (PNG or TIFF, exact) and ``float32`` (TIFF, exact; linear light by convention):
:data:`DEPTH_SUFFIXES`. OpenEXR is not written: this OpenCV build has no EXR encoder and
imageio's needs a system library, while a float TIFF holds the same float32 values.
"""

from __future__ import annotations

import os
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import FLOAT, TRANSFERS, check_depth

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp", ".gif")
TIFF_SUFFIXES = (".tif", ".tiff")
DEPTH_SUFFIXES = {8: IMAGE_SUFFIXES, 16: (".png", *TIFF_SUFFIXES), FLOAT: TIFF_SUFFIXES}
DEPTH_NAMES = {8: "8-bit", 16: "16-bit", FLOAT: "float32"}
# PNG chunks naming the transfer (written after IHDR; read back by ltmstore.capture.photographs)
PNG_GAMMA = {"srgb": 45455, "linear": 100000}  # gAMA: the encoding exponent times 100000


def check_image_path(path: str | os.PathLike, depth: int | str = 8) -> Path:
    """``path`` as a :class:`~pathlib.Path` whose suffix names an image format we write at
    ``depth`` (8, 16 or ``"float"``: :data:`DEPTH_SUFFIXES`).

    Raises
    ------
    LtmError
        When the suffix is missing or is not one of the formats that hold ``depth``.
    """
    path = Path(path)
    depth = check_depth(depth)
    suffixes = DEPTH_SUFFIXES[depth]
    if path.suffix.lower() not in suffixes:
        found = f"suffix {path.suffix!r}" if path.suffix else "no suffix"
        held = "" if depth == 8 else f" {DEPTH_NAMES[depth]} image"
        raise LtmError(f"output {str(path)!r} has {found}; expected a{held or 'n image'} file "
                       f"ending in {', '.join(suffixes)}")
    return path


def image_depth(image: np.ndarray) -> int | str:
    """The depth that ``image``'s dtype writes: 16 for ``uint16``, ``"float"`` for a floating
    dtype, else 8 (what the encoders take or refuse as before)."""
    dtype = np.asarray(image).dtype
    if dtype == np.uint16:
        return 16
    return FLOAT if np.issubdtype(dtype, np.floating) else 8


def encode_image(image: np.ndarray, suffix: str, *, transfer: str | None = None,
                 **kwargs) -> bytes:
    """The bytes of ``image`` (``(y, x[, c])``, or ``(n, y, x[, c])`` frames for a GIF) in
    the format named by ``suffix``; ``kwargs`` go to the encoder (``duration``, ``loop``).

    ``uint16`` colour PNGs are written by OpenCV (imageio's PNG writer holds 16 bits in grey
    only), ``uint16`` and ``float32`` TIFFs by tifffile (zlib), exactly. ``transfer`` (one of
    :data:`~ltmstore.core.transfer.TRANSFERS`) marks a PNG's transfer with its ``sRGB`` and
    ``gAMA`` chunks (linear: ``gAMA`` 1.0), which ``ltm ingest-rti`` reads back; default none
    (the bytes as before).
    """
    image = np.asarray(image)
    suffix = suffix.lower()
    try:
        if suffix in TIFF_SUFFIXES and image_depth(image) != 8 and not kwargs:
            data = _tiff_bytes(image)
        elif suffix == ".png" and image.dtype == np.uint16 and image.ndim == 3:
            data = _png16_bytes(image)
        else:
            import imageio.v3 as iio

            data = iio.imwrite("<bytes>", image, extension=suffix, **kwargs)
    except (OSError, ValueError, TypeError) as exc:
        raise LtmError(f"cannot encode a {suffix} image of shape {np.shape(image)}: "
                       f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    return data if transfer is None or suffix != ".png" else png_with_transfer(data, transfer)


def _tiff_bytes(image: np.ndarray) -> bytes:
    """A ``uint16`` or float TIFF (float stored as float32) of ``(y, x[, c])``, zlib."""
    import io

    import tifffile

    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise ValueError(f"expected (y, x), (y, x, 3) or (y, x, 4) pixels, not {image.shape}")
    if image.dtype != np.uint16:
        image = image.astype(np.float32)
    out = io.BytesIO()
    colour = image.ndim == 3 and image.shape[2] >= 3
    tifffile.imwrite(out, image, photometric="rgb" if colour else "minisblack",
                     extrasamples=("unassalpha",) if colour and image.shape[2] == 4 else None,
                     compression="zlib")
    return out.getvalue()


def _png16_bytes(image: np.ndarray) -> bytes:
    """A 16-bit colour PNG of ``(y, x, c)`` (c 1, 3 or 4; RGB order) by OpenCV."""
    import cv2

    if image.shape[2] not in (1, 3, 4):
        raise ValueError(f"expected 1, 3 or 4 channels, not {image.shape[2]}")
    order = {1: [0], 3: [2, 1, 0], 4: [2, 1, 0, 3]}[image.shape[2]]  # cv2 is BGR(A)
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[..., order]))
    if not ok:
        raise ValueError("OpenCV's PNG encoder refused it")
    return data.tobytes()


def png_with_transfer(data: bytes, transfer: str) -> bytes:
    """The PNG ``data`` with chunks naming ``transfer`` inserted after its header: ``sRGB``
    (perceptual) and ``gAMA`` 0.45455 for sRGB, ``gAMA`` 1.0 for linear (PNG's own marks,
    read by :func:`ltmstore.capture.photographs.image_transfer`)."""
    if transfer not in TRANSFERS:
        raise LtmError(f"transfer {transfer!r} is unknown; expected one of {', '.join(TRANSFERS)}")
    end = 8 + 8 + 13 + 4  # signature, IHDR length + type, its 13 bytes, CRC
    if data[12:16] != b"IHDR":
        raise LtmError("cannot mark the transfer of a PNG without its IHDR header first")
    chunks = _png_chunk(b"gAMA", struct.pack(">I", PNG_GAMMA[transfer]))
    if transfer == "srgb":
        chunks = _png_chunk(b"sRGB", b"\x00") + chunks
    return data[:end] + chunks + data[end:]


def _png_chunk(kind: bytes, payload: bytes) -> bytes:
    return (struct.pack(">I", len(payload)) + kind + payload
            + struct.pack(">I", zlib.crc32(kind + payload) & 0xFFFFFFFF))


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
                transfer: str | None = None, **kwargs) -> Path:
    """Encode ``image`` in the format of ``path``'s suffix and write it atomically
    (:func:`write_bytes_atomic`); ``kwargs`` go to the encoder.

    The suffix must hold the image's depth (:func:`image_depth`, :data:`DEPTH_SUFFIXES`):
    ``uint16`` to ``.png``, ``.tif``, ``.tiff``; ``float32`` to ``.tif``, ``.tiff``.
    ``transfer`` marks a PNG's transfer (:func:`encode_image`).

    Returns
    -------
    Path
        ``path``.
    """
    path = check_image_path(path, image_depth(image))
    return write_bytes_atomic(path, encode_image(image, path.suffix, transfer=transfer,
                                                 **kwargs), what=what)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
