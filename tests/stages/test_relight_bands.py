"""A far-light store's surface model is relit in bands of rows: the same image as one band,
in memory that follows the band, not the image (issue 64 item 13)."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest
from dome_helpers import RINGS, flash, write_capture

from ltmstore.core.store import open_store
from ltmstore.stages import relight as rl
from ltmstore.stages import surface as sf
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct

DIRECTIONS = np.array([[0.3, 0.2, 1.0], [-0.4, 0.1, 0.8], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def far_store(tmp_path_factory):
    """A small dome capture (flickering flash) whose default fit is the surface model."""
    tmp = tmp_path_factory.mktemp("bands")
    lp = write_capture(tmp / "capture", flash(sum(RINGS.values())), shape=(40, 36))
    ingest_rti(lp, tmp / "s.zarr", progress=False)
    reconstruct(tmp / "s.zarr", progress=False)
    ds = open_store(tmp / "s.zarr")
    methods = ds[rl.METHOD_MAP].attrs["methods"]
    assert any(methods[c].startswith(sf.PREFIX) for c in np.unique(ds[rl.METHOD_MAP].values))
    return tmp / "s.zarr"


@pytest.mark.parametrize("color", [True, False])
def test_bands_of_one_row_give_the_image_of_one_band(far_store, monkeypatch, color):
    ds = open_store(far_store)
    whole = rl.relight(ds, directions=DIRECTIONS, color=color)
    monkeypatch.setattr(rl, "BAND_BYTES", 1)  # one row a band
    banded = rl.relight(ds, directions=DIRECTIONS, color=color)
    assert banded.chunks[1] != whole.chunks[1] and len(banded.chunks[1]) == ds.sizes["y"]
    np.testing.assert_array_equal(banded.values, whole.values)  # bit for bit
    assert np.isfinite(whole.values).all()


def _band_peak(store, band_bytes: int, monkeypatch) -> int:
    """Peak bytes Python allocated (tracemalloc) while ``store`` is relit at one light in bands
    of ``band_bytes``, on one thread."""
    import dask

    ds = open_store(store)
    monkeypatch.setattr(rl, "BAND_BYTES", band_bytes)
    image = rl.relight(ds, directions=DIRECTIONS[:1], color=True)
    with dask.config.set(scheduler="synchronous"):
        image.data.compute()  # what a first call imports, compiles or caches: not traced
        gc.collect()  # nor the garbage earlier tests left for the collector
        tracemalloc.start()
        try:
            image.data.compute()
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()


def test_memory_follows_the_band_not_the_image(far_store, monkeypatch):
    """Relighting reads the 47 photographs and renders the surface model at their lights,
    about 7.5 kB a pixel at once: in bands of about a quarter of the image's rows the peak is
    about a quarter of the whole image's, plus the graph's own (which grows with the number
    of bands: bands of one row peak higher than bands of four)."""
    whole = _band_peak(far_store, 2**40, monkeypatch)
    quarter = _band_peak(far_store, 10 * 48 * 36 * 3 * 4, monkeypatch)  # bands of 10 rows
    # measured: whole image (40 x 36 pixels) 10.8 MB, bands of 10 rows 3.4 MB (0.32 of it)
    assert quarter < 0.4 * whole, (quarter, whole)


def test_a_strided_region_takes_its_own_tiles_models(far_store):
    """Each pixel is relit by the model of the tile it lies in, wherever the store passed to
    relight starts and however it is strided (ltm view's preview, the web export's sample):
    with a model per 8 x 8 tile alternating between the surface blend and a PTM, a region
    strided by 3 relights as the whole image does there."""
    ds = open_store(far_store)
    chosen = ds[rl.METHOD_MAP]
    names = chosen.attrs["methods"]
    blend, ptm = names.index(_blend(ds).name), names.index("ptm")
    tiles = (-(-ds.sizes["y"] // 8), -(-ds.sizes["x"] // 8))
    checker = np.where(np.add.outer(*map(np.arange, tiles)) % 2, blend, ptm).astype(np.int16)
    ds[rl.METHOD_MAP] = (chosen.dims, checker, {**chosen.attrs, "tile": [8, 8]})
    region = {"y": slice(5, None, 3), "x": slice(1, 30, 3)}
    whole = rl.relight(ds, directions=DIRECTIONS).isel(region)
    strided = rl.relight(ds.isel(region), directions=DIRECTIONS)
    np.testing.assert_allclose(strided.values, whole.values, rtol=0, atol=1e-6)


def _blend(ds) -> sf.Blend:
    chosen = ds[rl.METHOD_MAP]
    names = [chosen.attrs["methods"][int(c)] for c in np.unique(chosen.values)]
    return sf.Blend.from_name(next(n for n in names if n.startswith(sf.PREFIX)))
