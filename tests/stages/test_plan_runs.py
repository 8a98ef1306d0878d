"""The runs of tiles that a far-light reconstruct writes in one Zarr call each."""

from __future__ import annotations

import math

import pytest

from ltmstore.stages.plan import plan_tiles


@pytest.mark.parametrize(("image", "max_bytes"), [((1000, 1000), 16 * 2**20),
                                                  ((130, 70), 3 * 2**20), ((64, 64), 1)])
def test_runs_cover_every_tile_once_within_a_row_and_the_bound(image, max_bytes):
    plan = plan_tiles(image, (8, 8), tile=64)
    runs = plan.row_runs(max_bytes)
    tile_bytes = 4 * math.prod(plan.block)
    assert [t for run in runs for t in run] == [(i, j) for i in range(plan.grid[0])
                                                 for j in range(plan.grid[1])]
    for run in runs:
        assert len({i for i, _ in run}) == 1
        assert len(run) == 1 or len(run) * tile_bytes <= max_bytes
        rows, cols = plan.region(run)
        (i, first), last = run[0], run[-1][1]
        assert (rows.start, rows.stop) == (64 * i, min(64 * (i + 1), image[0]))
        assert (cols.start, cols.stop) == (64 * first, min(64 * (last + 1), image[1]))


def test_a_megapixel_is_written_a_tile_row_at_a_time():
    """1 MP at 8 x 8 cells: 1 MiB a tile, so 16 MiB takes a whole row of 16 tiles a call."""
    assert len(plan_tiles((1000, 1000), (8, 8), tile=64).row_runs(16 * 2**20, 16)) == 16


def test_a_small_image_keeps_enough_runs_for_the_threads():
    """A coin's 5 x 5 tiles, at least 16 runs asked: a tile a run, not a row a run; 10 x 10
    tiles: six a run (two runs a row)."""
    assert len(plan_tiles((300, 300), (8, 8), tile=64).row_runs(16 * 2**20, 16)) == 25
    runs = plan_tiles((640, 640), (8, 8), tile=64).row_runs(16 * 2**20, 16)
    assert [len(run) for run in runs] == [6, 4] * 10
