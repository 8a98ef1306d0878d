"""`ltm compact --form factored`: a per-tile basis and per-pixel weights in place of the dense
LTM; `ltm` reads back lazily within the recorded SNR, relights the same within it, a damaged
factor is refused, and the factors take fewer bytes than the dense LTM."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from pipeline_helpers import run_ltm

from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store, store_summary
from ltmstore.stages.relight import disk_light, relight

LIGHTS = [(-0.05, 0.03), (0.08, -0.11), (0.0, 0.0)]


def snr_db(reference: np.ndarray, estimate: np.ndarray) -> float:
    reference = np.asarray(reference, np.float64)
    return float(10 * np.log10(np.sum(reference ** 2) / np.sum((reference - estimate) ** 2)))


def folder_bytes(path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


@pytest.fixture(scope="session")
def factored_store(small_store, tmp_path_factory):
    """The session's store compacted to the factored form (16 x 16 pixel tiles: 4 tiles)."""
    from ltmstore.stages.compact import compact

    store = tmp_path_factory.mktemp("factored") / "store.zarr"
    shutil.copytree(small_store, store, copy_function=os.link)
    info = compact(store, form="factored", tile=16)
    return store, info


def test_factored_ltm_equals_the_dense_one_within_its_recorded_snr(factored_store, small_store):
    store, info = factored_store
    dense, ds = open_store(small_store), open_store(store)
    assert "ltm" not in os.listdir(store) and "ltm_by_light" not in os.listdir(store)
    assert ds["ltm"].dims == ("y", "x", "r", "s") and ds["ltm"].dtype == np.float32
    assert ds["ltm"].chunks is not None  # lazy (Dask), derived from the factors
    measured = snr_db(dense["ltm"].values, ds["ltm"].values)
    assert measured == pytest.approx(info["snr_db"], abs=0.01)
    assert 50.5 <= info["snr_db"] < 51.5  # measured 51.03 dB by the default held-out threshold
    assert info["ranks"]["ltm"]["max"] <= 26  # measured 4 tiles of ranks 18-26 of 256 cells
    np.testing.assert_allclose(ds["ltm_by_light"].values, ds["ltm"].values, rtol=1e-5,
                               atol=1e-7)  # the same product, summed in another order
    recorded = store_summary(store)["compact"]
    assert recorded["form"] == "factored" and recorded["snr_db"] == info["snr_db"]
    assert recorded["rank_rule"] == "gavish-donoho" and "target_db" not in recorded


def test_the_factors_lose_little_against_the_truth(factored_store, small_store,
                                                   small_acquisition):
    """The held-out threshold keeps what stands above the noise of the model's own error:
    against the simulation's truth the factors lose little. A rule that cuts into the signal
    fails this: leaving out 0.5 of the held-out error's energy (ranks 7-10) lost 0.94 dB, 0.6
    lost 1.33 dB, when the dense LTM stood at 30.10 dB. Since the surface model is fitted where
    the samples were taken, the dense LTM stands at 42.92 dB; its held-out error scored at the
    cells' centres (3.8 %) took the fall-off across a cell for noise, and the factors lost 2.76
    dB; scored where the samples were taken (1.0 %), they lose 0.02 dB."""
    from ltmstore.judge.evaluate import compare_stores

    truth = small_acquisition / "truth.zarr"
    dense = compare_stores(small_store, truth)["snr_y_db"]
    found = compare_stores(factored_store[0], truth)["snr_y_db"]
    assert dense - 0.1 < found <= dense + 0.05 and found > 42.8  # measured 42.90 against 42.92


def test_tiles_that_do_not_divide_the_image_read_back(small_store, tmp_path):
    """12 x 12 px tiles on the 32 px image: 3 tiles a side, the last cut (a 400 px image of
    32 px tiles failed to open: the basis was chunked by the image, not by its tiles)."""
    from ltmstore.stages.compact import compact

    store = tmp_path / "store.zarr"
    shutil.copytree(small_store, store, copy_function=os.link)
    info = compact(store, form="factored", tile=12)
    dense, ds = open_store(small_store)["ltm"].values, open_store(store)
    assert snr_db(dense, ds["ltm"].values) == pytest.approx(info["snr_db"], abs=0.01)
    image = relight(store, [LIGHTS[0]]).values
    assert snr_db(relight(small_store, [LIGHTS[0]]).values, image) > info["snr_db"]


