"""A pixel tile's done-mark is written after its data: a tile whose data write failed (a full
disk, a killed process) is never marked done, so a resumed run solves it again."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from ltmstore.core.dims import LTM
from ltmstore.solve import Geometry
from ltmstore.stages.reconstruct import TILES, _read_marks, _solve_tile


class FullDisk:
    """An array whose every write fails, as on a full disk."""

    def __setitem__(self, key, value) -> None:
        raise OSError(28, "No space left on device")


def test_a_tile_whose_data_write_fails_is_not_marked_done(tmp_path):
    marks = zarr.create_array(str(tmp_path / "marks.zarr"), shape=(1, 2), chunks=(1, 1),
                              dtype=str, fill_value="")
    samples = np.full((2, 2, 4, 4), np.nan, dtype=np.float32)
    samples[..., ::2, ::2] = 1.0
    with pytest.raises(OSError, match="No space left"):  # tile (0, 1): pixels (0, 2) on
        _solve_tile(samples, (0, 1), (0, 2), (2, 4), out={LTM: FullDisk(), TILES: marks},
                    method="cs", params={}, geometry=Geometry.from_shape((4, 4)), auto=False)
    assert (_read_marks(marks) == "").all()  # a resume solves the tile again
