"""The photographs of a classic RTI capture, decoded: 8- and 16-bit PNG, JPEG and TIFF, float
TIFF and raw photographs, with the transfer function their files declare.

The ``.lp`` directions (:mod:`ltmstore.capture.lp`) are given in the frame the photographs
were taken in, the camera sensor's: every photograph is read as its pixels are stored, and an
EXIF orientation tag (a phone or camera turned for portrait shots) is ignored, consistently for
every image, with one warning line naming the files that carry one
(:func:`warn_orientations`). Turning some of them would put their pixels, but not their light
directions, in another frame.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.lp import LpWarning
from ltmstore.core.errors import LtmError

MAX_IMAGE_PIXELS = 100_000_000  # a declared image size above this is refused before decoding
ORIENTATION_TAG = 0x0112  # EXIF Orientation; 1 (or absent) is upright as stored


class OrientationWarning(LpWarning):
    """Photographs carry an EXIF orientation tag, ignored: read as stored (one line)."""


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
    """Decode one image file's bytes as (H, W, 3) RGB: ``uint8``, ``uint16`` for a 16-bit
    image, ``float32`` for a floating-point one (a float TIFF, linear light by convention;
    negative values clipped to 0). A raw photograph (:func:`is_raw`: DNG and the cameras'
    raw formats) is developed by LibRaw (:func:`_decode_raw`) to 16-bit linear RGB.

    The header's declared size is checked first (:data:`MAX_IMAGE_PIXELS`), so a corrupt or
    hostile header never makes the decoder allocate gigabytes. The pixels are returned as
    stored: an EXIF orientation tag is ignored (see the module's note); the callers that read a
    whole capture say so once (:func:`warn_orientations`). Integer TIFFs, PNG and JPEG are
    decoded by OpenCV, floating-point TIFFs (which it reads only in part) by tifffile, both
    exactly; an alpha channel is dropped, grey is repeated in R, G and B.
    """
    if is_raw(data, name):
        return _decode_raw(data, name)
    tiff = _tiff_header(data) if is_tiff(data) else None
    width, height = tiff[:2] if tiff else _header(data, name)[:2]
    _check_pixels(name, width, height)
    rgb = _decode_float_tiff(data, name) if tiff and tiff[2] else _decode_opencv(data, name)
    return _checked_samples(rgb, name)


def _check_pixels(name: str, width: int, height: int) -> None:
    if width * height > MAX_IMAGE_PIXELS:
        raise LtmError(f"image {name!r} declares {width} x {height} pixels; expected at most "
                       f"{MAX_IMAGE_PIXELS} pixels")


# raw photographs, developed by LibRaw: by suffix, or a TIFF that carries DNGVersion
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf",
                ".orf", ".rw2", ".pef", ".srw", ".3fr", ".iiq", ".rwl", ".erf", ".kdc", ".mrw")
DNG_VERSION = 50706


def is_raw(data: bytes, name: str) -> bool:
    """Whether an image file is a raw photograph: its name's suffix is one of
    :data:`RAW_SUFFIXES`, or it is a TIFF carrying a ``DNGVersion`` tag."""
    if Path(name).suffix.lower() in RAW_SUFFIXES:
        return True
    header = _tiff_header(data) if is_tiff(data) else None
    return bool(header and header[4])


def _decode_raw(data: bytes, name: str) -> np.ndarray:
    """A raw photograph developed by LibRaw (rawpy) as (H, W, 3) ``uint16`` linear RGB (sRGB
    primaries): demosaiced, the camera's white balance as shot, no automatic brightening (the
    sensor's white level is 65535, so exposure is kept), no gamma, and no turning by its
    orientation flag (pixels as stored, as for every image)."""
    import io

    import rawpy

    try:
        with rawpy.imread(io.BytesIO(data)) as raw:
            _check_pixels(name, raw.sizes.width, raw.sizes.height)
            rgb = raw.postprocess(gamma=(1, 1), no_auto_bright=True, output_bps=16,
                                  use_camera_wb=True, user_flip=0)
    except LtmError:
        raise
    except Exception as exc:  # untrusted bytes: any failure of LibRaw is a bad file
        raise LtmError(f"image {name!r} cannot be decoded as a raw photograph (LibRaw): "
                       f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    return np.ascontiguousarray(rgb, dtype=np.uint16)


# Decoded as RGB where OpenCV can (4.11 on): a contiguous image, where BGR's flipped view made
# every later pass copy it first; a 12 MP JPEG decodes in half the time too.
_RGB = getattr(cv2, "IMREAD_COLOR_RGB", cv2.IMREAD_COLOR)


def _decode_opencv(data: bytes, name: str) -> np.ndarray:
    try:
        # 16-bit images keep 16 bits; pixels as stored, never turned by an EXIF orientation
        flags = _RGB | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:  # empty data, or a header declaring more pixels than OpenCV accepts
        image = None
    if image is None:
        raise LtmError(f"image {name!r} cannot be decoded (expected a JPEG, PNG or TIFF file)")
    return image if _RGB != cv2.IMREAD_COLOR else image[..., ::-1]


TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
TIFF_ICC = 34675  # the TIFF tag holding an ICC profile


def is_tiff(data: bytes) -> bool:
    """Whether ``data`` starts as a TIFF (or BigTIFF) file."""
    return data[:4] in TIFF_MAGIC


def _tiff_header(data: bytes) -> tuple[int, int, bool, bytes | None, bool] | None:
    """Width, height, whether its samples are floating point, its ICC profile, and whether it
    is a DNG, of a TIFF's first image (tifffile reads the header only); None where tifffile
    cannot."""
    import io

    import tifffile

    try:
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            page = tif.pages.first
            icc = page.tags.valueof(TIFF_ICC)
            return (int(page.imagewidth), int(page.imagelength), int(page.sampleformat) == 3,
                    bytes(icc) if icc is not None else None, DNG_VERSION in page.tags)
    except Exception:  # a probe of untrusted bytes: OpenCV then decides
        return None


def _decode_float_tiff(data: bytes, name: str) -> np.ndarray:
    """The first image of a floating-point TIFF as (H, W, 3) float32 RGB (tifffile)."""
    import io

    import tifffile

    try:
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            page = tif.pages.first
            pixels, axes = page.asarray(), page.axes
    except Exception as exc:  # untrusted bytes: any failure is a bad file
        raise LtmError(f"image {name!r} cannot be decoded as a float TIFF: "
                       f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    if pixels.ndim == 3 and axes.startswith("S"):  # planar: one plane per sample
        pixels = np.moveaxis(pixels, 0, -1)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3:
        raise LtmError(f"image {name!r} holds {pixels.ndim}-dimensional pixels ({axes}); "
                       "expected one grey or RGB image")
    return pixels[..., [0, 0, 0] if pixels.shape[2] < 3 else [0, 1, 2]]


def _checked_samples(rgb: np.ndarray, name: str) -> np.ndarray:
    """``rgb`` as ``uint8``, ``uint16`` or finite non-negative ``float32``; other integer
    depths refused, naming the image."""
    if rgb.dtype in (np.uint8, np.uint16):
        return rgb
    if not np.issubdtype(rgb.dtype, np.floating):
        raise LtmError(f"image {name!r} holds {rgb.dtype} samples; expected 8- or 16-bit "
                       "integers or floating point")
    rgb = rgb.astype(np.float32)
    if not np.isfinite(rgb).all():
        raise LtmError(f"image {name!r} holds NaN or infinite values; expected finite light")
    return np.maximum(rgb, 0, out=rgb)


DEPTH_NAMES = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit",
               np.dtype(np.float32): "float"}
CURVE_TOLERANCE = 0.01  # a tone curve this close (in linear light) to sRGB's or linear is it


def image_transfer(data: bytes, dtype: np.dtype, name: str = "") -> tuple[str | None, str]:
    """What an image file says of its transfer, and where that was read.

    Floating-point samples (``dtype``: the decoded image's) are linear light, and so is a raw
    photograph (:func:`is_raw` of ``data`` and its file ``name``). Else the file's
    marks: a PNG ``sRGB`` chunk; an ICC profile (PNG ``iCCP``, TIFF, JPEG) whose tone curve is
    within :data:`CURVE_TOLERANCE` of sRGB's or of the identity; a PNG ``gAMA`` chunk (1.0:
    linear; 0.45455, sRGB's approximation: sRGB).

    Returns
    -------
    transfer : str or None
        ``"srgb"``, ``"linear"``, or None where the file says nothing we can use.
    source : str
        What was read (``"PNG sRGB chunk"``, ``"ICC profile 'sRGB built-in'"``, ...) or why
        nothing was.
    """
    if np.issubdtype(dtype, np.floating):
        return "linear", "floating-point samples"
    if is_raw(data, name):
        return "linear", "a raw photograph, developed linear"
    info = _marks(data)
    if "srgb" in info:
        return "srgb", "PNG sRGB chunk"
    if info.get("icc_profile"):
        return _icc_transfer(bytes(info["icc_profile"]))
    if "gamma" in info:
        gamma = float(info["gamma"])
        return _curve_transfer(lambda x: x ** (1 / gamma) if gamma > 0 else x * np.nan,
                               f"PNG gAMA {gamma:g}")
    return None, "no sRGB, ICC or gAMA mark"


def _marks(data: bytes) -> dict:
    """The ``srgb``, ``gamma`` and ``icc_profile`` entries of Pillow's header info (a TIFF
    that Pillow cannot open: its ICC profile by tifffile)."""
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as image:
                return {k: v for k, v in image.info.items()
                        if k in ("srgb", "gamma", "icc_profile")}
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError,
            Image.DecompressionBombError):
        header = _tiff_header(data) if is_tiff(data) else None
        return {"icc_profile": header[3]} if header and header[3] else {}


def _curve_transfer(curve, source: str) -> tuple[str | None, str]:
    """``"linear"`` or ``"srgb"`` where ``curve`` (code value in ``[0, 1]`` to linear light)
    is within :data:`CURVE_TOLERANCE` of it, else None; ``source`` says what was read."""
    from ltmstore.core.transfer import srgb_to_linear

    x = np.linspace(0, 1, 256)
    try:
        with np.errstate(all="ignore"):
            y = np.broadcast_to(np.asarray(curve(x), dtype=np.float64), x.shape)
    except (ValueError, TypeError, IndexError, OverflowError, ZeroDivisionError):
        return None, f"{source}: an unreadable tone curve"
    for transfer, reference in (("linear", x), ("srgb", srgb_to_linear(x))):
        if np.all(np.abs(y - reference) < CURVE_TOLERANCE):
            return transfer, source
    return None, f"{source}: a tone curve neither sRGB nor linear"


def _icc_transfer(profile: bytes) -> tuple[str | None, str]:
    """The transfer of an ICC profile's red (or grey) tone curve (:func:`_curve_transfer`)."""
    name = _icc_name(profile)
    try:
        curve = _icc_curve(profile)
    except (ValueError, IndexError, struct.error):
        curve = None
    if curve is None:
        return None, f"ICC profile {name!r}: no tone curve read"
    return _curve_transfer(curve, f"ICC profile {name!r}")


def _icc_name(profile: bytes) -> str:
    import io

    from PIL import ImageCms

    try:
        return ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(profile))
                                              ).strip() or "unnamed"
    except (ImageCms.PyCMSError, OSError, ValueError, TypeError):
        return "unreadable"


