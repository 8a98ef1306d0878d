"""Relit tiles: a region of a store relit at one light, scaled and encoded, reading only it.

:class:`RelitTiles` keeps, per light, the lazy image :func:`ltmstore.stages.relight.relight`
returns (the whole image's Dask graph, nothing read), and computes a request's region of it
alone: Dask reads only the stored chunks the region overlaps (of the light-major copy, the
pixel tiles, the factors or, for a far-light store, the frames and surface maps), so a tile
costs its chunks, not the image. The values are those of ``ltm relight`` at that light: the
same lazy image, cut, encoded by :func:`~ltmstore.core.transfer.encode_images` at the capture's
exposure ``ev`` stops brighter (per pixel, so a full-scale tile is the same region of the
whole image's PNG).

A reduced size is the region relit at full resolution and area-averaged in linear light (each
output pixel the mean of the source area it covers, fractions of pixels at its edges weighted by
their area), then encoded: its cost is the region's, not the output's. Regions are computed in
bands of whole row chunks of at most :data:`BAND_PIXELS` pixels, each averaged across before the
next, so memory follows the band and the output. Recent encoded tiles and lazy images are kept
(:data:`CACHED_TILES`, :data:`CACHED_LIGHTS`).
"""

from __future__ import annotations

import io
import threading
import warnings
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
import xarray as xr
from scipy import sparse

from ltmstore.core.transfer import CAPTURE, encode_images
from ltmstore.share.iiif import LightId, TileRequest
from ltmstore.stages.relight import LIGHT, relight

BAND_PIXELS = 1 << 20  # region pixels computed at once
CACHED_TILES = 128  # encoded tiles kept (each at most CACHED_TILE_BYTES)
CACHED_TILE_BYTES = 1 << 20
CACHED_LIGHTS = 8  # lazy relit images kept
JPEG_QUALITY = 90


def area_matrix(n_in: int, n_out: int) -> sparse.csr_matrix:
    """``(n_out, n_in)`` weights that area-average ``n_in`` samples into ``n_out`` (each row
    sums to 1; a source pixel split between two outputs shares its weight by area)."""
    rows, cols, weights = [], [], []
    step = n_in / n_out
    for i in range(n_out):
        start, stop = i * step, (i + 1) * step
        for j in range(int(np.floor(start)), min(int(np.ceil(stop)), n_in)):
            overlap = min(stop, j + 1) - max(start, j)
            if overlap > 0:
                rows.append(i)
                cols.append(j)
                weights.append(overlap / step)
    return sparse.csr_matrix((weights, (rows, cols)), shape=(n_out, n_in))


def area_resample(values: np.ndarray, width: int | None = None,
                  height: int | None = None) -> np.ndarray:
    """``values (h, w[, c])`` area-averaged to ``width`` columns and/or ``height`` rows
    (float32; an axis not given is kept)."""
    out = np.asarray(values)
    if (width in (None, out.shape[1])) and (height in (None, out.shape[0])):
        return out.astype(np.float32, copy=False)
    out = out.astype(np.float64)
    if width is not None and width != out.shape[1]:
        moved = np.moveaxis(out, 1, 0)
        out = np.moveaxis((area_matrix(out.shape[1], width) @ moved.reshape(
            moved.shape[0], -1)).reshape(width, *moved.shape[1:]), 0, 1)
    if height is not None and height != out.shape[0]:
        out = (area_matrix(out.shape[0], height) @ out.reshape(out.shape[0], -1)).reshape(
            height, *out.shape[1:])
    return out.astype(np.float32)


def row_bands(chunks: tuple[int, ...], start: int, stop: int,
              width: int, limit: int = BAND_PIXELS) -> list[slice]:
    """Bands of rows ``[start, stop)`` that end on row-chunk boundaries (``chunks``: the
    image's chunk heights) and hold at most ``limit`` pixels of ``width`` where a chunk
    allows (a chunk is never split: it would be read once per band)."""
    edges = np.concatenate([[0], np.cumsum(chunks)])
    cuts = [e for e in edges if start < e < stop]
    bands, first = [], start
    for cut, after in zip(cuts, [*cuts[1:], stop][:len(cuts)], strict=True):
        if (after - first) * width > limit:
            bands.append(slice(first, int(cut)))
            first = int(cut)
    return [*bands, slice(first, stop)]


