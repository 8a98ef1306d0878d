"""What :func:`ltmstore.stages.placement.place_object` takes, from a resampled store (the
placement tests of ``tests/solve`` and ``tests/stages``)."""

from __future__ import annotations

from pathlib import Path

import zarr


def placement_inputs(store: Path) -> tuple:
    """The store's group (writable), tile plan, binning and light positions ``r``, ``s``."""
    from ltmstore.core.dims import Lattice
    from ltmstore.stages.plan import plan_tiles
    from ltmstore.stages.resample import bin_positions

    group = zarr.open_group(store, mode="r+")
    rec = group.attrs["stages"]["resample"]["lattice"]
    lat = Lattice(bounds=tuple(map(tuple, rec["bounds"])), shape=tuple(rec["shape"]))
    r, s = group["pose_r"][:], group["pose_s"][:]
    binning = bin_positions(lat, (r, s), group["pose_valid"][:])
    plan = plan_tiles(group["frames"].shape[1:], lat.shape, tile=32)
    return group, plan, binning, r, s
