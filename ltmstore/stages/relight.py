"""Lazy relighting: ``y = T l`` on the chunked LTM, for near- and far-light stores alike.

Near-light store (a handheld LED on a plane at height ``h``): a point light on the plane is a
bilinear weight over the four nearest lattice cells, so its image reads only the inner chunks
that hold those cells. A light beyond the plane (or a direction that meets the plane outside it,
or never) is not clamped to the edge: its weights over the lattice are those of a hemispherical
harmonics fit (order 2) of the whole lattice, evaluated at its direction (the model's own smooth
extrapolation), with one :class:`LightExtrapolationWarning`. Any weight pattern over the lattice
(an area light, an environment) is a weighted sum over the cells it covers.

Every query reads the LTM's light-major copy when the store has one
(:mod:`ltmstore.stages.by_light`): a point light then reads its 4 cells' image planes only.

Far-light store (a classic RTI capture, :mod:`ltmstore.stages.reconstruct_far`): a direction is
evaluated by each tile's chosen model straight from the frames (no lattice in between; fitted,
as there, to the sRGB-encoded colours and decoded to linear light); a
``(r, s)`` light is the direction ``(r, s, sqrt(1 - r^2 - s^2))``. Its surface model is
rendered block by block (its stored column chunks by bands of rows of :data:`BAND_BYTES`), as its
frames are read chunk by chunk: memory follows the block, not the image.

Relit values are linear light at the capture's exposure, never negative (clipped at 0),
not scaled for display (:func:`ltmstore.core.transfer.encode_images` does that, photometric by
default). Results are lazy Dask-backed
:class:`xarray.DataArray` objects; nothing is read until they are computed.

A 6D LTM ``(y, x, r, s, p, q)`` is re-viewed the same way: a camera position ``(p, q)`` on the
view plane is a bilinear weight over the four nearest view cells, so a (light, view) query reads
the inner chunks of at most 16 cells per tile.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import dask.array as da
import numpy as np
import xarray as xr

from ltmstore.core import factored
from ltmstore.core.dims import (
    CHROMA,
    CHROMA_LTM,
    COLOR,
    COLOR_CHANNELS,
    FRAME_CHROMA,
    FRAMES,
    LTM,
    P,
    Plane,
    Q,
    T,
    rgb_from_ycbcr,
)
from ltmstore.core.errors import LtmError, LtmWarning, brief
from ltmstore.core.imagefile import check_image_path, write_image
from ltmstore.core.lights import (
    FAR,
    above_horizon,
    check_light,
    direction_to_plane,
    disk_to_direction,
    light_kind,
    normalise,
    plane_to_direction,
)
from ltmstore.core.store import open_group, open_store
from ltmstore.core.transfer import (
    AUTO,
    CAPTURE,
    check_depth,
    check_exposure,
    encode,
    exposure_gain,
    linear_to_srgb,
    srgb_to_linear,
)
from ltmstore.solve import shadows
from ltmstore.solve.hsh import hsh_basis
from ltmstore.solve.lightfit import Model
from ltmstore.stages import surface
from ltmstore.stages.by_light import cell_major_name, light_major
from ltmstore.stages.plan import METHOD_MAP

LIGHT = "light"


FAR_FROM_DATA_DEG = 25.0  # a light further than this from every observed one gets a warning
# A far-light store is relit in bands of rows whose values at the captured lights and at the
# asked ones (float32 RGB) take at most this (surface.row_bands): the whole image at once took
# 2.7 GB at 1 MP, 47 lights; bands of 2**26 bytes 0.87 GB, of 2**24 0.54 GB (the frames'
# chunks in flight the most of the rest), of 2**22 no less (relight(...).values' peak RSS;
# the command's: bench/relight_memory.py).
BAND_BYTES = 2**24
# A far-light store's surface blend is relit by the compiled kernel (physical_far.blend) where the
# image's pixels times its photographs and asked lights reach this, by NumPy below: loading Numba
# and the kernel took 0.3 s, 15-25 % of a small capture's ltm relight (coin 1.75 -> 2.03 s), where
# at 1 MP the kernel saves 0.8 s. The asked lights count since the kernel draws the web export's
# grids (256-2,304 nodes) faster than NumPy's model: ltm export 9.5 -> 8.7 s on the coin, 15.8 ->
# 13.0 s on the icon, 79 -> 67 s on SynthRTI (bench/results/export_speed_compiled.json).
COMPILED_WORK = 2**24
# Above this many point lights a near-light store is relit in one pass over its cell-major LTM
# (_relight_many), not image by image (_relight_points: tasks per light, cell and chunk of pixels;
# 944 lights on the demo's 96 x 96 store, in colour: 21 s against 0.8-1.3 s). The web export's
# grids: ltm export 39.2 -> 12.0 s on the demo's store (bench/results/export_speed_near.json).
POINT_LIGHTS = 16
# Up to this many asked lights a compiled classic model sums the photographs as it encodes them
# (far_sums.encoded_sum); at more, BLAS sums the encoded photographs faster than its loop.
FUSED_LIGHTS = 8
# Relit images at ``auto`` exposure are encoded (encoded_images) in bands of rows of at most this
# many pixels: a whole 24 MP image at once peaked at 3.0 GiB for one light
# (bench/relight_memory.py).
ENCODE_BAND_PIXELS = 2**20


class LightClampWarning(UserWarning):
    """A requested camera position lay outside the view lattice and was moved to its edge."""


class LightExtrapolationWarning(LtmWarning):
    """A requested light lies far from every observation: its image is an extrapolation."""


def linear_position(centres: np.ndarray, value: float) -> tuple[int, int, float]:
    """Indices ``i0, i1`` and weight of ``i1`` for linear interpolation between evenly spaced
    cell centres, clamped at the first and last centre."""
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
    i0, i1, wa = linear_position(ca, va)
    j0, j1, wb = linear_position(cb, vb)
    cells = [((i0, j0), (1 - wa) * (1 - wb)), ((i1, j0), wa * (1 - wb)),
             ((i0, j1), (1 - wa) * wb), ((i1, j1), wa * wb)]
    return ([({dim_a: i, dim_b: j}, w) for (i, j), w in cells if w > 0]
            or [({dim_a: i0, dim_b: j0}, 1.0)])


def light_weights(ltm: xr.DataArray, light: tuple[float, float]) -> list[tuple[dict, float]]:
    """Bilinear weights of a point light inside the lattice: ``[({r: i, s: j}, weight)]``."""
    r, s = (float(v) for v in light)
    return _cell_weights(("r", ltm["r"].values, r), ("s", ltm["s"].values, s))


def disk_light(ltm: xr.DataArray, centre: tuple[float, float], radius: float, *,
               samples: int = 8) -> xr.DataArray:
    """An area light: a uniform disk on the plane, as weights over the lattice ``(r, s)``.

    Each cell's weight is proportional to the part of the disk that falls in it (``samples`` x
    ``samples`` points per cell), and the weights sum to 1: the power of one point light,
    spread over the cells the disk covers (a disk smaller than a cell covers at least the cell
    of its centre). Relight it with ``relight(store, weights)``: only the cells the disk
    covers are read.
    """
    if not (np.isfinite(radius) and radius > 0):
        raise LtmError(f"area light radius {radius!r} must be a positive number")
    axes = []
    for dim, c in zip(("r", "s"), centre, strict=True):
        centres = ltm[dim].values
        step = float(centres[1] - centres[0]) if len(centres) > 1 else 2 * radius
        offsets = (np.arange(samples) + 0.5) / samples - 0.5
        axes.append((centres[:, None] + step * offsets[None, :] - c, step))
    (dr, _), (ds_, _) = axes
    inside = (dr[:, None, :, None] ** 2 + ds_[None, :, None, :] ** 2) <= radius ** 2
    weights = inside.mean(axis=(2, 3))
    if not weights.any():
        weights = np.zeros_like(weights)
        weights[tuple(np.argmin(np.abs(d[:, samples // 2])) for d, _ in axes)] = 1.0
    weights = weights / weights.sum()
    return xr.DataArray(weights, dims=("r", "s"), coords={"r": ltm["r"], "s": ltm["s"]})


def extrapolation_weights(ltm: xr.DataArray, plane: Plane, directions: np.ndarray) -> np.ndarray:
    """``(n, R, S)`` weights over a near-light lattice that evaluate, at unit ``directions``,
    the least-squares order-2 hemispherical harmonics fit of every pixel's lattice values."""
    basis, fit = _extrapolation_factors(ltm, plane, directions)
    return (basis @ fit).reshape(len(directions), ltm.sizes["r"], ltm.sizes["s"])


