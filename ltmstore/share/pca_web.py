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
from ltmstore.share import jpeg_quality, light_grid
from ltmstore.share.fidelity import Checkpoints, banded, display_images, psnr
from ltmstore.share.light_grid import grid_directions, node_weights
from ltmstore.share.relight_web import DEFAULT_QUALITY

if TYPE_CHECKING:
    import xarray as xr

PLANES = (27, 36, 48)  # PCA planes (9, 12, 16 JPEG images) tried in this order
MAX_PCA_LOSS_DB = 0.25  # the most the PCA may cost against the held-out photographs
RESOLUTION_LIMITS = (4, 64)  # the least and the most nodes a side (the viewers take any)
MAX_PLANES = PLANES[-1]
SAMPLE_PIXELS = 2**15  # at most this many pixels for the PCA's covariance
EIGH_MAX_VALUES = 1024  # up to this many values a pixel, the covariance is decomposed whole


def evaluate(coef: np.ndarray, mean: np.ndarray, vectors: np.ndarray, resolution: int,
             directions: np.ndarray) -> np.ndarray:
    """Display values ``(n, y, x, 3)`` of coefficients ``(y, x, P)`` with the mean ``(D,)`` and
    eigenvectors ``(D, P)`` a viewer reads, at ``directions (n, 3)``."""
    w = node_weights(directions, resolution)
    m = w @ mean.reshape(-1, 3)  # (n, 3)
    b = np.einsum("ln,nkp->lkp", w, vectors.reshape(resolution ** 2, 3, -1))
    return m[:, None, None, :] + np.einsum("yxp,lkp->lyxk", coef, b, optimize=True)  # BLAS: 3x


