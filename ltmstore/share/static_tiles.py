"""A relit image as static tiles: a folder any web server serves, in one of two layouts.

``iiif``: an IIIF Image API 3.0 level-0 service, ``info.json`` and one JPEG per tile at each
scale factor, named as the IIIF implementation notes' tile algorithm requests it (what
OpenSeadragon, Mirador and OpenLIME ask for a level-0 service)::

    info.json
    {x},{y},{w},{h}/{ws},{hs}/0/default.jpg
    full/{ws},{hs}/0/default.jpg       (and full/max at full size)

``{x},{y},{w},{h}`` the tile's region in full-image pixels (cropped at the image's edge), ``ws =
ceil(w / s)`` and ``hs = ceil(h / s)`` at scale factor ``s``; where one tile holds the whole
image, it is also written under ``full`` (the sizes ``info.json`` lists), as viewers ask for it.
Each tile is computed as ``ltm view`` computes the same request (:mod:`ltmstore.share.iiif`):
the linear relit region, area resampled, then encoded, so a tile on disk and the one served for
its URL are the same picture.

``deepzoom``: a Deep Zoom image as OpenSeadragon reads it (and OpenLIME's ``deepzoom1px``
layout), ``image.dzi`` and ``image_files/<level>/<x>_<y>.jpg``: levels ``0`` (1 x 1 px) to
``ceil(log2(max(W, H)))`` (the full image), level ``L`` of ``ceil(W / 2^k)`` by ``ceil(H /
2^k)`` pixels with ``k`` the levels above it, 256 px tiles overlapping by 1 px (the Deep Zoom
and libvips defaults; tile ``(x, y)`` as :func:`ltmstore.share.tiles.tile_span` cuts it). Each
level is the whole linear image area-averaged to its size, then encoded: the full level is
``ltm relight``'s 8-bit image, JPEG-compressed.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import xarray as xr

from ltmstore.core.transfer import CAPTURE, encode_images, exposure_gain
from ltmstore.share import iiif
from ltmstore.share.atomic import atomic_output
from ltmstore.share.relit_tiles import area_resample, encode_jpeg, region_values
from ltmstore.share.tiles import DZI, tile_span

LAYOUTS = ("iiif", "deepzoom")
DEFAULT_URL = "http://127.0.0.1:8000"  # `python -m http.server` in the folder's parent
DZI_NAME = "image"  # image.dzi and image_files/ in each folder
DZI_TILE = 256
DZI_OVERLAP = 1


def tiles(width: int, height: int, tile: int = iiif.TILE) -> Iterator[tuple[tuple, tuple]]:
    """Every tile of a level-0 service: ``((x, y, w, h), (ws, hs))``, region and size, for each
    scale factor of :func:`ltmstore.share.iiif.scale_factors`."""
    for s in iiif.scale_factors(width, height, tile):
        step = tile * s
        for y in range(0, height, step):
            for x in range(0, width, step):
                w, h = min(step, width - x), min(step, height - y)
                yield (x, y, w, h), (math.ceil(w / s), math.ceil(h / s))


def tile_paths(region: tuple[int, int, int, int], size: tuple[int, int],
               width: int, height: int) -> list[str]:
    """The tile's paths below the service, as viewers request it."""
    paths = [f"{','.join(map(str, region))}/{size[0]},{size[1]}/0/default.jpg"]
    if region == (0, 0, width, height):
        paths.append(f"full/{size[0]},{size[1]}/0/default.jpg")
        if size == (width, height):
            paths.append("full/max/0/default.jpg")
    return paths


def encoded(linear: np.ndarray, transfer: str, gain: float, ev: float) -> np.ndarray:
    """8-bit code values of ``linear`` times ``gain``, ``ev`` stops brighter than the
    capture's exposure."""
    if gain != 1.0:
        linear = linear * np.float32(gain)
    return encode_images(linear[None], transfer, exposure=CAPTURE, ev=ev)[0]


