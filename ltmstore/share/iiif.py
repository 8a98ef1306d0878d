"""The IIIF Image API 3.0 grammar of ``ltm view``'s relit tiles: identifiers, parameters, info.json.

Each light is an image service (checked against the IIIF Image API 3.0 specification, its
compliance levels and its implementation notes' tile algorithm)::

    /iiif/{light}/info.json
    /iiif/{light}/{region}/{size}/{rotation}/{quality}.{format}
    /iiif/{light}                                  303: to its info.json

``{light}`` (the identifier) is ``R,S``, a light in the store's own coordinates as ``ltm relight
--light R,S`` takes it (a plane position for a near-light store; ``lx,ly`` inside the unit disk
for a far-light store), or ``LX,LY,LZ``, a direction as ``--direction`` takes it (normalised;
``lz > 0``), optionally followed by ``;ev=E`` (``E`` stops brighter than the capture's exposure,
as ``ltm relight --ev``; default 0) and, for a 6D store, ``;view=P,Q``. Examples:
``0.1,-0.05``, ``0.3,0.2,0.9;ev=1``. ``ev=auto`` is refused: its gain comes from the whole
image's brightest pixels, which one tile cannot know.

Supported (``profile: level0`` plus ``extraFeatures``): region ``full``, ``square``,
``x,y,w,h`` (cropped at the image's edge), ``pct:x,y,w,h``; size ``max``, ``w,``, ``,h``,
``w,h``, ``!w,h``, ``pct:n`` (never larger than the region: no ``^``); rotation ``0``; quality
``default``; format ``png`` or ``jpg``. A malformed or out-of-range value is a
:class:`~ltmstore.core.errors.LtmError` (400); a valid request for a feature not implemented
(upscaling, rotation, mirroring, another quality or format) an :class:`Unsupported` (501).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import AUTO, CAPTURE, check_exposure

PREFIX = "/iiif/"
CONTEXT = "http://iiif.io/api/image/3/context.json"
PROTOCOL = "http://iiif.io/api/image"
TILE = 256  # the tile side info.json advertises
FORMATS = {"png": "image/png", "jpg": "image/jpeg"}
OTHER_FORMATS = ("tif", "gif", "jp2", "pdf", "webp")  # valid in IIIF, not served here
OTHER_QUALITIES = ("color", "gray", "bitonal")
EXTRA_FEATURES = ["regionByPx", "regionByPct", "regionSquare", "sizeByW", "sizeByH",
                  "sizeByWh", "sizeByConfinedWh", "sizeByPct", "baseUriRedirect"]
_INT = r"(\d+)"
_NUM = r"(\d+(?:\.\d*)?|\.\d+)"


class Unsupported(LtmError):
    """A valid IIIF request for a feature this server does not implement (HTTP 501)."""


@dataclass(frozen=True)
class LightId:
    """A parsed identifier: ``light (r, s)`` or ``direction (lx, ly, lz)``, stops and view."""

    light: tuple[float, float] | None = None
    direction: tuple[float, float, float] | None = None
    ev: float = 0.0
    view: tuple[float, float] | None = None


@dataclass(frozen=True)
class TileRequest:
    """One image request: the light, the region ``(x, y, w, h)`` in full-image pixels (inside
    the image), the output ``size (w, h)`` and the format (``png`` or ``jpg``)."""

    light: LightId
    region: tuple[int, int, int, int]
    size: tuple[int, int]
    fmt: str


def finite_numbers(text: str, what: str, counts: tuple[int, ...]) -> tuple[float, ...]:
    """The comma-separated finite numbers of ``text``, as many as one of ``counts``.

    Raises
    ------
    LtmError
        Naming ``what`` and ``text`` when they are not numbers, not finite or not as many.
    """
    try:
        values = tuple(float(t) for t in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in counts or not all(math.isfinite(v) for v in values):
        many = " or ".join(map(str, counts))
        plural = "numbers separated by commas" if counts != (1,) else "number"
        raise LtmError(f"{what} {text!r} must be {many} finite {plural}")
    return values


def parse_light(text: str) -> LightId:
    """The light of an identifier ``R,S`` or ``LX,LY,LZ`` with ``;ev=E`` and ``;view=P,Q``.

    Raises
    ------
    LtmError
        A malformed identifier, an unknown option, ``ev`` out of range or ``auto``.
    """
    head, *options = text.split(";")
    values = finite_numbers(head, "light", (2, 3))
    ev, view = 0.0, None
    for option in options:
        key, _, value = option.partition("=")
        if key == "ev" and value == AUTO:
            raise LtmError("ev=auto scales by the whole image's brightest pixels, which a tile "
                           "cannot know; give stops (ev=E)")
        if key == "ev":
            ev = check_exposure(CAPTURE, finite_numbers(value, "ev", (1,))[0])[1]
        elif key == "view":
            view = finite_numbers(value, "view", (2,))
        else:
            raise LtmError(f"identifier option {option!r} is unknown; expected ev=E or view=P,Q")
    return LightId(light=values if len(values) == 2 else None,
                   direction=values if len(values) == 3 else None, ev=ev, view=view)


def parse_region(text: str, width: int, height: int) -> tuple[int, int, int, int]:
    """``(x, y, w, h)`` of a region parameter, cropped at the image's edge.

    Raises
    ------
    LtmError
        A malformed region, one of zero width or height, or one wholly outside the image.
    """
    if text == "full":
        return 0, 0, width, height
    if text == "square":
        side = min(width, height)
        return (width - side) // 2, (height - side) // 2, side, side
    pct = re.fullmatch(",".join([_NUM] * 4), text.removeprefix("pct:"))
    px = re.fullmatch(",".join([_INT] * 4), text)
    if text.startswith("pct:") and pct:
        fx, fy, fw, fh = (float(v) / 100 for v in pct.groups())
        x0, y0 = round(fx * width), round(fy * height)
        x, y, w, h = x0, y0, round((fx + fw) * width) - x0, round((fy + fh) * height) - y0
    elif px:
        x, y, w, h = (int(v) for v in px.groups())
    else:
        raise LtmError(f"region {text!r} must be full, square, x,y,w,h or pct:x,y,w,h")
    if w <= 0 or h <= 0 or x >= width or y >= height:
        raise LtmError(f"region {text!r} is empty or lies outside the {width} x {height} image")
    return x, y, min(w, width - x), min(h, height - y)


def parse_size(text: str, rw: int, rh: int) -> tuple[int, int]:
    """``(w, h)`` of a size parameter for a region of ``rw x rh`` pixels (never larger).

    Raises
    ------
    LtmError
        A malformed size, zero, or larger than the region.
    Unsupported
        Upscaling (``^``).
    """
    if text.startswith("^"):
        raise Unsupported(f"size {text!r}: upscaling (^) is not supported by this server")
    if text == "max":
        return rw, rh
    pct = re.fullmatch(r"pct:" + _NUM, text)
    confined = re.fullmatch(r"!" + _INT + "," + _INT, text)
    given = re.fullmatch(r"(\d*),(\d*)", text)
    if pct:
        scale = float(pct.group(1)) / 100
        w, h = round(rw * scale), round(rh * scale)
    elif confined:
        scale = min(int(confined.group(1)) / rw, int(confined.group(2)) / rh, 1.0)
        w, h = max(1, math.floor(rw * scale)), max(1, math.floor(rh * scale))
    elif given and any(given.groups()):
        w, h = (int(v) if v else None for v in given.groups())
        w = max(1, round(rw * h / rh)) if w is None else w
        h = max(1, round(rh * w / rw)) if h is None else h
    else:
        raise LtmError(f"size {text!r} must be max, w,, ,h, w,h, !w,h or pct:n")
    if w <= 0 or h <= 0 or w > rw or h > rh:
        raise LtmError(f"size {text!r} gives {w} x {h} px: must be at least 1 and at most the "
                       f"region's {rw} x {rh} px (no upscaling)")
    return w, h


def parse_rotation(text: str) -> None:
    """Accept rotation ``0``; a mirror or another angle is :class:`Unsupported`."""
    angle = re.fullmatch(r"(!?)" + _NUM, text)
    if not angle or float(angle.group(2)) > 360:
        raise LtmError(f"rotation {text!r} must be a number of degrees from 0 to 360")
    if angle.group(1) or float(angle.group(2)) % 360:
        raise Unsupported(f"rotation {text!r}: only 0 is supported by this server")


def parse_quality_format(text: str) -> str:
    """The format of ``{quality}.{format}``: ``png`` or ``jpg`` with quality ``default``."""
    quality, _, fmt = text.rpartition(".")
    if quality in OTHER_QUALITIES:
        raise Unsupported(f"quality {quality!r}: only default is supported by this server")
    if quality != "default" or fmt not in (*FORMATS, *OTHER_FORMATS):
        raise LtmError(f"{text!r} must be default.png or default.jpg")
    if fmt not in FORMATS:
        raise Unsupported(f"format {fmt!r}: only png and jpg are supported by this server")
    return fmt


def parse_request(params: list[str], width: int, height: int) -> TileRequest:
    """The image request ``[light, region, size, rotation, quality.format]``.

    Raises
    ------
    LtmError
        A malformed or out-of-range parameter (400).
    Unsupported
        A valid feature this server does not implement (501).
    """
    light, region, size, rotation, quality_format = params
    x, y, w, h = parse_region(region, width, height)
    out = parse_size(size, w, h)
    parse_rotation(rotation)
    return TileRequest(parse_light(light), (x, y, w, h), out, parse_quality_format(quality_format))


def scale_factors(width: int, height: int, tile: int = TILE) -> list[int]:
    """Powers of two from 1 until the image, reduced by the factor, fits in one tile."""
    factors = [1]
    while max(width, height) > tile * factors[-1]:
        factors.append(2 * factors[-1])
    return factors


def info(service_id: str, width: int, height: int, tile: int = TILE) -> dict:
    """The image information document (``info.json``) of one light's image service."""
    return {"@context": CONTEXT, "id": service_id, "type": "ImageService3",
            "protocol": PROTOCOL, "profile": "level0", "width": width, "height": height,
            "tiles": [{"width": tile, "height": tile,
                       "scaleFactors": scale_factors(width, height, tile)}],
            "extraFormats": ["png"], "extraFeatures": EXTRA_FEATURES}