def check(resolution: int | None, planes: int | None) -> None:
    """Refuse a grid resolution or a number of planes the format cannot hold (None: chosen by
    :func:`write`)."""
    lo, hi = RESOLUTION_LIMITS
    if resolution is not None and not lo <= resolution <= hi:
        raise LtmError(f"--resolution {resolution!r} must be from {lo} to {hi} grid nodes a side")
    if planes is not None and not (3 <= planes <= MAX_PLANES and planes % 3 == 0):
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
    """A store relit at light directions, as display values."""

    def __init__(self, store: str | os.PathLike) -> None:
        self.ds = open_store(store)
        self.transfer = self.ds.attrs.get("acquisition", {}).get("transfer", "srgb")
        self.shape = (self.ds.sizes["y"], self.ds.sizes["x"])

    @staticmethod
    def _relit(ds: xr.Dataset, directions: np.ndarray) -> xr.DataArray:
        """``ds`` relit at ``directions``, lazily."""
        from ltmstore.stages.relight import relight  # share sits above stages

        with warnings.catch_warnings():  # nodes far from the lights are the model's own
            warnings.simplefilter("ignore")  # extrapolation: that is what the grid asks
            return relight(ds, directions=directions)

    def _display(self, ds: xr.Dataset, directions: np.ndarray) -> np.ndarray:
        """Display values ``(light, y, x, color)`` of ``ds`` relit at ``directions``."""
        relit = self._relit(ds, directions)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _display(relit.values, self.transfer)

    def window(self, directions: np.ndarray) -> np.ndarray:
        """Display values ``(light, y, x, color)`` of the window
        :func:`ltmstore.share.light_grid.window` relit at ``directions``."""
        wy, wx = light_grid.window(self.shape)
        return self._display(self.ds.isel(y=wy, x=wx), directions)

    def project(self, directions: np.ndarray, mean: np.ndarray, project: np.ndarray
                ) -> np.ndarray:
        """Every pixel's coefficients ``(y, x, P)``: ``project (P, D)`` applied to its display
        values at ``directions`` less ``mean (D,)``, block by block as the relighting computes
        them (one graph computed once: a graph per band of rows had been culled again for each
        band, minutes at 24 MP)."""
        coef = np.empty((*self.shape, len(project)), np.float32)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            da.store(self._relit(self.ds, directions).data,
                     _Projection(coef, mean.astype(np.float32), project.T.copy(),
                                 self.transfer), lock=False)
        return coef

    @property
    def strided(self) -> slice:
        """The rows and the columns :meth:`sample` takes: every k-th, at most
        ``SAMPLE_PIXELS`` pixels."""
        step = max(1, int(np.ceil(np.sqrt(self.shape[0] * self.shape[1] / SAMPLE_PIXELS))))
        return slice(step // 2, None, step)

    def sample(self, directions: np.ndarray) -> np.ndarray:
        """Display values ``(pixels, n * 3)`` at ``directions`` of a regular subsample of at most
        ``SAMPLE_PIXELS`` pixels: the store strided to every k-th pixel both ways and relit
        there only (rows picked one by one had the relighting compute the whole band of rows
        each lies in)."""
        v = self._display(self.ds.isel(y=self.strided, x=self.strided), directions)
        return np.ascontiguousarray(v.transpose(1, 2, 0, 3)).reshape(-1, v.shape[0] * 3)


def principal(sample: np.ndarray, planes: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(D,)`` and the ``planes`` leading eigenvectors ``(D, planes)`` of the sample's
    covariance (pixels ``(n, D)``), largest first; a constant sample gives vectors that carry
    nothing.

    Up to :data:`EIGH_MAX_VALUES` values a pixel (a grid of up to 18 nodes a side) the
    covariance is decomposed whole (exact; the coin's 20,016 x 768 sample in 0.7 s against 2.1
    s and scikit-learn's import, 1-3 s); above, where that takes minutes (D = 6,912 at 48 nodes a
    side), the leading right singular vectors of the centred sample come from
    :func:`sklearn.utils.extmath.randomized_svd`.
    """
    mean = sample.mean(axis=0, dtype=np.float64)
    centred = sample - mean.astype(np.float32)
    k = min(planes, *centred.shape)
    if centred.shape[1] <= EIGH_MAX_VALUES:
        _, vectors = np.linalg.eigh((centred.T @ centred).astype(np.float64))
        vectors = vectors[:, ::-1][:, :k]
    else:
        from sklearn.utils.extmath import randomized_svd  # 1-3 s to import

        _, _, vt = randomized_svd(centred, k, n_oversamples=20, n_iter=7, random_state=0)
        vectors = vt.T.astype(np.float64)
    if k < planes:  # fewer pixels than planes: the rest carry nothing
        vectors = np.pad(vectors, ((0, 0), (0, planes - k)))
    return mean, vectors


def choose_planes(sample: np.ndarray, mean: np.ndarray, vectors: np.ndarray, resolution: int,
                  check: Checkpoints, strided: slice) -> tuple[int, dict]:
    """The fewest of :data:`PLANES` whose PCA costs at most :data:`MAX_PCA_LOSS_DB`.

    Parameters
    ----------
    sample : ndarray, shape (pixels, D)
        Display values of the sampled pixels at the grid's nodes.
    mean, vectors : ndarray
        The sample's mean ``(D,)`` and leading eigenvectors ``(D, max(PLANES))``.
    resolution : int
        The grid's nodes a side.
    check : Checkpoints
        The held-out lights with their photographs.
    strided : slice
        The rows and the columns of the sample.

    Returns
    -------
    planes : int
        The number chosen (the most where none is within the bound).
    record : dict
        ``planes``, ``max_loss_db`` and ``loss_db``: each number tried and what its PCA cost
        on the sampled pixels at the held-out lights, in dB against the photographs, beside the
        grid's nodes drawn exactly.
    """
    photos = check.photos[:, strided, strided].reshape(len(check.photos), -1, 1, 3)
    coef = ((sample - mean) @ vectors)[:, None, :]  # (pixels, 1, P)

    weights = node_weights(check.directions, resolution)
    used = np.flatnonzero(weights.any(axis=0))  # at most 4 nodes a light (48 a side: 7 s whole)
    grid = display_images(np.einsum("ln,ink->lik", weights[:, used], sample.reshape(
        len(sample), resolution ** 2, 3)[:, used]))[:, :, None, :]
    reference = psnr(grid, photos)
    losses: dict[int, float] = {}
    for planes in PLANES:
        images = evaluate(coef[..., :planes], mean, vectors[:, :planes], resolution,
                          check.directions)
        losses[planes] = round(reference - psnr(display_images(images), photos), 3)
        if losses[planes] <= MAX_PCA_LOSS_DB:
            break
    return planes, {"planes": planes, "max_loss_db": MAX_PCA_LOSS_DB, "loss_db": losses}


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
          resolution: int | None = None, planes: int | None = None,
          quality: int | None = None, checkpoints: Checkpoints | None = None) -> dict:
    """Relight the store at the grid's nodes and write Relight's ``bilinear`` web format.

    Parameters
    ----------
    store : path-like
        A reconstructed store.
    folder : path-like
        An existing empty folder: ``info.json`` and ``plane_<j>.jpg`` are written into it.
    resolution : int, optional
        Grid nodes per side (``resolution^2`` light directions); default: chosen at the
        ``checkpoints`` (:func:`ltmstore.share.light_grid.choose`), else the smallest of
        :data:`ltmstore.share.light_grid.RESOLUTIONS`.
    planes : int, optional
        PCA planes, a multiple of 3; default: chosen at the held-out lights of the
        ``checkpoints`` (:func:`choose_planes`), else the fewest of :data:`PLANES`.
    quality : int, optional
        JPEG quality of the planes; default: chosen at the ``checkpoints``
        (:func:`ltmstore.share.jpeg_quality.choose`), else Relight's default, 95.
    checkpoints : Checkpoints, optional
        Lights and ``ltm relight``'s images there (:func:`ltmstore.share.fidelity.checkpoints`)
        to choose the grid and the quality by and to evaluate the written file at (its
        quantised basis and its planes as decoded from the JPEG files).

    Returns
    -------
    dict
        ``width``, ``height``, ``directions`` (grid nodes), ``planes``, ``quality`` and, with
        ``checkpoints``, ``images``: 8-bit display values ``(n, y, x, 3)`` at their lights;
        where the quality was chosen, ``jpeg`` (:func:`ltmstore.share.jpeg_quality.choose`'s
        record); where the grid was chosen, ``grid`` (:func:`ltmstore.share.light_grid.choose`'s
        record); where the planes were, ``pca`` (:func:`choose_planes`'s record).
    """
    check(resolution, planes)
    folder = Path(folder)
    render = _Renderer(store)
    grid = None
    if resolution is None and checkpoints is not None:
        resolution, grid = light_grid.choose(render.window, checkpoints, render.shape)
    elif resolution is None:
        resolution = light_grid.RESOLUTIONS[0]
    directions = grid_directions(resolution)
    sample = render.sample(directions)
    pca = None
    if planes is None and checkpoints is not None and checkpoints.photos is not None:
        mean, vectors = principal(sample, PLANES[-1])
        planes, pca = choose_planes(sample, mean, vectors, resolution, checkpoints,
                                    render.strided)
        vectors = vectors[:, :planes]
    else:
        planes = PLANES[0] if planes is None else planes
        mean, vectors = principal(sample, planes)
    del sample
    basis_bytes, rng, mean_q, vec_q = quantised_basis(mean, vectors)
    project = np.linalg.pinv(vec_q).astype(np.float32)  # (P, D): least squares on the bytes
    height, width = render.shape
    coef = render.project(directions, mean_q, project)
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
    if grid is not None:
        out["grid"] = grid
    if pca is not None:
        out["pca"] = pca
    if checkpoints is not None:
        out["images"] = images(codes)
    return out
