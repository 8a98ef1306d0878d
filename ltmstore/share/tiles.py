"""Tiled pyramids of the web format's planes (``ltm export --format relight --layout
deepzoom``): a viewer reads the tiles of what is on the screen, not the whole image.

Layout (writer checked: Relight ``relightlab/zoom.cpp`` ``deepZoom`` + ``src/deepzoom.cpp``, run by
its ``RtiTask`` as ``deepZoom(output, output, 95, 0, 256)``; reader: OpenLIME
``LayoutTiles.initDeepzoom``/``initBoxes``/``tileCoords``, ``LayerRTI.imageUrl``):

* each ``plane_<j>.jpg`` becomes ``plane_<j>.dzi`` (XML: ``Format``, ``Overlap``, ``TileSize``,
  ``<Size Width Height>``) and ``plane_<j>_files/<level>/<x>_<y>.jpg``; the plane JPEGs
  themselves are removed, as Relight removes them; ``info.json`` is unchanged (Relight names no
  layout there: its viewers are told it or find ``plane_0.dzi``);
* levels are numbered as OpenLIME's ``deepzoom`` layout (pyvips' ``depth=onetile``) reads them:
  ``nlevels = ceil(log2(max(W, H) / tile)) + 1``, level ``nlevels - 1`` the full image, each
  level below half the one above, rounded down (OpenLIME's ``w >>>= 1``), level 0 within one
  tile;
* tile ``(x, y)`` of a level ``w x h`` holds columns ``max(0, x T - overlap)`` to ``min(w, (x +
  1) T + overlap)`` and likewise rows; ``ceil(w / T)`` by ``ceil(h / T)`` tiles;
* a level is the one above halved by the kernel ``1 3 3 1 / 8`` along each axis (rounded to
  bytes after each), centred between pixels ``2 i`` and ``2 i + 1``, where OpenLIME's
  ``tileCoords`` puts level pixel ``i``: Relight's ``DeepZoom`` uses ``1 4 6 4 1 / 16`` centred
  on pixel ``2 i + 1``, half a pixel of the level above off that place;
* tiles are JPEG at the planes' quality without chroma subsampling (each channel is a different
  coefficient). As in Relight, they are cut from the decoded plane JPEGs: with the default
  overlap 0 and a tile size that is a multiple of 8, the full level keeps the planes' 8 x 8
  block grid and decodes to within a level or so of them.

OpenLIME's ``LayerRTI`` cannot open IIIF planes (``imageUrl``: ``case 'iiif': throw
Error("Unimplemented")``, OpenLIME 1.2.6), so no IIIF layout is written.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from PIL import Image

from ltmstore.core.errors import LtmError

LAYOUTS = ("image", "deepzoom")
TILE_SIZE = 256  # Relight's and OpenLIME's
OVERLAP = 0  # Relight's RtiTask writes its RTI pyramids without overlap
KERNEL = (1, 3, 3, 1)  # the downsampling filter, sum 8, centred between pixels 2 i and 2 i + 1
DZI = ('<?xml version="1.0" encoding="UTF-8"?>\n'
       '<Image xmlns="http://schemas.microsoft.com/deepzoom/2008"\n'
       '  Format="jpg"\n  Overlap="{overlap}"\n  TileSize="{tile}">\n'
       '  <Size Height="{height}" Width="{width}"/>\n</Image>\n')


def check(layout: str, fmt: str, tile_size: int, overlap: int) -> None:
    """Refuse a layout, tile size or overlap the export cannot write."""
    if layout not in LAYOUTS:
        raise LtmError(f"--layout {layout!r} is unknown; expected one of {', '.join(LAYOUTS)}")
    if layout == "image":
        return
    if fmt != "relight":
        raise LtmError(f"--layout {layout} tiles the web format's planes; use it with --format "
                       "relight")
    if not 8 <= tile_size <= 4096:
        raise LtmError(f"--tile-size {tile_size!r} must be from 8 to 4096 pixels")
    if not 0 <= overlap < tile_size // 2:
        raise LtmError(f"overlap {overlap!r} must be from 0 to less than half a tile")


def level_count(width: int, height: int, tile_size: int) -> int:
    """Levels of the pyramid, as OpenLIME's ``initDeepzoom`` counts them (the same as V8's
    ``Math.ceil(Math.log(m / t) / Math.LN2) + 1`` for every side up to 70000 px and tiles of 8
    to 512 px, checked)."""
    return math.ceil(math.log2(max(width, height) / tile_size)) + 1


def _halve_axis(image: np.ndarray, axis: int) -> np.ndarray:
    """``image`` halved along ``axis``: pixel ``i`` the ``1 3 3 1`` mean of pixels ``2 i - 1`` to
    ``2 i + 2`` (edges clamped), rounded to bytes."""
    n = image.shape[axis]
    first = 2 * np.arange(max(1, n >> 1))
    acc = sum(weight * np.take(image, np.clip(first + k - 1, 0, n - 1), axis=axis)
              .astype(np.uint16) for k, weight in enumerate(KERNEL))
    return ((acc + 4) // 8).astype(np.uint8)


def halve(image: np.ndarray) -> np.ndarray:
    """The next level of a pyramid: ``(y, x, 3)`` bytes halved, rows and columns rounded down."""
    return _halve_axis(_halve_axis(image, 1), 0)


def tile_span(index: int, size: int, tile_size: int, overlap: int) -> slice:
    """The pixels of tile ``index`` along an axis of ``size`` pixels, with their overlap."""
    return slice(max(0, index * tile_size - overlap), min(size, (index + 1) * tile_size + overlap))


def write_pyramid(image: np.ndarray, base: str | os.PathLike, *, quality: int,
                  tile_size: int = TILE_SIZE, overlap: int = OVERLAP) -> int:
    """Write ``base.dzi`` and the tiles ``base_files/<level>/<x>_<y>.jpg`` of ``image`` ``(y, x,
    3)`` bytes; the number of tiles."""
    base = Path(base)
    height, width = image.shape[:2]
    levels = [image]
    for _ in range(level_count(width, height, tile_size) - 1):
        levels.append(halve(levels[-1]))
    count = 0
    for level, pixels in enumerate(levels[::-1]):
        folder = base.parent / f"{base.name}_files" / str(level)
        folder.mkdir(parents=True)
        h, w = pixels.shape[:2]
        for y in range(math.ceil(h / tile_size)):
            rows = tile_span(y, h, tile_size, overlap)
            for x in range(math.ceil(w / tile_size)):
                tile = pixels[rows, tile_span(x, w, tile_size, overlap)]
                Image.fromarray(np.ascontiguousarray(tile)).save(
                    folder / f"{x}_{y}.jpg", quality=int(quality), subsampling=0)
                count += 1
    base.with_suffix(".dzi").write_text(DZI.format(overlap=overlap, tile=tile_size,
                                                   height=height, width=width))
    return count


def tile_folder(folder: str | os.PathLike, *, quality: int, tile_size: int = TILE_SIZE,
                overlap: int = OVERLAP) -> dict:
    """Replace every ``plane_<j>.jpg`` of a web folder by its DeepZoom pyramid.

    Returns
    -------
    dict
        ``levels`` (per plane), ``tiles`` (all planes) and ``tile_size``, ``overlap``.
    """
    folder = Path(folder)
    tiles, levels = 0, 0
    for plane in sorted(folder.glob("plane_*.jpg")):
        with Image.open(plane) as im:
            pixels = np.asarray(im.convert("RGB"))
        tiles += write_pyramid(pixels, plane.with_suffix(""), quality=quality,
                               tile_size=tile_size, overlap=overlap)
        levels = level_count(pixels.shape[1], pixels.shape[0], tile_size)
        plane.unlink()
    return {"levels": levels, "tiles": tiles, "tile_size": tile_size, "overlap": overlap}


def check_size(width: int, height: int, tile_size: int) -> None:
    """Refuse an image too small for OpenLIME's count of levels (none below half a tile)."""
    if max(width, height) <= tile_size // 2:
        raise LtmError(f"--layout deepzoom needs an image larger than half a tile "
                       f"({tile_size // 2} px) on its longer side (OpenLIME reads no pyramid "
                       f"of fewer levels); this one is {width}x{height} px: use "
                       "--layout image or a smaller --tile-size")


def tile_planes(folder: str | os.PathLike, *, layout: str, quality: int,
                tile_size: int = TILE_SIZE, overlap: int = OVERLAP) -> dict:
    """Lay out a web folder's planes as ``layout`` says: ``image`` leaves them as they are,
    ``deepzoom`` replaces each by its pyramid (:func:`tile_folder`).

    Returns
    -------
    dict
        ``layout`` and, tiled, :func:`tile_folder`'s report.
    """
    if layout == "image":
        return {"layout": layout}
    return {"layout": layout, **tile_folder(folder, quality=quality, tile_size=tile_size,
                                            overlap=overlap)}
