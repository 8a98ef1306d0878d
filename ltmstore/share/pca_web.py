"""Relight's ``bilinear`` web format carrying the store's own relighting (``ltm export --format
relight --basis bilinear``).

The classic bases (PTM, HSH) are fitted to the store and lose its highlights and shadows. This
basis is the store itself: it is relit (:func:`ltmstore.relight`, band by band of rows) at the
nodes of Relight's octahedral light grid, encoded for display at the capture's exposure as
``ltm relight`` writes it (no rescale), and compressed by PCA over each pixel's colours at all
nodes, as Relight's ``RtiBuilder`` does for its ``rbf`` and ``bilinear`` types with colour space
``mrgb``. A viewer interpolates the grid bilinearly at any light and adds the planes' weighted
eigenvectors to the mean.

Layout (readers: OpenLIME ``ShaderRTI`` ``BLN.lightWeights`` + ``MRGB.render`` + ``loadBasis``,
Relight ``Rti::load``/``lightWeightsBilinear``; writer: Relight ``RtiBuilder::saveJSON``):

* grid node ``(i, j)``, ``i, j`` in ``0 .. R-1``: ``x = 2 i / (R - 1) - 1``, ``y = 2 j / (R - 1) -
  1``; the light ``l`` with ``s = |lx| + |ly| + |lz|`` has ``x = (lx + ly) / s``, ``y = (ly - lx)
  / s`` (a 45 degree turn of the octahedral map: the upper hemisphere fills the square);
* ``basis``: ``(nplanes + 1) * R^2 * 3`` bytes, offset ``(p R^2 + i + j R) 3 + k`` for plane
  ``p``, node ``(i, j)`` and channel ``k``; plane 0 is the mean (byte / 255), plane ``p >= 1`` an
  eigenvector (``(byte - 127) / range[p - 1]``);
* ``plane_<j>.jpg``: PCA coefficients ``3 j + k`` in channel ``k``; a texel ``t`` in ``[0, 1]``
  means ``(t - bias) * scale``;
* the colour is ``mean + sum_p coefficient_p * eigenvector_p`` at the light, sRGB-encoded
  (``"colorprofile": "sRGB"``).

Quantisation follows Relight's: one ``range`` per eigenvector (``127 / max |e|``), one ``scale``
and ``bias`` per plane. The coefficients are then refitted by least squares to the quantised
mean and eigenvectors, so that they absorb the basis's rounding.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import dask.array as da
import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.core.transfer import linear_to_srgb
from ltmstore.share import jpeg_quality
from ltmstore.share.fidelity import Checkpoints, banded
from ltmstore.share.relight_web import DEFAULT_QUALITY

if TYPE_CHECKING:
    import xarray as xr

DEFAULT_RESOLUTION = 16  # grid nodes per side: 256 light directions
DEFAULT_PLANES = 27  # PCA planes (9 JPEG images)
RESOLUTIONS = (4, 32)  # the least and the most nodes per side
MAX_PLANES = 48
MIN_ELEVATION_Z = 0.02  # grid nodes on the horizon are relit a hair above it
SAMPLE_PIXELS = 2**15  # at most this many pixels for the PCA's covariance


def grid_directions(resolution: int) -> np.ndarray:
    """Unit light directions ``(R^2, 3)`` of the octahedral grid nodes, node ``(i, j)`` at row
    ``i + j R`` (the order of Relight's and OpenLIME's ``basePixelOffset``)."""
    t = np.linspace(-1.0, 1.0, resolution)
    x, y = np.meshgrid(t, t, indexing="xy")  # x varies along a row: index i + j R
    lx, ly = (x - y) / 2, (x + y) / 2
    lz = np.maximum(1 - np.abs(lx) - np.abs(ly), MIN_ELEVATION_Z)
    d = np.column_stack([lx.ravel(), ly.ravel(), lz.ravel()])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def node_weights(directions: np.ndarray, resolution: int) -> np.ndarray:
    """Bilinear weights ``(n, R^2)`` of the grid nodes at unit light ``directions (n, 3)``, as
    the viewers compute them (OpenLIME ``setLight`` + ``BLN.lightWeights``)."""
    d = np.asarray(directions, np.float64)
    x, y = d[:, 0].copy(), d[:, 1].copy()
    r = np.hypot(x, y)
    shrink = np.where(r > 1, 1 / np.maximum(r, 1e-300), 1.0)  # to the unit disk
    x, y = x * shrink, y * shrink
    z = np.sqrt(np.maximum(0.0, 1 - x * x - y * y))
    s = np.abs(x) + np.abs(y) + z
    u = ((x + y) / s + 1) / 2 * (resolution - 1)
    v = ((y - x) / s + 1) / 2 * (resolution - 1)
    su = np.clip(np.floor(u), 0, resolution - 2).astype(int)
    sv = np.clip(np.floor(v), 0, resolution - 2).astype(int)
    du, dv = u - su, v - sv
    w = np.zeros((len(d), resolution * resolution))
    rows = np.arange(len(d))
    for (i, j), weight in (((0, 0), (1 - du) * (1 - dv)), ((1, 0), du * (1 - dv)),
                           ((0, 1), (1 - du) * dv), ((1, 1), du * dv)):
        np.add.at(w, (rows, su + i + (sv + j) * resolution), weight)
    return w


def evaluate(coef: np.ndarray, mean: np.ndarray, vectors: np.ndarray, resolution: int,
             directions: np.ndarray) -> np.ndarray:
    """Display values ``(n, y, x, 3)`` of coefficients ``(y, x, P)`` with the mean ``(D,)`` and
    eigenvectors ``(D, P)`` a viewer reads, at ``directions (n, 3)``."""
    w = node_weights(directions, resolution)
    m = w @ mean.reshape(-1, 3)  # (n, 3)
    b = np.einsum("ln,nkp->lkp", w, vectors.reshape(resolution ** 2, 3, -1))
    return m[:, None, None, :] + np.einsum("yxp,lkp->lyxk", coef, b)


def check(resolution: int, planes: int) -> None:
    """Refuse a grid resolution or a number of planes the format cannot hold."""
    lo, hi = RESOLUTIONS
    if not lo <= resolution <= hi:
        raise LtmError(f"--resolution {resolution!r} must be from {lo} to {hi} grid nodes a side")
    if not (3 <= planes <= MAX_PLANES and planes % 3 == 0):
        raise LtmError(f"--planes {planes!r} must be a multiple of 3 from 3 to {MAX_PLANES}")


def _display(linear: np.ndarray, transfer: str) -> np.ndarray:
    """Relit linear light to display values in ``[0, 1]`` at the capture's exposure, as
    :func:`ltmstore.core.transfer.encode` writes them, unrounded."""
    v = linear_to_srgb(np.maximum(linear, 0)) if transfer == "srgb" else linear
    return np.clip(v, 0.0, 1.0).astype(np.float32)


@dataclass
class _Projection:
    """A target of :func:`dask.array.store`: each block of relit linear light ``(light, y, x,
    color)`` written to ``coef``'s pixels as its display values' coefficients."""

    coef: np.ndarray  # (y, x, P)
    mean: np.ndarray  # (D,)
    project: np.ndarray  # (D, P)
    transfer: str

    def __setitem__(self, key: tuple[slice, ...], linear: np.ndarray) -> None:
        v = _display(linear, self.transfer)
        pixels = np.ascontiguousarray(v.transpose(1, 2, 0, 3)).reshape(-1, v.shape[0] * 3)
        self.coef[key[1], key[2]] = ((pixels - self.mean) @ self.project).reshape(
            v.shape[1], v.shape[2], -1)


class _Renderer:
    """A store relit at the grid's directions, as display values ``(pixels, R^2 * 3)``."""

    def __init__(self, store: str | os.PathLike, directions: np.ndarray) -> None:
        self.ds, self.directions = open_store(store), directions
        self.transfer = self.ds.attrs.get("acquisition", {}).get("transfer", "srgb")
        self.relit = self._relit(self.ds)
        self.shape = (self.ds.sizes["y"], self.ds.sizes["x"])

    def _relit(self, ds: xr.Dataset) -> xr.DataArray:
        """``ds`` relit at the grid's directions, lazily."""
        from ltmstore.stages.relight import relight  # share sits above stages

        with warnings.catch_warnings():  # nodes far from the lights are the model's own
            warnings.simplefilter("ignore")  # extrapolation: that is what the grid asks
            return relight(ds, directions=self.directions)

    def project(self, mean: np.ndarray, project: np.ndarray) -> np.ndarray:
        """Every pixel's coefficients ``(y, x, P)``: ``project (P, D)`` applied to its display
        values less ``mean (D,)``, block by block as the relighting computes them (one graph
        computed once: a graph per band of rows had been culled again for each band, minutes
        at 24 MP)."""
        coef = np.empty((*self.shape, len(project)), np.float32)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            da.store(self.relit.data, _Projection(coef, mean.astype(np.float32),
                                                  project.T.copy(), self.transfer), lock=False)
        return coef

    def sample(self) -> np.ndarray:
        """Display values of a regular subsample of at most ``SAMPLE_PIXELS`` pixels: the
        store strided to every k-th pixel both ways and relit there only (rows picked one by
        one had the relighting compute the whole band of rows each lies in)."""
        step = max(1, int(np.ceil(np.sqrt(self.shape[0] * self.shape[1] / SAMPLE_PIXELS))))
        strided = slice(step // 2, None, step)
        relit = self._relit(self.ds.isel(y=strided, x=strided))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = _display(relit.values, self.transfer)  # (light, y, x, color)
        return np.ascontiguousarray(v.transpose(1, 2, 0, 3)).reshape(-1, v.shape[0] * 3)


def principal(sample: np.ndarray, planes: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(D,)`` and the ``planes`` leading eigenvectors ``(D, planes)`` of the sample's
    covariance (pixels ``(n, D)``), largest first."""
    mean = sample.mean(axis=0, dtype=np.float64)
    centred = sample - mean.astype(np.float32)
    cov = centred.T.astype(np.float64) @ centred.astype(np.float64)
    values, vectors = np.linalg.eigh(cov)
    keep = np.argsort(values)[::-1][:planes]
    return mean, vectors[:, keep]


def quantised_basis(mean: np.ndarray, vectors: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Relight's bytes of the mean and eigenvectors, their ``range`` per eigenvector, and the
    values a viewer reads back from them (mean ``(D,)``, eigenvectors ``(D, P)``)."""
    mean_bytes = np.clip(np.round(mean * 255), 0, 255)
    peak = np.maximum(np.abs(vectors).max(axis=0), 1e-12)
    rng = 127 / peak
    vec_bytes = np.clip(np.round(vectors * rng + 127), 0, 255)
    return (np.concatenate([mean_bytes[None], vec_bytes.T]).astype(np.uint8), rng,
            mean_bytes / 255, (vec_bytes - 127) / rng)


def write(store: str | os.PathLike, folder: str | os.PathLike, *,
          resolution: int = DEFAULT_RESOLUTION, planes: int = DEFAULT_PLANES,
          quality: int | None = None, checkpoints: Checkpoints | None = None) -> dict:
    """Relight the store at the grid's nodes and write Relight's ``bilinear`` web format.

    Parameters
    ----------
    store : path-like
        A reconstructed store.
    folder : path-like
        An existing empty folder: ``info.json`` and ``plane_<j>.jpg`` are written into it.
    resolution : int
        Grid nodes per side (``resolution^2`` light directions).
    planes : int
        PCA planes, a multiple of 3.
    quality : int, optional
        JPEG quality of the planes; default: chosen at the ``checkpoints``
        (:func:`ltmstore.share.jpeg_quality.choose`), else Relight's default, 95.
    checkpoints : Checkpoints, optional
        Lights and ``ltm relight``'s images there (:func:`ltmstore.share.fidelity.checkpoints`)
        to choose the quality by and to evaluate the written file at (its quantised basis and
        its planes as decoded from the JPEG files).

    Returns
    -------
    dict
        ``width``, ``height``, ``directions`` (grid nodes), ``planes``, ``quality`` and, with
        ``checkpoints``, ``images``: 8-bit display values ``(n, y, x, 3)`` at their lights;
        where the quality was chosen, ``jpeg`` (:func:`ltmstore.share.jpeg_quality.choose`'s
        record).
    """
    check(resolution, planes)
    folder = Path(folder)
    render = _Renderer(store, grid_directions(resolution))
    mean, vectors = principal(render.sample(), planes)
    basis_bytes, rng, mean_q, vec_q = quantised_basis(mean, vectors)
    project = np.linalg.pinv(vec_q).astype(np.float32)  # (P, D): least squares on the bytes
    height, width = render.shape
    coef = render.project(mean_q, project)
    lo, hi = coef.reshape(-1, planes).min(axis=0), coef.reshape(-1, planes).max(axis=0)
    scale = np.where(hi > lo, hi - lo, 1e-6)
    coef -= lo  # in place, as (coef - lo) / scale * 255 rounded: no float copies at 24 MP
    coef /= scale
    coef *= 255
    codes = np.clip(np.round(coef, out=coef), 0, 255, out=coef).astype(np.uint8)
    del coef

    def images(part: np.ndarray) -> np.ndarray:  # 8-bit images at the checkpoints' lights
        return banded(lambda rows: evaluate(part[rows] / np.float32(255) * scale + lo, mean_q,
                                            vec_q, resolution, checkpoints.directions),
                      part.shape[:2], len(checkpoints.directions))

    choice = None
    if quality is None and checkpoints is not None:
        wy, wx = jpeg_quality.window((height, width))
        quality, choice = jpeg_quality.choose(codes[wy, wx], images,
                                              checkpoints.store[:, wy, wx])
    quality = DEFAULT_QUALITY if quality is None else int(quality)
    for j in range(planes // 3):
        data = jpeg_quality.encode(codes[:, :, 3 * j:3 * j + 3], quality)
        (folder / f"plane_{j}.jpg").write_bytes(data)
        codes[:, :, 3 * j:3 * j + 3] = jpeg_quality.decode(data)  # as a viewer decodes it
    info = {"width": width, "height": height, "format": "jpg", "type": "bilinear",
            "resolution": int(resolution), "colorspace": "mrgb", "nplanes": int(planes),
            "quality": quality, "colorprofile": "sRGB",
            "basis": basis_bytes.ravel().tolist(),
            "materials": [{"range": rng.tolist(), "scale": scale.tolist(),
                           "bias": (-lo / scale).tolist()}]}
    (folder / "info.json").write_text(json.dumps(info, separators=(",", ":")))
    out = {"width": width, "height": height, "directions": resolution ** 2, "planes": planes,
           "quality": quality}
    if choice is not None:
        out["jpeg"] = choice
    if checkpoints is not None:
        out["images"] = images(codes)
    return out