def _extrapolation_factors(ltm: xr.DataArray, plane: Plane, directions: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`extrapolation_weights` as its two factors: the HSH functions at ``directions``
    ``(n, 9)`` and the fit of the cells' values to them ``(9, R * S)``."""
    rr, ss = np.meshgrid(ltm["r"].values, ltm["s"].values, indexing="ij")
    cells = plane_to_direction(rr.ravel(), ss.ravel(), plane.height)
    return hsh_basis(directions, 2), np.linalg.pinv(hsh_basis(cells, 2))


def _warn_far(directions: np.ndarray, observed: np.ndarray | None) -> None:
    """One warning line for the lights far from every observed direction."""
    if observed is None or not len(observed):
        return
    cosine = np.clip(directions @ observed.T, -1, 1).max(axis=1)
    far = np.degrees(np.arccos(cosine)) > FAR_FROM_DATA_DEG
    if far.any():
        listed = ", ".join(f"({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f})" for d in directions[far][:3])
        warnings.warn(f"{int(far.sum())} light(s) lie more than {FAR_FROM_DATA_DEG:g} degrees "
                      f"from every captured light ({listed}{', ...' if far.sum() > 3 else ''}): "
                      "extrapolated, distrust them (see expected_error)",
                      LightExtrapolationWarning, stacklevel=3)


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
            raise LtmError(f"view {brief(view)} given, but the store's ltm has no "
                           "view axes (p, q): it is a 4D LTM")
        return None, None
    bounds = ds.attrs.get("acquisition", {}).get("view_plane")
    if view is None:  # the centre of the view plane
        view = ([float(np.mean(bounds[P])), float(np.mean(bounds[Q]))] if bounds
                else [float(ltm[P].mean()), float(ltm[Q].mean())])
    views = np.atleast_2d(np.asarray(view, dtype=float))
    if views.shape[-1] != 2 or views.ndim != 2 or len(views) not in (1, n) or \
            not np.isfinite(views).all():
        raise LtmError(f"view {brief(view)} must be one finite (p, q) pair or "
                       f"one per light ({n})")
    return views, [view_weights(ltm, v, bounds) for v in views]


def _point_image(ltm: xr.DataArray, weights: list[tuple[dict, float]]) -> xr.DataArray:
    """``sum(w * ltm[cell])``, on the variable (no coordinate alignment: interactive speed)."""
    var = ltm.variable
    terms = [var.isel(cell) * w for cell, w in weights]
    image = sum(terms[1:], terms[0])
    return xr.DataArray(image, coords={k: c for k, c in ltm.coords.items()
                                       if set(c.dims) <= set(image.dims)})


def _as_dataset(store) -> xr.Dataset:
    if isinstance(store, xr.Dataset):
        return store
    if isinstance(store, str | os.PathLike):
        return open_store(store)
    raise LtmError(f"store {store!r} must be a path or an xarray.Dataset")


def relight(store, lights=None, *, directions=None, view=None,
            color: bool = True) -> xr.DataArray:
    """Relight (and, for a 6D LTM, re-view) the LTM of a store, lazily.

    Parameters
    ----------
    store : path-like or xarray.Dataset
        A reconstructed store (or the dataset :func:`ltmstore.open_store` returns).
    lights : array-like of shape (n, 2), or xarray.DataArray, optional
        Point lights ``(r, s)`` in the store's coordinates (a plane position for a near-light
        store, anywhere on or beyond the plane; ``(lx, ly)`` inside the unit disk for a far-light
        store); or, for a near-light store, a weight pattern over the lattice with dims
        ``(r, s)`` or ``(light, r, s)`` (area lights, environments).
    directions : array-like of shape (n, 3), optional
        Instead of ``lights``: directions ``(lx, ly, lz)`` towards the lights (normalised here),
        above the horizon; on a near-light store each becomes the plane position at the
        plane's height.
    view : array-like of shape (2,) or (n, 2), optional
        6D LTMs only: camera position ``(p, q)`` on the view plane, one for all lights or one
        per light (a path where light and viewpoint both move); default the view plane's
        centre. Given for a 4D LTM it is an error.
    color : bool
        Return linear RGB (dim ``color``): from the colour LTM when the store has one
        (``ltm_cb``, ``ltm_cr``), the frames' chroma for a far-light store, else from the stored
        chroma ratios; else luminance only.

    Returns
    -------
    xarray.DataArray
        Dims ``(light, y, x[, color])``, linear light, never negative, Dask-backed (with
        coordinates ``view_p, view_q`` for a 6D LTM). Photometric, at the capture's exposure:
        at a light of the capture it is that light's photograph (far lights; at the capture's
        mean exposure where reconstruct fitted one per photograph) or camera B's video frame
        (near lights), decoded to linear light in ``[0, 1]``; a weight pattern of half the
        weight gives half the value, and lights summed give the sum of their images. Written
        as 8-bit images by :func:`ltmstore.core.transfer.encode_images` (``exposure``, ``ev``).
    """
    ds = _as_dataset(store)
    if LTM not in ds:
        raise LtmError("the store has no complete ltm; run `ltm reconstruct` first")
    if (lights is None) == (directions is None):
        raise LtmError("give either lights (r, s) or directions (lx, ly, lz), not both")
    acq = ds.attrs.get("acquisition", {})
    far = light_kind(acq) == FAR
    if isinstance(lights, xr.DataArray):
        if far:
            raise LtmError("a far-light store relights point lights or directions, not "
                           "weight patterns over its lattice")
        return _relight_pattern(ds, lights, view, color)
    if directions is not None:
        dirs = _above_horizon(directions)
    else:
        points = check_light(lights, "light", ("r", "s"))  # (n, 2), finite
        if far and (np.hypot(points[:, 0], points[:, 1]) >= 1).any():
            raise LtmError(f"lights {brief(points)} of a far-light store must lie inside the "
                           "unit disk (r = lx, s = ly, r^2 + s^2 < 1)")
        dirs = (disk_to_direction(points[:, 0], points[:, 1]) if far else
                plane_to_direction(points[:, 0], points[:, 1], _plane(acq, ds[LTM]).height))
    if far:
        if view is not None:
            raise LtmError("view given, but a far-light store has no view axes (p, q)")
        return _relight_far(ds, dirs, color)
    plane = _plane(acq, ds[LTM])
    points = direction_to_plane(dirs, plane.height) if directions is not None else points
    return _relight_near(ds, plane, points, dirs, view, color)


def _plane(acq: dict, ltm: xr.DataArray) -> Plane:
    """The store's plane; without one, the lattice's extent at unit height."""
    if "plane" in acq:
        return Plane.from_json(acq["plane"])
    r, s = ltm["r"].values, ltm["s"].values
    return Plane(r=(float(r[0]), float(r[-1])), s=(float(s[0]), float(s[-1])), height=1.0)


def _above_horizon(directions) -> np.ndarray:
    dirs = normalise(check_light(directions, "direction", ("lx", "ly", "lz")))
    if not above_horizon(dirs).all():
        bad = dirs[~above_horizon(dirs)][0]
        raise LtmError(f"direction ({bad[0]:.3g}, {bad[1]:.3g}, {bad[2]:.3g}) is at or below "
                       "the horizon; expected lz > 0 (a light above the object)")
    return dirs


def _observed_directions(ds: xr.Dataset) -> np.ndarray | None:
    """Unit directions of the captured lights (None when the store holds no poses)."""
    if "pose_valid" not in ds:
        return None
    valid = ds["pose_valid"].values.astype(bool)
    r, s, z = (np.asarray(ds[k])[valid] for k in ("pose_r", "pose_s", "pose_z"))
    bad = np.count_nonzero(~np.isfinite(np.column_stack([r, s, z])).all(axis=1))
    if bad:
        raise LtmError(f"the store's poses hold {bad} valid light positions that are not finite; "
                       "the store is damaged (run ltm check)")
    if light_kind(ds.attrs.get("acquisition", {})) == FAR:
        return np.column_stack([r, s, z])
    return normalise(np.column_stack([r, s, z]))


def _relight_near(ds: xr.Dataset, plane: Plane, points: np.ndarray, dirs: np.ndarray, view,
                  color: bool) -> xr.DataArray:
    """Point lights on a near-light store: bilinear inside the plane, extrapolated beyond."""
    inside = np.isfinite(points).all(axis=1) & plane.contains(points[:, 0], points[:, 1])
    _warn_far(dirs, _observed_directions(ds))
    ltm = ds[LTM]
    if (len(points) > POINT_LIGHTS and view is None and not _factored(ds, LTM)
            and set(ltm.dims) == {"y", "x", "r", "s"}):
        image = _relight_many(ds, plane, points, dirs, inside, color)
    elif not inside.all() or _factored(ds, LTM):  # a factored store relights W (B l)
        pattern = _bilinear_matrix(ltm, points, inside).toarray().reshape(
            len(points), ltm.sizes["r"], ltm.sizes["s"])
        pattern[~inside] = extrapolation_weights(ltm, plane, dirs[~inside])
        image = _relight_pattern(ds, xr.DataArray(pattern, dims=(LIGHT, "r", "s")), view, color)
    else:
        image = _relight_points(ds, points, view, color)
    if inside.all():  # as _relight_points names them
        image = image.assign_coords({LIGHT: np.arange(len(points)),
                                     "light_r": (LIGHT, points[:, 0]),
                                     "light_s": (LIGHT, points[:, 1])})
    return image.assign_coords(light_lx=(LIGHT, dirs[:, 0]), light_ly=(LIGHT, dirs[:, 1]),
                               light_lz=(LIGHT, dirs[:, 2]))


def _relight_many(ds: xr.Dataset, plane: Plane, points: np.ndarray, dirs: np.ndarray,
                  inside: np.ndarray, color: bool) -> xr.DataArray:
    """Many point lights on a 4D near-light store, in one task per chunk of pixels of its
    cell-major LTM: the lights inside the plane by their bilinear weights (a sparse matrix,
    4 cells a light), those beyond it by the HSH fit they evaluate (9 functions, whatever the
    number of lights)."""
    ltm = ds[LTM]
    n = len(points)
    bilinear = _bilinear_matrix(ltm, points, inside).astype(np.float32)
    beyond = np.flatnonzero(~inside)
    basis, fit = (f.astype(np.float32) for f in _extrapolation_factors(ltm, plane, dirs[beyond]))

    def product(block: np.ndarray) -> np.ndarray:  # (y, x, r, s) -> (light, y, x)
        pixels = block.reshape(-1, bilinear.shape[1]).astype(np.float32, copy=False).T
        out = bilinear @ pixels
        if len(beyond):
            out[beyond] += basis @ (fit @ pixels)
        return out.reshape(n, *block.shape[:2])

    def apply(light_major_ltm: xr.DataArray) -> xr.DataArray:
        cell_major = ds[cell_major_name(str(light_major_ltm.name))]
        image = da.blockwise(product, "lyx", cell_major.transpose("y", "x", "r", "s").data,
                             "yxrs", new_axes={"l": n}, concatenate=True, dtype=np.float32)
        coords = {k: c for k, c in cell_major.coords.items() if set(c.dims) <= {"y", "x"}}
        return xr.DataArray(image, dims=(LIGHT, "y", "x"), coords=coords)
    return _finish(ds, apply, None, color)


def _bilinear_matrix(ltm: xr.DataArray, points: np.ndarray, inside: np.ndarray):
    """The bilinear weights (:func:`light_weights`) of the ``inside`` ones of ``points (n, 2)``
    over the lattice's cells ``r * S + s``: a sparse ``(n, R * S)`` matrix, rows of the other
    points empty."""
    from scipy import sparse

    size = ltm.sizes["s"]
    weights = sparse.lil_array((len(points), ltm.sizes["r"] * size))
    for k in np.flatnonzero(inside):
        for cell, w in light_weights(ltm, points[k]):
            weights[k, cell["r"] * size + cell["s"]] += w
    return weights.tocsr()


def _relight_points(ds: xr.Dataset, points: np.ndarray, view, color: bool) -> xr.DataArray:
    weights = [light_weights(ds[LTM], p) for p in points]
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
    return _finish(ds, apply, views, color)


def _relight_pattern(ds: xr.Dataset, lights: xr.DataArray, view, color: bool) -> xr.DataArray:
    pattern = lights if LIGHT in lights.dims else lights.expand_dims(LIGHT)
    views, vweights = _views(ds, view, pattern.sizes[LIGHT])

    box = _support(pattern)
    pattern = pattern.isel(box)

    def apply(ltm: xr.DataArray) -> xr.DataArray:
        ltm = ltm.isel(box)
        name = cell_major_name(str(ltm.name))
        if views is None and _factored(ds, name):
            return _factored_dot(ds, name, ltm, pattern, box)
        if views is None:
            return _dot_cells(ltm, pattern) if _one_chunk_per_cell(ltm) else xr.dot(
                ltm, pattern, dim=["r", "s"])
        if len(views) == 1:
            return xr.dot(_point_image(ltm, vweights[0]), pattern, dim=["r", "s"])
        return xr.concat([xr.dot(_point_image(ltm, vw), pattern.isel({LIGHT: k}),
                                 dim=["r", "s"]) for k, vw in enumerate(vweights)],
                         dim=LIGHT)
    return _finish(ds, apply, views, color)


def _factored(ds: xr.Dataset, name: str) -> bool:
    """Whether the LTM variable ``name`` is stored as factors (:mod:`ltmstore.core.factored`)."""
    return all(f(name) in ds for f in (factored.weights_name, factored.basis_name,
                                       factored.ranks_name))


def _factored_dot(ds: xr.Dataset, name: str, ltm: xr.DataArray, pattern: xr.DataArray,
                  box: dict[str, slice]) -> xr.DataArray:
    """``W (B l)`` from the stored factors of ``name``: never the dense LTM. (A dataset that
    does not name its store in ``encoding["source"]``, or holds part of its image, relights
    from its derived LTM.)"""
    group = open_group(ds.encoding["source"]) if "source" in ds.encoding else None
    basis = None if group is None else group[factored.basis_name(name)]
    if basis is None or list(ltm.shape[:2]) != list(basis.attrs["image"]):
        return xr.dot(ltm, pattern, dim=["r", "s"])
    full = np.zeros((pattern.sizes[LIGHT], *basis.shape[1:]), np.float32)
    full[(slice(None), box["r"], box["s"])] = pattern.transpose(LIGHT, "r", "s").values
    weights = ds.encoding.get("kept_weights", {}).get(name)  # decoded once per opened store
    if weights is None:
        weights = group[factored.weights_name(name)]
    image = factored.relight(weights, basis,
                             np.asarray(group[factored.ranks_name(name)][...]), full,
                             int(basis.attrs["tile"]))
    coords = {k: c for k, c in ltm.coords.items() if set(c.dims) <= {"y", "x"}}
    return xr.DataArray(image, dims=(LIGHT, "y", "x"), coords=coords)


def _one_chunk_per_cell(ltm: xr.DataArray) -> bool:
    """Whether ``ltm`` (y, x, r, s) is Dask-backed with one chunk per cell (light-major)."""
    return (ltm.chunks is not None and ltm.dims == ("y", "x", "r", "s")
            and all(c == 1 for dim in ("r", "s") for c in ltm.chunksizes[dim]))


def _dot_cells(ltm: xr.DataArray, pattern: xr.DataArray,
               group_bytes: int = 64 * 2**20) -> xr.DataArray:
    """``xr.dot(ltm, pattern)`` over ``(r, s)`` on a light-major LTM: each cell with a weight
    is read as one plane, the planes stacked in groups of about ``group_bytes``, each group
    contracted in one task (a few hundred tasks, not one per chunk pair)."""
    weights = np.asarray(pattern.transpose(LIGHT, "r", "s").values)
    cells = np.argwhere((weights != 0).any(axis=0))
    if not len(cells):
        return xr.dot(ltm, pattern, dim=["r", "s"])
    data = ltm.data
    plane = max(ltm.chunksizes["y"]) * max(ltm.chunksizes["x"]) * data.dtype.itemsize
    planes = da.stack([data[:, :, i, j] for i, j in cells]).rechunk(
        {0: max(1, group_bytes // plane)})
    used = weights[:, cells[:, 0], cells[:, 1]].astype(data.dtype)  # in the LTM's precision
    image = da.tensordot(used, planes, axes=1)
    coords = {**{k: c for k, c in ltm.coords.items() if set(c.dims) <= {"y", "x"}},
              **{k: c for k, c in pattern.coords.items() if c.dims == (LIGHT,)}}
    return xr.DataArray(image, dims=(LIGHT, "y", "x"), coords=coords)


def _support(pattern: xr.DataArray) -> dict[str, slice]:
    """The smallest box of lattice cells outside which every weight of ``pattern`` is zero
    (an area light reads only the cells it covers)."""
    weights = np.asarray(pattern.transpose(LIGHT, "r", "s").values)
    used = weights != 0
    box = {}
    for dim, axis in (("r", 2), ("s", 1)):
        hit = np.flatnonzero(used.any(axis=(0, axis)))
        box[dim] = slice(int(hit[0]), int(hit[-1]) + 1) if len(hit) else slice(0, 1)
    return box


def _finish(ds: xr.Dataset, apply, views, color: bool) -> xr.DataArray:
    """Luminance (and colour) images of ``apply`` on the store's LTMs, clipped at 0."""
    image = apply(light_major(ds, LTM)).transpose(LIGHT, "y", "x")
    if views is not None:
        n = image.sizes[LIGHT]
        image = image.assign_coords(view_p=(LIGHT, np.resize(views[:, 0], n)),
                                    view_q=(LIGHT, np.resize(views[:, 1], n)))
    if not color:
        return image.clip(min=0)
    if all(name in ds for name in CHROMA_LTM.values()):  # a colour LTM
        cb, cr = (apply(light_major(ds, CHROMA_LTM[c])).transpose(LIGHT, "y", "x")
                  for c in ("cb", "cr"))
        return _stack_rgb(image, cb, cr).clip(min=0)
    return (to_rgb(image, ds[CHROMA]) if CHROMA in ds else image).clip(min=0)


def _relight_far(ds: xr.Dataset, dirs: np.ndarray, color: bool) -> xr.DataArray:
    """Directions on a far-light store: each tile's chosen model, evaluated from the frames
    block by block (:func:`_far_image`)."""
    if METHOD_MAP not in ds:
        raise LtmError("the far-light store has no method_map; run `ltm reconstruct` again "
                       "with this version")
    valid = ds["pose_valid"].values.astype(bool)
    train = _observed_directions(ds)
    _warn_far(dirs, train)
    chosen = ds[METHOD_MAP]
    ty, tx = chosen.attrs["tile"]
    # each pixel's tile by its position in the image: ds may be a region or strided
    codes = chosen.values[(ds["y"].values // ty)[:, None], (ds["x"].values // tx)[None, :]]
    models = {int(c): _far_model(ds, chosen.attrs["methods"][int(c)]) for c in np.unique(codes)}
    planes, exposure = _photographs(ds, np.flatnonzero(valid), color)
    image = _far_image(ds, planes, exposure, codes, models, train, dirs)
    dims = (LIGHT, "y", "x", COLOR) if color else (LIGHT, "y", "x")
    coords = {LIGHT: np.arange(len(dirs)), "light_lx": (LIGHT, dirs[:, 0]),
              "light_ly": (LIGHT, dirs[:, 1]), "light_lz": (LIGHT, dirs[:, 2]),
              "y": ds["y"], "x": ds["x"]}
    if color:
        coords[COLOR] = list(COLOR_CHANNELS)
    return xr.DataArray(image, dims=dims, coords=coords, attrs=ds[FRAMES].attrs)


def _far_model(ds: xr.Dataset, name: str) -> Model | surface.Blend:
    """The model a far-light store's method ``name`` names (its surface blend checked
    against the store's surface)."""
    if not name.startswith(surface.PREFIX):
        return Model(name)
    blend = surface.Blend.from_name(name)
    if blend.lobe != surface.surface_lobe(ds):  # the lobe is written twice
        raise LtmError(f"the far-light store's method {name!r} names the {blend.lobe} lobe, "
                       f"its roughness the {surface.surface_lobe(ds)} lobe; run `ltm "
                       "reconstruct` again")
    if blend.shadows and surface.SHADOW_HEIGHT not in ds:
        raise LtmError(f"the far-light store's method {name!r} casts shadows but it has no "
                       f"{surface.SHADOW_HEIGHT}; run `ltm reconstruct` again")
    return blend


def _photographs(ds: xr.Dataset, used: np.ndarray, color: bool
                 ) -> tuple[list[da.Array], np.ndarray]:
    """The photographs at ``used``, lazily: their linear Y (and Cb, Cr) ``(t, y, x)`` float32,
    and the capture's exposure of each ``(t,)`` float32 (:func:`_linear` makes of them the
    linear values whose sRGB encoding the models are fitted to)."""
    planes = [ds[FRAMES]]
    if color:
        planes += [ds[FRAME_CHROMA].sel(channel=c, drop=True) for c in ("cb", "cr")]
    planes = [da.asarray(p.isel({T: used}).data.astype(np.float32)) for p in planes]
    exposure = (ds[surface.EXPOSURE].values[used].astype(np.float32)
                if surface.EXPOSURE in ds else np.ones(len(used), np.float32))
    return planes, exposure


def _linear(*planes: np.ndarray, exposure: np.ndarray, compiled: bool) -> np.ndarray:
    """The linear RGB (or Y) ``(t, y, x, 3)`` (or ``(t, y, x, 1)``) of photographs' ``planes``,
    their Y (and Cb, Cr) ``(t, y, x)``: clipped at 0 and divided by their ``exposure``
    (compiled, :func:`ltmstore.stages.far_sums.linear`, also clipped at 1 as
    :func:`~ltmstore.core.transfer.linear_to_srgb` clips: the same encoding)."""
    color = len(planes) == 3
    if compiled:
        from ltmstore.stages import far_sums

        out = np.empty((*planes[0].shape, 3 if color else 1), np.float32)
        y, cb, cr = planes if color else planes * 3  # the chroma ignored without colour
        far_sums.linear(*(p.reshape(len(p), -1) for p in (y, cb, cr)), exposure, color,
                        np.float32(1), out.reshape(len(out), -1, out.shape[-1]))
        return out
    scale = exposure.reshape(-1, 1, 1, 1)
    if color:
        return np.clip(_rgb(*planes), 0, None) / scale
    return planes[0][..., None] / scale


def _far_image(ds: xr.Dataset, planes: list[da.Array], exposure: np.ndarray, codes: np.ndarray,
               models: dict, train: np.ndarray, dirs: np.ndarray) -> da.Array:
    """Linear images ``(light, y, x[, color])`` of the far-light models: one task per chunk of
    the frames, split in bands of rows where it would take more than :data:`BAND_BYTES`
    (:func:`~ltmstore.stages.surface.row_bands`), each reading its part of the frames and of
    the surface variables only (a region of the image, an IIIF tile, computes its own
    columns, not whole rows). ``planes`` and ``exposure``: :func:`_photographs`."""
    height, width = codes.shape
    color = len(planes) == 3
    blends = {c: m for c, m in models.items() if isinstance(m, surface.Blend)}
    cols = planes[0].chunks[2]  # the frames' own chunks (each read once), their rows split
    most = surface.row_bands((len(train) + len(dirs), height, max(cols)), BAND_BYTES)[0].stop
    rows = tuple(part for n in planes[0].chunks[1] for part in _split(n, most))
    compiled = height * width * (len(train) + len(dirs)) >= COMPILED_WORK
    planes = [p.rechunk((-1, rows, cols)) for p in planes]
    maps = [da.asarray(ds[name].data) for name in surface.SURFACE] if blends else []
    maps = [m.rechunk((rows, cols, *(-1,) * (m.ndim - 2))) for m in maps]
    operators = {c: _FarOperator.of(m, train, dirs, compiled) for c, m in models.items()}
    # the classic models' sums encoded as they are summed where the kernel repays it
    fusable = compiled and len(dirs) <= FUSED_LIGHTS

    def block(ys: np.ndarray, xs: np.ndarray, where: np.ndarray, *arrays: np.ndarray
              ) -> np.ndarray:
        ycc, values = arrays[:len(planes)], arrays[len(planes):]  # Y (Cb, Cr); the surface's
        shape = ycc[0].shape[1:] + ((3,) if color else ())  # (y, x[, color])
        values = [v.reshape(-1, *v.shape[2:]) for v in values]
        where = where.ravel()
        present = np.unique(where)
        visible = {c: _visible(ds, blends[c], ys, xs, train, dirs) for c in present
                   if c in blends and blends[c].shadows}
        fused = fusable and not any(c in blends for c in present)
        if fused:  # (t, pixels) each
            frames = [p.reshape(len(p), -1) for p in ycc]
        else:  # (t, pixels[, c]) encoded
            frames = _linear(*ycc, exposure=exposure, compiled=compiled)
            frames = linear_to_srgb(frames if color else frames[..., 0])
            frames = frames.reshape(len(frames), -1, *frames.shape[3:])

        def image(c: int, inside: np.ndarray | slice) -> np.ndarray:
            if fused:
                out = operators[c].encoded_sum([f[:, inside] for f in frames], exposure)
                return out if color else out[..., 0]
            return operators[c](frames[:, inside], [v[inside] for v in values],
                                visible.get(c), inside)

        if len(present) == 1:  # one model for the whole block: no copies in and out
            out = image(present[0], slice(None))
        else:
            out = np.empty((len(dirs), len(where), *shape[2:]), np.float32)
            for c in present:
                inside = where == c
                out[:, inside] = image(c, inside)
        return srgb_to_linear(np.clip(out, 0, None, out=out)).reshape(len(dirs), *shape)

    index = "yx" + ("c" if color else "")
    at = (da.from_array(np.arange(height), chunks=(rows,)),  # where each block lies
          da.from_array(np.arange(width), chunks=(cols,)))
    args = [at[0], "y", at[1], "x", da.from_array(codes, chunks=(rows, cols)), "yx"]
    args += [x for p in planes for x in (p, "tyx")]
    args += [x for m in maps for x in (m, "yx" + ("k" if m.ndim == 3 else ""))]
    return da.blockwise(block, "l" + index, *args,
                        new_axes={"l": len(dirs), **({"c": 3} if color else {})},
                        concatenate=True, dtype=np.float32,
                        meta=np.empty((0,) * (len(index) + 1), np.float32))


def _visible(ds: xr.Dataset, blend: surface.Blend, ys: np.ndarray, xs: np.ndarray,
             train: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cast shadows (:mod:`ltmstore.solve.shadows`) of the block of rows ``ys`` and
    columns ``xs`` (positions in ``ds``) at the photographs' lights ``train`` and at
    ``dirs``."""
    rows, cols = slice(int(ys[0]), int(ys[-1]) + 1), slice(int(xs[0]), int(xs[-1]) + 1)
    stored = ds[surface.SHADOW_HEIGHT].variable
    # a store strided to every n-th pixel (ltm view's preview): its x coordinate says n
    spacing = int(ds["x"][1] - ds["x"][0]) if "x" in ds.coords and ds.sizes["x"] > 1 else 1
    return tuple(shadows.visible(d, shadows.region_horizons(stored, rows, cols, d,
                                                            spacing=spacing),
                                 blend.shadows) for d in (train, dirs))


def _split(n: int, most: int) -> list[int]:
    """``n`` as the fewest near-equal parts of at most ``most``."""
    parts = -(-n // most)
    return [n // parts + (i < n % parts) for i in range(parts)]


@dataclass(frozen=True)
class _FarOperator:
    """A far-light model's image at ``dirs`` from the encoded photographs at ``train``:
    ``linear @ frames``, plus for a surface blend ``weight (srgb(M(dirs)) - smoother @
    srgb(M(train)))`` (:meth:`ltmstore.stages.surface.Blend.correction`), its two sums over
    the photographs taken as one: ``compiled``, in one pass per pixel
    (:func:`ltmstore.stages.surface.blend_encoded`), else in NumPy."""

    model: Model | surface.Blend
    train: np.ndarray
    dirs: np.ndarray
    weights: np.ndarray  # (d, n) float64, or (d, 2n): the frames' then the model's
    compiled: bool

    @classmethod
    def of(cls, model: Model | surface.Blend, train: np.ndarray, dirs: np.ndarray,
           compiled: bool) -> _FarOperator:
        weights = model.weights(train, dirs)
        if isinstance(model, surface.Blend):
            weights = np.hstack([weights, -model.weight * model.smoother.weights(train, dirs)])
        return cls(model, train, dirs, weights.astype(np.float64), compiled)

    def encoded_sum(self, ycc: list[np.ndarray], exposure: np.ndarray) -> np.ndarray:
        """A classic model's encoded images ``(d, p, c)`` from the photographs' ``ycc``: Y
        (and Cb, Cr: ``c = 3``) ``(n, p)`` and their ``exposure (n,)``, linearised and encoded
        as they are summed (:func:`ltmstore.stages.far_sums.encoded_sum`: NumPy's values to
        float32 rounding, without their temporaries)."""
        from ltmstore.stages import far_sums

        y, cb, cr = ycc if len(ycc) == 3 else ycc * 3  # no chroma: ignored
        out = np.empty((len(self.weights), y.shape[1], len(ycc)), np.float32)
        far_sums.encoded_sum(y, cb, cr, exposure, len(ycc) == 3, self.weights,
                             far_sums.srgb_table(), out)
        return out

    def __call__(self, frames: np.ndarray, values: list[np.ndarray],
                 visible: tuple[np.ndarray, np.ndarray] | None, pixels: np.ndarray | slice
                 ) -> np.ndarray:
        """Encoded images ``(d, p[, 3])`` of the pixels whose encoded ``frames (n, p[, 3])``
        and surface ``values`` (:data:`~ltmstore.stages.surface.SURFACE`) are given;
        ``visible``: the block's shadows at ``train`` and ``dirs`` (pixel-major), ``pixels``
        selecting these pixels of it."""
        if not isinstance(self.model, surface.Blend):
            return _weighted_sum(self.weights, frames)
        blend = self.model
        at, to = (None, None) if visible is None else (v[pixels] for v in visible)
        theta = surface.surface_theta(*values)
        if self.compiled:
            return surface.blend_encoded(frames, self.weights, theta, self.train, self.dirs,
                                         blend.weight, lobe=blend.lobe, visible=(at, to))
        color = frames.ndim == 3
        at_train, query = (surface.model_encoded(theta, d, color=color, lobe=blend.lobe,
                                                 visible=v, compiled=False)
                           for d, v in ((self.train, at), (self.dirs, to)))
        return (_weighted_sum(self.weights, np.concatenate([frames, at_train]))
                + np.float32(blend.weight) * query)


def _weighted_sum(weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``weights (d, n) @ values (n, ...)`` in float64 (one BLAS call), as float32. BLAS sums
    in an order that changes with the number of pixels: in float32 that changed the last bit
    of 1.5 % of the values of a 1000 x 300 image between blocks of rows; float64's last bits
    next to never reach float32's (blocks of one row and the whole image agree bit for bit,
    tests/stages/test_relight_bands.py)."""
    flat = values.reshape(len(values), -1).astype(np.float64)
    return (weights @ flat).astype(np.float32).reshape(len(weights), *values.shape[1:])


def to_rgb(luminance: xr.DataArray, chroma: xr.DataArray) -> xr.DataArray:
    """Linear RGB from luminance and chroma stored as ratios to luminance."""
    order = [list(chroma["channel"].values).index(c) for c in ("cb", "cr")]

    def rgb(y: np.ndarray, ratios: np.ndarray) -> np.ndarray:
        return _rgb(y, y * ratios[..., order[0]], y * ratios[..., order[1]])
    return _apply_rgb(rgb, [luminance, chroma], [[], ["channel"]])


def _stack_rgb(y: xr.DataArray, cb: xr.DataArray, cr: xr.DataArray) -> xr.DataArray:
    """Linear RGB (dim ``color``, last) from Y, Cb and Cr, in one blockwise step."""
    return _apply_rgb(_rgb, [y, cb, cr], [[], [], []])


def _rgb(y: np.ndarray, cb: np.ndarray, cr: np.ndarray) -> np.ndarray:
    return np.stack(np.broadcast_arrays(*rgb_from_ycbcr(y, cb, cr)), axis=-1)


def _apply_rgb(func, args: list[xr.DataArray], core: list[list[str]]) -> xr.DataArray:
    probes = (np.zeros((1, *(a.sizes[d] for d in c)), a.dtype) for a, c in zip(args, core,
                                                                                strict=True))
    dtype = func(*probes).dtype
    rgb = xr.apply_ufunc(func, *args, input_core_dims=core, output_core_dims=[[COLOR]],
                         dask="parallelized", output_dtypes=[dtype],
                         dask_gufunc_kwargs={"output_sizes": {COLOR: len(COLOR_CHANNELS)}})
    return rgb.assign_coords({COLOR: list(COLOR_CHANNELS)})


def write_gif(store, path: str | os.PathLike, lights, views=None, *, fps: float = 12,
              exposure: str = CAPTURE, ev: float = 0.0) -> str:
    """An animated GIF of the store relit along ``lights (n, 2)`` and, for a 6D LTM, seen from
    ``views (n, 2)`` (the light and the viewpoint both move).

    Frames are written at the capture's exposure by default (photometric, as ``ltm relight``):
    a frame lit from far out is darker than one lit from above. ``exposure="auto"`` scales all
    frames by one factor so that the brightest 0.5 % of their pixels clip
    (:func:`ltmstore.core.transfer.encode_images`).

    Parameters
    ----------
    store : path-like or xarray.Dataset
    path : path-like
        The GIF to write.
    lights : array-like, shape (n, 2)
    views : array-like, shape (n, 2) or (2,), optional
    fps : float
    exposure : {"capture", "auto"}
        The frames' exposure (default ``capture``).
    ev : float
        Stops added to ``exposure`` (linear values times ``2**ev``).

    Returns
    -------
    str
        The path written.
    """
    check_exposure(exposure, ev)
    check_image_path(path)
    ds = _as_dataset(store)
    transfer = ds.attrs.get("acquisition", {}).get("transfer", "srgb")
    images = np.stack(list(encoded_images(relight(ds, lights, view=views), transfer,
                                          exposure=exposure, ev=ev)))
    write_image(path, images, what="GIF", duration=1000 / fps, loop=0)
    return os.fspath(path)


def encoded_images(images: xr.DataArray, transfer: str, *, exposure: str = CAPTURE,
                   ev: float = 0.0, depth: int | str = 8) -> Iterator[np.ndarray]:
    """Each light's image of ``images`` encoded as
    :func:`ltmstore.core.transfer.encode_images` encodes them all (the same values), each
    block of ``images`` computed once and encoded as it comes.

    Parameters
    ----------
    images : xarray.DataArray
        :func:`relight`'s lazy images, dims ``(light, y, x[, color])``.
    transfer : str
        The capture's transfer function.
    exposure : {"capture", "auto"}
    ev : float
    depth : {8, 16, "float"}
        As :func:`~ltmstore.core.transfer.encode_images`.

    Yields
    ------
    numpy.ndarray
        One light's code values ``(y, x[, color])``, light by light. Every light's code
        values are held, and at the capture's exposure the linear values of the blocks being
        computed (every light of a block at once: the frames are read once); ``auto`` holds
        every light's linear values (float32), its gain being their 99.5th percentile.
    """
    exposure, _ = check_exposure(exposure, ev)
    depth = check_depth(depth)
    images = images.transpose(LIGHT, "y", ...)
    codes = np.empty(images.shape, encode(np.zeros(1, np.float32), transfer, depth).dtype)
    if exposure == AUTO:  # its gain is every light's percentile: their values first
        linear = np.empty(images.shape, np.float32)
        _compute_into(images, linear)
        encoding = _Encoding(codes, np.float32(exposure_gain(linear, exposure, ev)), transfer,
                             depth)
        rows = max(1, ENCODE_BAND_PIXELS // max(images.sizes["x"], 1))
        for start in range(0, images.sizes["y"], rows):  # bounded temporaries
            band = (slice(None), slice(start, start + rows))
            encoding[band] = linear[band]
    else:
        _compute_into(images, _Encoding(codes, np.float32(exposure_gain(np.empty(0), exposure,
                                                                        ev)), transfer, depth))
    yield from codes


@dataclass(frozen=True)
class _Encoding:
    """A target of :func:`dask.array.store`: each block of linear light ``(light, y, x, ...)``
    written to ``codes`` as :func:`~ltmstore.core.transfer.encode` of it times ``gain``."""

    codes: np.ndarray
    gain: np.float32
    transfer: str
    depth: int | str

    def __setitem__(self, key: tuple[slice, ...], linear: np.ndarray) -> None:
        self.codes[key] = encode(np.asarray(linear) * self.gain, self.transfer, self.depth)


def _compute_into(images: xr.DataArray, target) -> None:
    """``images``' values written to ``target[key]`` block by block as they are computed, one
    graph on this process's threads (a block is computed once: bands of rows that split a
    block had computed it again for each, twice at 24 MP; a distributed client's workers
    would fill copies of ``target``)."""
    if images.chunks is None:
        target[(slice(None),) * images.ndim] = images.values
    else:
        da.store(images.data, target, lock=False, scheduler="threads")