def _icc_curve(profile: bytes):
    """The ``rTRC`` (or ``kTRC``) tone curve of an ICC profile as a function of code values
    in ``[0, 1]`` (``curv``: identity, gamma or table; ``para``: ICC's five functions), or
    None where it has none."""
    count = struct.unpack(">I", profile[128:132])[0]
    tags = {}
    for i in range(min(count, 100)):
        sig, offset, size = struct.unpack(">4sII", profile[132 + 12 * i:144 + 12 * i])
        tags[sig] = profile[offset:offset + size]
    tag = tags.get(b"rTRC", tags.get(b"kTRC"))
    if tag is None or len(tag) < 12:
        return None
    if tag[:4] == b"curv":
        n = struct.unpack(">I", tag[8:12])[0]
        if n == 0:
            return lambda x: x
        if n == 1:
            gamma = struct.unpack(">H", tag[12:14])[0] / 256
            return lambda x: x ** gamma
        table = np.frombuffer(tag[12:12 + 2 * n], dtype=">u2") / 65535
        return lambda x: np.interp(x, np.linspace(0, 1, len(table)), table)
    if tag[:4] == b"para":
        kind = struct.unpack(">H", tag[8:10])[0]
        size = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}.get(kind)
        if size is None:
            return None
        g, a, b, c, d, e, f = (list(struct.unpack(f">{size}i", tag[12:12 + 4 * size]))
                               + [0] * (7 - size))
        g, a, b, c, d, e, f = (v / 65536 for v in (g, a, b, c, d, e, f))
        return _parametric(kind, g, a, b, c, d, e, f)
    return None


def _parametric(kind: int, g: float, a: float, b: float, c: float, d: float, e: float,
                f: float):
    """ICC's parametric curve of function type ``kind`` (0 to 4)."""
    def power(x):
        return np.maximum(a * x + b, 0) ** g

    if kind == 0:
        return lambda x: x ** g
    if kind in (1, 2):
        low = -b / a if a else 0.0
        return lambda x: np.where(x >= low, power(x) + (c if kind == 2 else 0),
                                  c if kind == 2 else 0)
    return lambda x: np.where(x >= d, power(x) + (e if kind == 4 else 0),
                              c * x + (f if kind == 4 else 0))
