"""The lights and colours an export fits: the one place that knows what a store's lattice means.

Every export format holds, per pixel, a function of the light *direction* (a unit vector from
the object towards the light; x = image right, y = image up, z towards the camera, the ``.lp``
convention). A near-light store (a handheld LED on a plane at height ``h``) is read at the
lattice cells' directions from the object centre, ``(r, s, h) / |(r, s, h)|``
(:meth:`ltmstore.solve.Geometry.directions`), so the export approximates the near light by one
direction per cell, the same for every pixel (as RTIViewer and the web viewers assume). A store
of far lights (a classic RTI capture: ``r, s`` are the direction's ``lx, ly``) is read at each
cell's direction :func:`~ltmstore.core.lights.disk_to_direction`, where its ``ltm`` was
evaluated.

The colours are read block by block straight from the Zarr arrays (whole shards, no Dask graph
over the small inner chunks): a 96 x 96 px store on a 32 x 32 lattice reads in under a second.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import zarr

from ltmstore.core.dims import (
    CHROMA,
    CHROMA_LTM,
    LIGHT_DIMS,
    LTM,
    Lattice,
    rgb_from_ycbcr,
)
from ltmstore.core.errors import LtmError
from ltmstore.core.factored import stored_or_derived
from ltmstore.core.lights import FAR, disk_to_direction, light_kind
from ltmstore.core.store import open_group, open_store
from ltmstore.solve import Geometry

if TYPE_CHECKING:
    import xarray as xr


@dataclass(frozen=True)
class LightSamples:
    """A store's linear RGB at each of its light directions, read on demand by rows.

    Attributes
    ----------
    directions : ndarray, shape (M, 3)
        Unit light directions, one per lattice cell in C order of ``(r, s)``.
    shape : tuple of int
        ``(height, width)`` in pixels.
    """

    directions: np.ndarray
    shape: tuple[int, int]
    luminance: zarr.Array
    chroma: tuple[zarr.Array, zarr.Array] | np.ndarray | None  # Cb, Cr LTMs, or ratios (y, x, 2)

    def rows(self, rows: slice, columns: slice = slice(None)) -> np.ndarray:
        """Linear RGB ``(rows, x, M, 3)`` of a block of pixels (NaN read as 0)."""
        y = np.nan_to_num(self.luminance[rows, columns], nan=0.0)
        y = y.reshape(*y.shape[:2], -1)
        if self.chroma is None:
            cb = cr = np.zeros_like(y)
        elif isinstance(self.chroma, np.ndarray):
            ratios = self.chroma[rows, columns]
            cb, cr = y * ratios[..., 0:1], y * ratios[..., 1:2]
        else:
            cb, cr = (np.nan_to_num(a[rows, columns], nan=0.0).reshape(y.shape)
                      for a in self.chroma)
        return np.stack(rgb_from_ycbcr(y, cb, cr), axis=-1).astype(np.float32)


def _directions(ds: xr.Dataset) -> np.ndarray:
    """Unit light direction of each lattice cell, ``(M, 3)`` in C order of ``(r, s)``."""
    if light_kind(ds.attrs.get("acquisition", {})) == FAR:
        lx, ly = np.meshgrid(*(ds[LTM][d].values for d in LIGHT_DIMS), indexing="ij")
        return disk_to_direction(lx.ravel(), ly.ravel())
    return _geometry(ds).directions()


def _geometry(ds: xr.Dataset) -> Geometry:
    """The lattice of the store's ``ltm`` and the plane height it was captured at."""
    plane = ds.attrs.get("acquisition", {}).get("plane")
    if not plane or "height" not in plane:
        raise LtmError("the store records no plane height (attrs acquisition.plane); "
                       "cannot place its lights")
    rc, sc = (ds[LTM][d].values for d in LIGHT_DIMS)
    bounds = tuple((float(c[0] - _half(c)), float(c[-1] + _half(c))) for c in (rc, sc))
    return Geometry(Lattice(bounds=bounds, shape=(len(rc), len(sc))), float(plane["height"]))


def _half(centres: np.ndarray) -> float:
    return float(centres[1] - centres[0]) / 2 if len(centres) > 1 else 0.5


def _chroma(ds: xr.Dataset, group: zarr.Group):
    if all(name in ds for name in CHROMA_LTM.values()):
        return (stored_or_derived(group, ds, CHROMA_LTM["cb"]),
                stored_or_derived(group, ds, CHROMA_LTM["cr"]))
    if CHROMA in ds:
        return np.asarray(ds[CHROMA].sel(channel=["cb", "cr"]).transpose("y", "x", "channel"))
    return None


def light_samples(store: str | os.PathLike) -> LightSamples:
    """Light directions and the linear RGB the store predicts at each of them.

    Parameters
    ----------
    store : path-like
        A reconstructed store.

    Returns
    -------
    LightSamples
        ``directions (M, 3)`` and ``rows(...)`` giving linear RGB ``(rows, x, M, 3)``.
    """
    ds = open_store(store)
    if LTM not in ds:
        raise LtmError("the store has no complete ltm; run `ltm reconstruct` first")
    if ds[LTM].dims != ("y", "x", *LIGHT_DIMS):
        raise LtmError(f"the store's ltm has dims {ds[LTM].dims}: export holds one view; "
                       "6D stores are not supported yet")
    group = open_group(store)
    return LightSamples(directions=_directions(ds),
                        shape=(ds.sizes["y"], ds.sizes["x"]),
                        luminance=stored_or_derived(group, ds, LTM),
                        chroma=_chroma(ds, group))