def test_factors_take_fewer_bytes_than_the_dense_ltm(factored_store, small_store):
    store, _ = factored_store
    dense = folder_bytes(small_store / "ltm")
    factors = folder_bytes(store / "ltm_weights") + folder_bytes(store / "ltm_basis")
    assert factors < 0.23 * dense  # measured 0.214 (16 x 16 px tiles of 256 cells: ranks 18-26)
    assert folder_bytes(store) < folder_bytes(small_store)


def test_relight_from_the_factors_matches_the_dense_store(factored_store, small_store):
    store, info = factored_store
    expected, found = relight(small_store, LIGHTS).values, relight(store, LIGHTS).values
    assert snr_db(expected, found) > 43.2  # measured 43.73 dB (recorded ltm: 41.81 dB)
    area = disk_light(open_store(store)["ltm"], (0.0, 0.0), 0.08)
    assert snr_db(relight(small_store, area).values, relight(store, area).values) > 62.0  # 62.8


def test_an_opened_store_decodes_its_weights_once(factored_store, tmp_path):
    """Relit light after light, an opened store reads its weights from disk once: with the
    weight files gone it relights the same from memory, while the store opened anew cannot."""
    store = shutil.copytree(factored_store[0], tmp_path / "store.zarr")
    ds = open_store(store)
    first = relight(ds, [LIGHTS[0]]).values
    kept = ds.encoding["kept_weights"]["ltm"]
    assert kept.nbytes == ds["ltm_weights"].size * 4  # every block, float32
    shutil.rmtree(store / "ltm_weights" / "c")
    np.testing.assert_array_equal(relight(ds, [LIGHTS[0]]).values, first)
    np.testing.assert_array_equal(relight(ds, [LIGHTS[1]]).values,
                                  relight(factored_store[0], [LIGHTS[1]]).values)
    with pytest.raises(LtmError, match="ltm_weights/c/0 is missing"):
        relight(open_store(store), [LIGHTS[0]])


def test_a_damaged_factor_chunk_is_refused_by_check_and_relight(factored_store, tmp_path):
    store = shutil.copytree(factored_store[0], tmp_path / "store.zarr")
    part = next(p for p in sorted((store / "ltm_weights" / "c").rglob("*")) if p.is_file())
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0xFF
    part.write_bytes(bytes(data))
    check = run_ltm("check", store)
    assert check.returncode == 2 and "ltm_weights/c/" in check.stderr
    out = tmp_path / "relit.png"
    proc = run_ltm("relight", store, "--light", "0,0", "-o", out)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "damaged" in proc.stderr
    assert not out.exists()


def test_the_padded_factored_form_of_earlier_versions_is_named_not_read(factored_store,
                                                                     tmp_path):
    """A store whose weights are ``(y, x, rank)`` (before 2026-11-28) is refused, saying so."""
    import json

    store = shutil.copytree(factored_store[0], tmp_path / "store.zarr")
    meta_path = store / "ltm_weights" / "zarr.json"
    meta = json.loads(meta_path.read_text())
    meta["dimension_names"], meta["shape"] = ["y", "x", "rank"], [32, 32, 16]
    meta["chunk_grid"]["configuration"]["chunk_shape"] = [32, 32, 16]
    meta_path.write_text(json.dumps(meta))
    proc = run_ltm("relight", store, "--light", "0,0", "-o", tmp_path / "relit.png")
    assert proc.returncode == 2 and "padded factored form written before" in proc.stderr
    assert not (tmp_path / "relit.png").exists()