class Superseded(Exception):
    """A computation given up between two bands: a newer request wants the result instead."""


def region_values(image: xr.DataArray, region: tuple[int, int, int, int],
                  size: tuple[int, int],
                  superseded: Callable[[], bool] | None = None) -> np.ndarray:
    """Linear values ``(h, w[, color])`` of ``region (x, y, w, h)`` of a lazy ``image (y,
    x[, color])`` at ``size (w, h)``: computed a band of rows at a time (:func:`row_bands`),
    reading the region's chunks only, and area-averaged. :class:`Superseded` is raised
    before a band where ``superseded()`` is true."""
    x, y, w, h = region
    chunks = image.chunks[0] if image.chunks else (image.sizes["y"],)
    parts = []
    for rows in row_bands(chunks, y, y + h, w):
        if superseded is not None and superseded():
            raise Superseded
        parts.append(area_resample(image.isel(y=rows, x=slice(x, x + w)).values, width=size[0]))
    return area_resample(np.concatenate(parts), height=size[1])


def encode_png(code: np.ndarray) -> bytes:
    """A PNG (compression level 1, as ``/relight``'s) of 8-bit code values."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(code)).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def encode_jpeg(code: np.ndarray) -> bytes:
    """A JPEG (quality :data:`JPEG_QUALITY`, no chroma subsampling) of 8-bit code values."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(code)).save(buf, format="JPEG", quality=JPEG_QUALITY,
                                                     subsampling=0)
    return buf.getvalue()


class RelitTiles:
    """Tiles of one open store, relit by light.

    Parameters
    ----------
    ds : xarray.Dataset
        The store as :func:`ltmstore.open_store` opens it (any Zarr store: a counting one
        measures the bytes a tile reads).
    transfer : str
        The capture's transfer function (``srgb`` or ``linear``).
    lock : threading.Lock, optional
        Held while computing (the viewer's: one render at a time).
    """

    def __init__(self, ds: xr.Dataset, transfer: str,
                 lock: threading.Lock | None = None) -> None:
        self.ds, self.transfer = ds, transfer
        self.height, self.width = int(ds.sizes["y"]), int(ds.sizes["x"])
        self._lock = lock or threading.Lock()
        self._images: OrderedDict = OrderedDict()
        self._tiles: OrderedDict = OrderedDict()

    def image(self, light: LightId) -> tuple[xr.DataArray, list[str]]:
        """The lazy linear image ``(y, x[, color])`` at ``light`` and the warnings relight
        raised (nothing read but the light's checks). Call with the lock held."""
        key = (light.light, light.direction, light.view)
        if key not in self._images:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                lights = None if light.light is None else [light.light]
                directions = None if light.direction is None else [light.direction]
                image = relight(self.ds, lights, directions=directions, view=light.view)
            notes = sorted({str(w.message) for w in caught})
            self._images[key] = (image.isel({LIGHT: 0}).transpose("y", "x", ...), notes)
            while len(self._images) > CACHED_LIGHTS:
                self._images.popitem(last=False)
        self._images.move_to_end(key)
        return self._images[key]

    def linear(self, light: LightId, region: tuple[int, int, int, int],
               size: tuple[int, int]) -> tuple[np.ndarray, list[str]]:
        """Linear values ``(h, w[, color])`` of ``region (x, y, w, h)`` at ``size (w, h)``,
        reading the region's chunks only, and relight's warnings."""
        with self._lock:
            image, notes = self.image(light)
            return region_values(image, region, size), notes

    def tile(self, request: TileRequest) -> tuple[bytes, list[str]]:
        """The encoded tile of ``request`` (PNG or JPEG) and relight's warnings."""
        key = request
        with self._lock:
            if key in self._tiles:
                self._tiles.move_to_end(key)
                return self._tiles[key]
        values, notes = self.linear(request.light, request.region, request.size)
        code = encode_images(values[None], self.transfer, exposure=CAPTURE,
                             ev=request.light.ev)[0]
        body = (encode_png if request.fmt == "png" else encode_jpeg)(code)
        if len(body) <= CACHED_TILE_BYTES:
            with self._lock:
                self._tiles[key] = (body, notes)
                while len(self._tiles) > CACHED_TILES:
                    self._tiles.popitem(last=False)
        return body, notes
