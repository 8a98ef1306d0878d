"""Where the frame lies on the object plane, for the near-light surface model.

The physical model (:mod:`ltmstore.solve.physical`) needs each pixel's position under the light.
``acquisition.json`` may declare it (``object``: the rectangle the rectified frame shows, ``{"x":
[left, right], "y": [bottom, top]}``, or, in any orientation, the plane positions of three of
its corners); when it does not, :func:`place_object` estimates the frame's map to the plane,
whatever its turn or mirroring, from the binned samples of a few thousand pixels spread over the
frame (:mod:`ltmstore.solve.placement`), then moves it until the surface model's normals are
level on average (:mod:`ltmstore.solve.level`). A declared map is checked against the estimate
(one warning line where they disagree beyond the estimate's uncertainty) and wins.

Where the capture cannot place the object (the lights cover too little of it, or the estimate is
too uncertain to help the model), ``auto`` falls back to the classic methods with one warning
line saying what was measured: a user who declared nothing still gets the LTM the classic
methods give, and learns what to declare to get the better one. ``--method physical``, asked for
by name, is refused with the same line instead.
"""

from __future__ import annotations

import warnings

import numpy as np
import zarr

from ltmstore.core.binning import cell_means
from ltmstore.core.dims import SAMPLES
from ltmstore.core.errors import LtmError, LtmWarning
from ltmstore.solve import Geometry
from ltmstore.solve.level import level_map
from ltmstore.solve.placement import (
    Placement,
    edge_offsets,
    fit_frame,
    frame_corners,
    placement_of,
)
from ltmstore.stages.plan import TilePlan
from ltmstore.stages.resample import Binning

READ_TILES = 8  # at most this many tile rows (and columns) of samples are read ...
READ_LINES = 64  # ... and from them this many pixel rows (columns), spread evenly
# The lights' range must cover this share of the estimated extent: beyond it a pixel's place
# rests on its profile's flank alone (the test capture lit on one side only, 10 %, still
# placed its relief as well as the whole path did: a margin, not a measured limit).
MIN_SUPPORT = 0.25
MAX_SIGMA = 0.05  # an edge less certain than this share of the extent's side is no placement
# The frame's sides on the plane must be this far from parallel (the sine of their angle): a
# frame squeezed flatter than that is no map the pixels' brightest lights can make.
MIN_SINE = 0.5
# Tilted surface regions move the pixels' peaks alike (a frame's bevel, all inwards), which no
# bootstrap over pixels sees: on simulated captures (tests, bench/placement_bench.py) the
# estimated edges lie up to 10 % of the side off beyond the bootstrap's spread where a relief's
# frame bevel covers a quarter of a 32 px frame, 2-3 % at 64 px, 1-1.5 % on a canvas. Each edge's
# uncertainty counts this share of the side as one standard deviation besides the bootstrap's.
SYSTEMATIC = 0.05
AGREE_SIGMAS = 3.0  # a declared edge further than this many uncertainties off: a warning


class PlacementWarning(LtmWarning):
    """The declared object extent disagrees with the capture, or the capture cannot place it."""