def test_cli_compact_factored_reports_its_cost_and_refuses_twice(small_store, tmp_path):
    store = shutil.copytree(small_store, tmp_path / "store.zarr", copy_function=os.link)
    bad = run_ltm("compact", store, "--form", "factored", "--target-snr", "0")
    assert bad.returncode == 2 and bad.stderr.startswith("ltm: error: target SNR")
    proc = run_ltm("compact", store, "--form", "factored", "--target-snr", "40")
    assert proc.returncode == 0, proc.stderr
    assert "factored" in proc.stdout and "SNR 4" in proc.stdout
    info = store_summary(store)
    assert info["complete"] and info["compact"]["form"] == "factored"
    assert 40.0 <= info["compact"]["snr_db"] < 41.0  # measured 40.10 dB (one tile, rank 16)
    assert run_ltm("check", store).returncode == 0
    again = run_ltm("compact", store)
    assert again.returncode == 2 and "already compacted" in again.stderr


@pytest.fixture(scope="module")
def colour_store(tmp_path_factory, dask_cluster):
    """A small glossy canvas: a colour LTM (ltm_cb, ltm_cr) beside the luminance."""
    from distributed import Client

    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct
    from ltmstore.synthetic.simulate import simulate_acquisition

    folder = tmp_path_factory.mktemp("canvas")
    simulate_acquisition(folder / "acq", scene="canvas", size=24, seed=2, lattice=(12, 12),
                         path_density=12.0, progress=False)
    ingest(folder / "acq", folder / "store.zarr", progress=False)
    with Client(dask_cluster) as client:
        reconstruct(folder / "store.zarr", client=client, lattice=(12, 12), progress=False)
    return folder / "store.zarr"


def test_a_colour_ltm_is_factored_and_relights_in_colour(colour_store, tmp_path):
    from ltmstore.stages.compact import compact

    store = shutil.copytree(colour_store, tmp_path / "store.zarr", copy_function=os.link)
    info = compact(store, form="factored", tile=8, target_db=50.0)
    assert set(info["ranks"]) == {"ltm", "ltm_cb", "ltm_cr"}
    dense, ds = open_store(colour_store), open_store(store)
    for name in ("ltm", "ltm_cb", "ltm_cr"):
        assert name not in os.listdir(store)
        assert snr_db(dense[name].values, ds[name].values) > 50.0  # the 50 dB target
    expected, found = relight(colour_store, LIGHTS).values, relight(store, LIGHTS).values
    assert found.shape == expected.shape and found.shape[-1] == 3
    assert snr_db(expected, found) > 52.5  # measured 53.0 dB (ltm 50.9 dB, 9 tiles each)
    assert run_ltm("check", store).returncode == 0


@pytest.mark.parametrize("rank", [12, 40, 90])
def test_a_tile_is_factored_at_the_least_rank_of_its_rule(rank):
    """A 32 x 32 tile on 40 x 50 cells: ``rank`` strong directions over noise. With a budget
    just above the noise, the range finder (ranks up to 48) and the exact eigenpairs beyond it
    both find the least rank (the exact SVD's) and leave out no more than the budget; with the
    held-out threshold for the noise's RMS (0.01), exactly the strong directions are kept."""
    from ltmstore.core import factored

    rng = np.random.default_rng(rank)
    strong = rng.standard_normal((1024, rank)) @ (rng.standard_normal((rank, 2000))
                                                  * np.geomspace(10, 1, rank)[:, None])
    a = strong + 0.01 * rng.standard_normal((1024, 2000))
    s = np.linalg.svd(a, compute_uv=False)
    allowed = 1.05 * float(np.sum(s[rank:] ** 2))
    least = int(np.argmax(np.sum(a ** 2) - np.cumsum(s ** 2) <= allowed)) + 1
    w, b = factored.factor_tile(a.reshape(32, 32, 40, 50), allowed)
    assert w.shape == (32, 32, least) and b.shape == (least, 40, 50) and least == rank
    sketched = factored._sketch(a, factored._enough(float(np.sum(a ** 2)), allowed, None))
    assert (sketched is None) == (rank > factored.SKETCH - factored.OVERSAMPLE)
    left = float(np.sum((a - w.reshape(1024, -1) @ b.reshape(least, -1)) ** 2))
    assert left <= allowed
    assert factored.left_out(a, b) == pytest.approx(left / float(np.sum(a ** 2)), rel=1e-6)
    np.testing.assert_allclose(w.reshape(1024, -1).T @ w.reshape(1024, -1), np.eye(least),
                               atol=1e-9)
    threshold = factored.heldout_threshold(np.full(1024, 0.01), 2000)
    assert s[rank] < threshold < s[rank - 1]  # 0.89: above the noise's 0.77, below the signal
    w, b = factored.factor_tile(a.reshape(32, 32, 40, 50), threshold=threshold)
    assert w.shape == (32, 32, rank) and b.shape == (rank, 40, 50)


