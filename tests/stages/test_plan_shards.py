"""The shards of tiles that a far-light reconstruct writes in one Zarr call each."""

from __future__ import annotations

from dataclasses import replace

import pytest

from ltmstore.stages.plan import plan_tiles


@pytest.mark.parametrize(("image", "side"), [((1000, 1000), 4), ((130, 70), 2), ((64, 64), 1),
                                             ((300, 300), 4)])
def test_shards_cover_every_tile_once_and_their_pixels_whole(image, side):
    plan = plan_tiles(image, (8, 8), tile=64)
    plan = replace(plan, shard_tiles=side)
    blocks = plan.shard_blocks()
    tiles = sorted(t for _, run in blocks for t in run)
    assert tiles == [(i, j) for i in range(plan.grid[0]) for j in range(plan.grid[1])]
    assert plan.shards == (64 * side, 64 * side, 8, 8)
    for (rows, cols), run in blocks:
        first, last = run[0], run[-1]
        assert rows.start == 64 * first[0] and cols.start == 64 * first[1]
        assert rows.start % (64 * side) == 0 and cols.start % (64 * side) == 0  # shard-aligned
        assert rows.stop == min(64 * (last[0] + 1), image[0])
        assert cols.stop == min(64 * (last[1] + 1), image[1])


def test_a_megapixel_is_written_sixteen_tiles_a_shard():
    """1 MP at 8 x 8 cells: 16 x 16 tiles of 64 px, so 4 x 4 tiles a shard leave 16 shards."""
    plan = plan_tiles((1000, 1000), (8, 8), tile=64).with_shards(16)
    assert plan.shard_tiles == 4 and len(plan.shard_blocks()) == 16


def test_a_small_image_keeps_enough_shards_for_the_threads():
    """A coin's 5 x 5 tiles: a tile a shard (4 of 2 x 2 would be too few); 10 x 10 tiles:
    2 x 2 a shard (25 shards; 4 x 4 would leave 9)."""
    assert plan_tiles((300, 300), (8, 8), tile=64).with_shards(16).shard_tiles == 1
    assert plan_tiles((640, 640), (8, 8), tile=64).with_shards(16).shard_tiles == 2