def read_pixels(group: zarr.Group, plan: TilePlan) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples ``(n, R * S)`` of up to :data:`READ_LINES` x :data:`READ_LINES` pixels spread
    over the frame, read from at most :data:`READ_TILES` x :data:`READ_TILES` tiles, and their
    rows and columns."""
    def picks(size: int, tile: int) -> np.ndarray:
        tiles = np.unique(np.linspace(0, (size - 1) // tile, READ_TILES).round().astype(int))
        per = -(-READ_LINES // len(tiles))
        return np.concatenate([t * tile + np.unique(np.linspace(
            0, min(tile, size - t * tile) - 1, per).round().astype(int)) for t in tiles])

    rows, cols = picks(plan.image[0], plan.tile[0]), picks(plan.image[1], plan.tile[1])
    block = group[SAMPLES].get_orthogonal_selection((rows, cols)).astype(np.float32)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return block.reshape(len(rows) * len(cols), -1), rr.ravel(), cc.ravel()


def estimate(group: zarr.Group, plan: TilePlan, binning: Binning, r: np.ndarray,
             s: np.ndarray, geometry: Geometry, *, seed: int = 0
             ) -> tuple[Placement | None, dict | None]:
    """The frame's map estimated from the store's samples (see :mod:`ltmstore.solve.placement`),
    levelled by the surface model (:func:`ltmstore.solve.level.level_map`, at ``geometry``'s
    lattice, height and beam), and the levelling's record."""
    values, rows, cols = read_pixels(group, plan)
    finite = np.isfinite(values)
    cells = finite.mean(0) >= 0.95  # the cells (nearly) every pixel saw
    pixels = finite[:, cells].all(1)
    values, rows, cols = values[pixels], rows[pixels], cols[pixels]
    lights = cell_means(binning, r, s)[cells]  # where each cell's samples were taken
    found = fit_frame(values[:, cells], rows, cols, plan.image, lights, geometry.height,
                      seed=seed)
    if found is None:
        return None, None
    fit, level = level_map(values.reshape(len(values), *binning.lattice.shape), rows, cols,
                           plan.image, found[0], geometry, seed=seed)
    return placement_of(fit, plan.image, lights, found[1]), level


def uncertainty(placement: Placement) -> np.ndarray:
    """Each frame edge's uncertainty ``(left, right, bottom, top)``, across the edge: the
    bootstrap's spread and :data:`SYSTEMATIC` of the frame's side across it, together."""
    width, height = placement.sides
    sides = np.array([width, width, height, height])
    boot = np.array(placement.sigma["x"] + placement.sigma["y"])
    return np.hypot(boot, SYSTEMATIC * sides)


def _estimate_record(found: Placement) -> dict:
    """The estimate, its bootstrap ``sigma`` and its full ``uncertainty`` per edge (left, right,
    bottom, top; plane units), the largest of those in pixels."""
    total = uncertainty(found)
    return {**found.to_json(), "uncertainty": total.tolist(),
            "uncertainty_pixels": float(total.max() / min(found.pitch))}


def unsupported(placement: Placement | None, lights_range: str) -> str | None:
    """Why ``placement`` cannot be used (one clause, with what was measured), or None."""
    if placement is None:
        return "too few pixels vary with the light to place them"
    tl, tr, bl = placement.corners
    width, height = placement.sides
    (ax, ay), (bx, by) = tr - tl, bl - tl
    sine = abs(float(ax * by - ay * bx)) / max(width * height, 1e-300)
    if sine < MIN_SINE:
        return ("the pixels' brightest lights do not move along two directions of the frame "
                f"(estimated {describe(placement.extent)})")
    if placement.support < MIN_SUPPORT:
        return (f"the lights ({lights_range}) cover {placement.support:.0%} of the estimated "
                f"extent, at least {MIN_SUPPORT:.0%} needed")
    side = min(width, height)
    if placement.sigma_max > MAX_SIGMA * side:
        return (f"its edges are uncertain by {placement.sigma_max:.3g} plane units "
                f"({placement.sigma_pixels:.1f} px), over {MAX_SIGMA:.0%} of its side")
    return None


def describe(extent: dict) -> str:
    """``x left..right, y bottom..top``, or the three corners of a map in any orientation."""
    if "x" in extent:
        return (f"x {extent['x'][0]:.4g}..{extent['x'][1]:.4g}, "
                f"y {extent['y'][0]:.4g}..{extent['y'][1]:.4g}")
    return ", ".join(f"{k.replace('_', '-')} ({v[0]:.4g}, {v[1]:.4g})" for k, v in extent.items())


