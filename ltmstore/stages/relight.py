"""Lazy relighting: ``y = T l`` on the chunked LTM.

A point light anywhere on the plane is a bilinear weight over the four nearest lattice cells,
so its image reads only the inner chunks that hold those cells. Any weight pattern over the
lattice (an area light, an environment) is a weighted sum over all cells. Results are lazy
Dask-backed :class:`xarray.DataArray` objects; nothing is read until they are computed.

A 6D LTM ``(y, x, r, s, p, q)`` is re-viewed the same way: a camera position ``(p, q)`` on the
view plane is a bilinear weight over the four nearest view cells, so a (light, view) query reads
the inner chunks of at most 16 cells per tile.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import xarray as xr

from ltmstore.core.dims import (
    CHROMA,
    CHROMA_LTM,
    COLOR,
    COLOR_CHANNELS,
    LTM,
    P,
    Plane,
    Q,
    rgb_from_ycbcr,
)
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.core.transfer import encode_images

LIGHT = "light"


class LightClampWarning(UserWarning):
    """A requested light lay outside the lattice and was moved to its nearest edge."""


def _bilinear(centres: np.ndarray, value: float) -> tuple[int, int, float]:
    """Indices ``i0, i1`` and weight of ``i1`` for linear interpolation between centres."""
    n = len(centres)
    if n == 1:
        return 0, 0, 0.0
    pos = (value - centres[0]) / (centres[1] - centres[0])
    pos = float(np.clip(pos, 0, n - 1))
    i0 = min(int(np.floor(pos)), n - 2)
    return i0, i0 + 1, pos - i0


def _cell_weights(a: tuple[str, np.ndarray, float],
                  b: tuple[str, np.ndarray, float]) -> list[tuple[dict, float]]:
    """Bilinear weights over two lattice axes, each ``(dim, centres, value)``:
    ``[({dim_a: i, dim_b: j}, w)]`` with zero weights left out."""
    (dim_a, ca, va), (dim_b, cb, vb) = a, b
    i0, i1, wa = _bilinear(ca, va)
    j0, j1, wb = _bilinear(cb, vb)
    cells = [((i0, j0), (1 - wa) * (1 - wb)), ((i1, j0), wa * (1 - wb)),
             ((i0, j1), (1 - wa) * wb), ((i1, j1), wa * wb)]
    return ([({dim_a: i, dim_b: j}, w) for (i, j), w in cells if w > 0]
            or [({dim_a: i0, dim_b: j0}, 1.0)])


def light_weights(ltm: xr.DataArray, light: tuple[float, float],
                  plane: Plane | None = None) -> list[tuple[dict, float]]:
    """Bilinear weights of a point light: a list of ``({r: i, s: j}, weight)``.

    A light outside the plane (or the lattice, when no plane is known) is clamped to the
    nearest edge with a :class:`LightClampWarning`.
    """
    r, s = (float(v) for v in light)
    rc, sc = ltm["r"].values, ltm["s"].values
    if plane is not None:
        outside = not bool(plane.contains(np.array(r), np.array(s)))
    else:
        outside = not (rc[0] <= r <= rc[-1] and sc[0] <= s <= sc[-1])
    if outside:
        warnings.warn(f"light ({r:g}, {s:g}) lies outside the lattice; clamped to its edge",
                      LightClampWarning, stacklevel=3)
    return _cell_weights(("r", rc, r), ("s", sc, s))


def view_weights(ltm: xr.DataArray, view: tuple[float, float],
                 bounds: dict | None = None) -> list[tuple[dict, float]]:
    """Bilinear weights of a camera position on the view lattice: ``[({p: i, q: j}, w)]``.

    A view outside the view plane (``bounds = {"p": [lo, hi], "q": [lo, hi]}``, or the lattice
    when not given) is clamped to the nearest edge with a :class:`LightClampWarning`.
    """
    p, q = (float(v) for v in view)
    pc, qc = ltm[P].values, ltm[Q].values
    (p0, p1), (q0, q1) = ((bounds[P], bounds[Q]) if bounds is not None
                          else ((pc[0], pc[-1]), (qc[0], qc[-1])))
    if not (p0 <= p <= p1 and q0 <= q <= q1):
        warnings.warn(f"view ({p:g}, {q:g}) lies outside the view lattice; clamped to its edge",
                      LightClampWarning, stacklevel=3)
    return _cell_weights((P, pc, p), (Q, qc, q))


def _views(ds: xr.Dataset, view, n: int) -> tuple[np.ndarray, list] | tuple[None, None]:
    """Camera positions ``(1 or n, 2)`` and their view weights; ``(None, None)`` for a 4D LTM."""
    ltm = ds[LTM]
    if P not in ltm.dims:
        if view is not None:
            raise LtmError(f"view {np.asarray(view).tolist()!r} given, but the store's ltm has no "
                           "view axes (p, q): it is a 4D LTM")
        return None, None
    bounds = ds.attrs.get("acquisition", {}).get("view_plane")
    if view is None:  # the centre of the view plane
        view = ([float(np.mean(bounds[P])), float(np.mean(bounds[Q]))] if bounds
                else [float(ltm[P].mean()), float(ltm[Q].mean())])
    views = np.atleast_2d(np.asarray(view, dtype=float))
    if views.shape[-1] != 2 or views.ndim != 2 or len(views) not in (1, n) or \
            not np.isfinite(views).all():
        raise LtmError(f"view {np.asarray(view).tolist()!r} must be one finite (p, q) pair or "
                       f"one per light ({n})")
    return views, [view_weights(ltm, v, bounds) for v in views]


def _point_image(ltm: xr.DataArray, weights: list[tuple[dict, float]]) -> xr.DataArray:
    terms = [ltm.isel(**cell, drop=True) * w for cell, w in weights]
    return sum(terms[1:], terms[0])


def _as_dataset(store) -> xr.Dataset:
    if isinstance(store, xr.Dataset):
        return store
    if isinstance(store, str | os.PathLike):
        return open_store(store)
    raise LtmError(f"store {store!r} must be a path or an xarray.Dataset")


def relight(store, lights, *, view=None, color: bool = True) -> xr.DataArray:
    """Relight (and, for a 6D LTM, re-view) the LTM of a store, lazily.

    Parameters
    ----------
    store : path-like or xarray.Dataset
        A reconstructed store (or the dataset :func:`ltmstore.open_store` returns).
    lights : array-like of shape (n, 2), or xarray.DataArray
        Point lights ``(r, s)`` anywhere on the plane; or a weight pattern over the lattice
        with dims ``(r, s)`` or ``(light, r, s)`` (area lights, environments).
    view : array-like of shape (2,) or (n, 2), optional
        6D LTMs only: camera position ``(p, q)`` on the view plane, one for all lights or one
        per light (a path where light and viewpoint both move); default the view plane's
        centre. Given for a 4D LTM it is an error.
    color : bool
        Return linear RGB (dim ``color``): from the colour LTM when the store has one
        (``ltm_cb``, ``ltm_cr``), else from the stored chroma ratios; else luminance only.

    Returns
    -------
    xarray.DataArray
        Dims ``(light, y, x[, color])``, linear light, Dask-backed (with coordinates
        ``view_p, view_q`` for a 6D LTM).
    """
    ds = _as_dataset(store)
    if LTM not in ds:
        raise LtmError("the store has no complete ltm; run `ltm reconstruct` first")
    if isinstance(lights, xr.DataArray):
        pattern = lights if LIGHT in lights.dims else lights.expand_dims(LIGHT)
        views, vweights = _views(ds, view, pattern.sizes[LIGHT])

        def apply(ltm: xr.DataArray) -> xr.DataArray:
            if views is None:
                return xr.dot(ltm, pattern, dim=["r", "s"])
            if len(views) == 1:
                return xr.dot(_point_image(ltm, vweights[0]), pattern, dim=["r", "s"])
            return xr.concat([xr.dot(_point_image(ltm, vw), pattern.isel({LIGHT: k}),
                                     dim=["r", "s"]) for k, vw in enumerate(vweights)],
                             dim=LIGHT)
    else:
        points = np.atleast_2d(np.asarray(lights, dtype=float))
        if points.shape[-1] != 2 or not np.isfinite(points).all():
            raise LtmError(f"lights {lights!r} must be finite (r, s) pairs")
        acq = ds.attrs.get("acquisition", {})
        plane = Plane.from_json(acq["plane"]) if "plane" in acq else None
        weights = [light_weights(ds[LTM], p, plane) for p in points]
        views, vweights = _views(ds, view, len(points))

        def apply(ltm: xr.DataArray) -> xr.DataArray:
            if views is None:
                image = xr.concat([_point_image(ltm, w) for w in weights], dim=LIGHT)
            else:
                at = [_point_image(ltm, vw) for vw in vweights]
                image = xr.concat([_point_image(at[k % len(at)], w)
                                   for k, w in enumerate(weights)], dim=LIGHT)
            return image.assign_coords({LIGHT: np.arange(len(points)),
                                        "light_r": (LIGHT, points[:, 0]),
                                        "light_s": (LIGHT, points[:, 1])})
    image = apply(ds[LTM]).transpose(LIGHT, "y", "x")
    if views is not None:
        n = image.sizes[LIGHT]
        image = image.assign_coords(view_p=(LIGHT, np.resize(views[:, 0], n)),
                                    view_q=(LIGHT, np.resize(views[:, 1], n)))
    if not color:
        return image
    if all(name in ds for name in CHROMA_LTM.values()):  # a colour LTM
        cb, cr = (apply(ds[CHROMA_LTM[c]]).transpose(LIGHT, "y", "x") for c in ("cb", "cr"))
        return _stack_rgb(image, cb, cr)
    return to_rgb(image, ds[CHROMA]) if CHROMA in ds else image


def to_rgb(luminance: xr.DataArray, chroma: xr.DataArray) -> xr.DataArray:
    """Linear RGB from luminance and chroma stored as ratios to luminance."""
    cb = luminance * chroma.sel(channel="cb", drop=True)
    cr = luminance * chroma.sel(channel="cr", drop=True)
    return _stack_rgb(luminance, cb, cr)


def _stack_rgb(y: xr.DataArray, cb: xr.DataArray, cr: xr.DataArray) -> xr.DataArray:
    rgb = xr.concat(rgb_from_ycbcr(y, cb, cr), dim=COLOR)
    return rgb.assign_coords({COLOR: list(COLOR_CHANNELS)}).transpose(..., COLOR)


def write_gif(store, path: str | os.PathLike, lights, views=None, *, fps: float = 12) -> str:
    """An animated GIF of the store relit along ``lights (n, 2)`` and, for a 6D LTM, seen from
    ``views (n, 2)`` (the light and the viewpoint both move).

    Parameters
    ----------
    store : path-like or xarray.Dataset
    path : path-like
        The GIF to write.
    lights : array-like, shape (n, 2)
    views : array-like, shape (n, 2) or (2,), optional
    fps : float

    Returns
    -------
    str
        The path written.
    """
    import imageio.v3 as iio

    ds = _as_dataset(store)
    transfer = ds.attrs.get("acquisition", {}).get("transfer", "srgb")
    images = encode_images(relight(ds, lights, view=views).values, transfer)
    try:
        iio.imwrite(path, images, duration=1000 / fps, loop=0)
    except (OSError, ValueError) as exc:
        raise LtmError(f"cannot write GIF {str(path)!r}: {exc}") from exc
    return os.fspath(path)