def test_packed_factors_keep_each_tile_at_its_own_rank(tmp_path, monkeypatch):
    """Tiles of ranks 1-6 on a 37 x 45 px image in tiles of 2 px (19 x 23 tiles: 2 x 2 blocks,
    cut at the edges) are stored without padding, in chunks that blocks end inside, read back
    as their dense product in any window, and relit ``W (B l)`` as the dense LTM's dot product
    with the lights."""
    import zarr

    from ltmstore.core import factored
    from ltmstore.stages import factors

    monkeypatch.setattr(factored, "WEIGHT_CHUNK", 100)  # about 6 tiles, so that blocks end
    monkeypatch.setattr(factored, "ROW_CHUNK", 7)  # inside chunks (2500 rows, 14 KB of weights)
    rng = np.random.default_rng(3)
    image, tile, lattice = (37, 45), 2, (5, 4)
    ranks = rng.integers(1, 7, size=(19, 23))
    group = zarr.open_group(str(tmp_path / "f.zarr"), mode="w", zarr_format=3)
    weights, basis, packing = factors.create(group, "ltm", ranks, image, lattice, (3, 2),
                                             np.float32, tile)
    writer = factors.PackedWriter(weights, basis, packing)
    dense = np.zeros((*image, *lattice), np.float32)
    parts = {}
    for (i, j), k in np.ndenumerate(ranks):
        h, w = min(tile, image[0] - i * tile), min(tile, image[1] - j * tile)
        parts[i, j] = (rng.standard_normal((h, w, k)).astype(np.float32),
                       rng.standard_normal((k, *lattice)).astype(np.float32))
        dense[i * tile:i * tile + h, j * tile:j * tile + w] = np.tensordot(*parts[i, j], axes=1)
    assert len(packing.blocks()) == 4
    with pytest.raises(ValueError, match="packed order"):
        writer.write(packing.blocks()[1], parts)
    for tiles in packing.blocks():
        writer.write(tiles, parts)
    writer.close()
    assert weights.shape == (sum(p[0].size for p in parts.values()),)  # no padding
    assert basis.shape == (ranks.sum(), *lattice) and basis.shards[0] == 7
    view = factored.derived(weights, basis, ranks, tile, (3, 2))
    np.testing.assert_allclose(view.compute(), dense, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(view[5:33, 7:40, 1:4, 2:].compute(), dense[5:33, 7:40, 1:4, 2:],
                               rtol=1e-5, atol=1e-5)
    pattern = np.zeros((3, *lattice), np.float32)
    pattern[0, 1:3, 2:4], pattern[1, 4, 0] = 0.25, 1.0  # a point light, a cell; no light
    lit = factored.relight(weights, basis, ranks, pattern, tile).compute()
    np.testing.assert_allclose(lit, np.einsum("yxrs,lrs->lyx", dense, pattern),
                               rtol=1e-4, atol=1e-4)
    assert not lit[2].any()
    spans = [packing.span(tiles)[0] for tiles in packing.blocks()]
    kept = factored.Kept(weights, budget=4 * max(s.stop - s.start for s in spans))  # 1-3 kept
    for _ in range(2):
        np.testing.assert_array_equal(factored.relight(kept, basis, ranks, pattern, tile)
                                      .compute(), lit)
    assert 0 < kept.nbytes <= kept.budget and len(kept.blocks) < 4
