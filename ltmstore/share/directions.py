"""The lights and colours an export fits: the one place that knows what a store's lattice means.

Every export format holds, per pixel, a function of the light *direction* (a unit vector from
the object towards the light; x = image right, y = image up, z towards the camera, the ``.lp``
convention). A near-light store (a handheld LED on a plane at height ``h``) is read at the
lattice cells' directions from the object centre, ``(r, s, h) / |(r, s, h)|``
(:meth:`ltmstore.solve.Geometry.directions`), so the export approximates the near light by one
direction per cell, the same for every pixel (as RTIViewer and the web viewers assume). A store
of far lights (directions stored directly) changes only :func:`light_samples`.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ltmstore.core.dims import (
    CHROMA,
    CHROMA_LTM,
    COLOR,
    COLOR_CHANNELS,
    LIGHT_DIMS,
    LTM,
    Lattice,
    rgb_from_ycbcr,
)
from ltmstore.core.errors import LtmError
from ltmstore.solve import Geometry

CELL = "cell"


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


def _luminance_and_chroma(ds: xr.Dataset) -> tuple[xr.DataArray, xr.DataArray, xr.DataArray]:
    """Y, Cb, Cr LTMs ``(y, x, r, s)``: from a colour LTM, or from the stored chroma ratios."""
    y = ds[LTM]
    if all(name in ds for name in CHROMA_LTM.values()):
        return y, ds[CHROMA_LTM["cb"]], ds[CHROMA_LTM["cr"]]
    if CHROMA not in ds:
        return y, xr.zeros_like(y), xr.zeros_like(y)
    chroma = ds[CHROMA]
    return y, y * chroma.sel(channel="cb", drop=True), y * chroma.sel(channel="cr", drop=True)


def light_samples(ds: xr.Dataset) -> tuple[np.ndarray, xr.DataArray]:
    """Light directions and the linear RGB the store predicts at each of them.

    Parameters
    ----------
    ds : xarray.Dataset
        A reconstructed store (:func:`ltmstore.open_store`).

    Returns
    -------
    directions : ndarray, shape (M, 3)
        Unit light directions, one per lattice cell in C order of ``(r, s)``.
    values : xarray.DataArray
        Dims ``(y, x, cell, color)``, linear RGB, Dask-backed (nothing read yet).
    """
    if LTM not in ds:
        raise LtmError("the store has no complete ltm; run `ltm reconstruct` first")
    extra = [d for d in ds[LTM].dims if d not in ("y", "x", *LIGHT_DIMS)]
    if extra:
        raise LtmError(f"the store's ltm has view axes {extra}: export holds one view; "
                       "6D stores are not supported yet")
    directions = _geometry(ds).directions()
    rgb = xr.concat(rgb_from_ycbcr(*_luminance_and_chroma(ds)), dim=COLOR)
    rgb = rgb.assign_coords({COLOR: list(COLOR_CHANNELS)}).transpose("y", "x", *LIGHT_DIMS, COLOR)
    values = rgb.stack({CELL: LIGHT_DIMS}).transpose("y", "x", CELL, COLOR)
    return directions, values.drop_vars([CELL, *LIGHT_DIMS])