def write_service(linear: np.ndarray, out: str | os.PathLike, *, transfer: str,
                  service_id: str, gain: float = 1.0, ev: float = 0.0,
                  tile: int = iiif.TILE) -> dict:
    """Write ``linear`` (an image ``(y, x[, color])`` as :func:`ltmstore.relight` gives it) as
    a level-0 IIIF image service in the folder ``out``.

    Parameters
    ----------
    linear : numpy.ndarray
        Linear relit values.
    out : path-like
        An existing, empty folder.
    transfer : str
        The capture's transfer function (``srgb`` or ``linear``).
    service_id : str
        The URL the folder will be served at (``info.json``'s ``id``: viewers build the tiles'
        URLs from it).
    gain : float
        A factor on ``linear`` before encoding (``--exposure auto``'s); 1 at the capture's
        exposure.
    ev : float
        Stops brighter than the capture's exposure, as ``ltm relight --ev``.
    tile : int
        Tile side in pixels.

    Returns
    -------
    dict
        ``width``, ``height``, ``tiles`` (how many), ``scale_factors`` and ``id``.
    """
    out = Path(out)
    height, width = linear.shape[:2]
    info = iiif.info(service_id, width, height, tile)
    for key in ("extraFormats", "extraFeatures"):  # a folder answers only its own tiles
        del info[key]
    whole = [size for region, size in tiles(width, height, tile)
             if region == (0, 0, width, height)]
    info["sizes"] = [{"width": w, "height": h} for w, h in sorted(whole)]
    (out / "info.json").write_text(json.dumps(info, indent=1) + "\n")
    count = 0
    for (x, y, w, h), size in tiles(width, height, tile):
        values = area_resample(area_resample(linear[y:y + h, x:x + w], width=size[0]),
                               height=size[1])
        body = encode_jpeg(encoded(values, transfer, gain, ev))
        for name in tile_paths((x, y, w, h), size, width, height):
            (out / name).parent.mkdir(parents=True)
            (out / name).write_bytes(body)
        count += 1
    return {"width": width, "height": height, "tiles": count,
            "scale_factors": info["tiles"][0]["scaleFactors"], "id": service_id}


def dzi_levels(width: int, height: int) -> list[tuple[int, int]]:
    """``(width, height)`` of each Deep Zoom level, from level 0 (1 x 1 px) to the full image."""
    top = math.ceil(math.log2(max(width, height)))
    return [(math.ceil(width / 2 ** (top - level)), math.ceil(height / 2 ** (top - level)))
            for level in range(top + 1)]


def write_dzi(linear: np.ndarray, out: str | os.PathLike, *, transfer: str, gain: float = 1.0,
              ev: float = 0.0, tile: int = DZI_TILE, overlap: int = DZI_OVERLAP) -> dict:
    """Write ``linear`` (an image ``(y, x[, color])`` as :func:`ltmstore.relight` gives it) as
    a Deep Zoom image in the folder ``out``: ``image.dzi`` and ``image_files/``.

    Parameters as :func:`write_service`'s; ``tile`` and ``overlap`` in pixels.

    Returns
    -------
    dict
        ``width``, ``height``, ``levels`` and ``tiles`` (how many).
    """
    out = Path(out)
    height, width = linear.shape[:2]
    levels = dzi_levels(width, height)
    count = 0
    for level, (w, h) in enumerate(levels):
        code = encoded(area_resample(linear, width=w, height=h), transfer, gain, ev)
        folder = out / f"{DZI_NAME}_files" / str(level)
        folder.mkdir(parents=True)
        for y in range(math.ceil(h / tile)):
            rows = tile_span(y, h, tile, overlap)
            for x in range(math.ceil(w / tile)):
                body = encode_jpeg(code[rows, tile_span(x, w, tile, overlap)])
                (folder / f"{x}_{y}.jpg").write_bytes(body)
                count += 1
    (out / f"{DZI_NAME}.dzi").write_text(DZI.format(overlap=overlap, tile=tile, height=height,
                                                    width=width))
    return {"width": width, "height": height, "levels": len(levels), "tiles": count}


def write_folders(images: xr.DataArray, outputs: list[Path], *, layout: str, transfer: str,
                  exposure: str = CAPTURE, ev: float = 0.0, url: str = DEFAULT_URL,
                  overwrite: bool = False,
                  inputs: Iterable[str | os.PathLike] = ()) -> Iterator[tuple[Path, dict]]:
    """Each light's image of ``images`` (:func:`ltmstore.relight`'s, dims ``(light, y,
    x[, color])``) as tiles in its folder of ``outputs``, whole or not at all.

    ``layout``: one of :data:`LAYOUTS` (:func:`write_service` or :func:`write_dzi`);
    ``exposure`` and ``ev`` as ``ltm relight`` takes them (``auto``: one gain from every
    light's image, as its image files get); ``url``: where the folders' parent is served (each
    IIIF ``id`` is ``url/<folder name>``); ``overwrite`` and ``inputs`` as
    :func:`ltmstore.share.atomic.atomic_output` takes them. Yields each folder and its
    writer's summary.
    """
    whole = (0, 0, images.sizes["x"], images.sizes["y"])
    linear = [region_values(image.transpose("y", "x", ...), whole, whole[2:])  # in row bands
              for image in images]
    gain = exposure_gain(np.stack(linear), exposure) if exposure != CAPTURE else 1.0
    for out, values in zip(outputs, linear, strict=True):
        with atomic_output(out, overwrite=overwrite, folder=True, inputs=inputs) as tmp:
            if layout == "deepzoom":
                info = write_dzi(values, tmp, transfer=transfer, gain=gain, ev=ev)
            else:
                info = write_service(values, tmp, transfer=transfer, gain=gain, ev=ev,
                                     service_id=f"{url.rstrip('/')}/{Path(out).name}")
        yield Path(out), info