def place_object(group: zarr.Group, plan: TilePlan, binning: Binning, r: np.ndarray,
                 s: np.ndarray, height: float, *, method: str,
                 geometry: Geometry | None = None) -> tuple[dict | None, dict]:
    """The object extent the surface model uses, and the stage record of how it was found.

    Parameters
    ----------
    group : zarr.Group
        The store, with complete ``samples``.
    plan : TilePlan
        The run's tiles (which pixels to read).
    binning : Binning
        The frames' cells; ``r``, ``s`` the frames' light positions.
    height : float
        Height of the light plane.
    method : str
        ``auto`` (an unplaceable object: the classic methods, with a warning) or ``physical``
        (refused).
    geometry : Geometry, optional
        The lattice's geometry with the LED's beam and axes, which the estimate is levelled
        with; None: ``binning``'s lattice at ``height``, where the cells' samples were taken,
        the LED level and without a beam.

    Returns
    -------
    extent : dict or None
        The frame's map to the plane: ``{"x": [left, right], "y": [bottom, top]}`` (its columns
        along ``+r``, its rows down ``s``) or, in any orientation, ``{"top_left": [r, s],
        "top_right": [r, s], "bottom_left": [r, s]}`` (its corners; both forms are what
        :func:`ltmstore.core.dims.object_pixels` reads); None: the surface model is left out.
    record : dict
        ``source`` ("declared", "estimated" or "none"), ``extent``, ``estimate`` (the estimate's
        record: the bootstrap's ``sigma`` per frame edge and ``sigma_pixels``, the full
        ``uncertainty`` per edge (left, right, bottom, top; across the edge) in plane units and
        ``uncertainty_pixels``, the ``orientation``: ``model``, ``turn_degrees``,
        ``turn_sigma_degrees``, ``mirrored``; ``levelled``: the levelling's record), and
        ``disagreement`` or ``reason`` where they apply.

    Raises
    ------
    LtmError
        ``method`` is ``physical``, nothing is declared and the capture cannot place the object.
    """
    declared = group.attrs["acquisition"].get("object")
    lights = cell_means(binning, r, s)
    if geometry is None:
        geometry = Geometry(lattice=binning.lattice, height=height, sampled=lights)
    found, level = estimate(group, plan, binning, r, s, geometry)
    lo, hi = np.nanmin(lights, 0), np.nanmax(lights, 0)
    lights_range = f"r {lo[0]:.3g}..{hi[0]:.3g}, s {lo[1]:.3g}..{hi[1]:.3g}"
    why = unsupported(found, lights_range)
    record: dict = {"estimate": None if found is None else {**_estimate_record(found),
                                                            "levelled": level}}
    if declared is not None:
        record.update(source="declared", extent=declared)
        if why is None:
            record["disagreement"] = _check_declared(declared, found)
        else:
            record["reason"] = why
        return declared, record
    if why is None:
        return found.extent, {**record, "source": "estimated", "extent": found.extent}
    message = (f"the object's place on the light plane cannot be estimated from this capture: "
               f"{why}")
    if method == "physical":
        raise LtmError(f"{message}; declare it in acquisition.json ('object': {{'x': [left, "
                       "right], 'y': [bottom, top]}, or in any orientation {'top_left': [r, "
                       "s], 'top_right': [r, s], 'bottom_left': [r, s]}) and ingest again")
    warnings.warn(f"{message}; the surface model is left out (declare 'object' in "
                  "acquisition.json to use it)", PlacementWarning, stacklevel=3)
    return None, {**record, "source": "none", "extent": None, "reason": why}


def _check_declared(declared: dict, found: Placement) -> dict:
    """How far each edge of the declared map lies from the estimate's, across it (either form,
    any orientation); one warning line beyond :data:`AGREE_SIGMAS` uncertainties."""
    diff = edge_offsets(frame_corners(declared), found.corners)
    sigmas = diff / uncertainty(found)
    worst = int(np.argmax(sigmas))
    out = {"max_plane": float(np.abs(diff).max()), "max_sigmas": float(sigmas[worst]),
           "agrees": bool(sigmas[worst] <= AGREE_SIGMAS)}
    if not out["agrees"]:
        edge = ("left", "right", "bottom", "top")[worst]
        warnings.warn(f"the object extent declared in acquisition.json ({describe(declared)}) "
                      f"disagrees with the one the capture shows ({describe(found.extent)}): "
                      f"its {edge} edge by {abs(diff[worst]):.3g} plane units, "
                      f"{sigmas[worst]:.1f} times the estimate's uncertainty; the declared one "
                      "is used", PlacementWarning, stacklevel=3)
    return out
