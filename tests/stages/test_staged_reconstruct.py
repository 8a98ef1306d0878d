"""A classic capture reconstructs in two recorded stages (issue 62, item 1): the classic fit
(``reconstruct``), complete and relightable on its own, then the surface refinement
(``reconstruct_surface``), swapped in only when complete; the default runs both and gives the
store that running them one after the other gives."""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zarr
from archive_helpers import kill_group
from dome_helpers import RINGS, dome, flash, write_capture
from pipeline_helpers import BIN

from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store, stages, store_summary, verify_store
from ltmstore.core.transfer import srgb_to_linear
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.stages.reconstruct_far import REFINE, FarFit
from ltmstore.stages.relight import relight
from ltmstore.stages.surface import NORMAL, PREFIX


@pytest.fixture(scope="module")
def ingested(tmp_path_factory) -> Path:
    """A dome capture of a glossy surface under a flickering flash (its surface model pays),
    as ``ltm ingest-rti`` leaves it."""
    root = tmp_path_factory.mktemp("staged")
    lp = write_capture(root / "capture", flash(sum(RINGS.values())))
    ingest_rti(lp, root / "ingested.zarr", progress=False)
    return root / "ingested.zarr"


@pytest.fixture(scope="module")
def default_run(ingested) -> Path:
    """The store of an uninterrupted default run (both stages at once)."""
    store = ingested.parent / "default.zarr"
    shutil.copytree(ingested, store)
    reconstruct(store, progress=False)
    return store


@pytest.fixture
def store(ingested, tmp_path) -> Path:
    """A fresh copy of the ingested store."""
    shutil.copytree(ingested, tmp_path / "s.zarr")
    return tmp_path / "s.zarr"


def methods(store: Path) -> list[str]:
    return list(zarr.open_group(store, mode="r")["method_map"].attrs["methods"])


def assert_unrefined_and_relightable(store: Path) -> None:
    """The classic fit, complete and checked, relights; the store says it is not refined."""
    records = stages(zarr.open_group(store, mode="r"))
    assert records["reconstruct"]["complete"] and records["reconstruct"]["refinement"] == "pending"
    assert records[REFINE]["complete"] is False
    info = store_summary(store)
    assert not info["complete"] and "damaged" not in info
    assert info["stages"][REFINE]["complete"] is False
    assert verify_store(store, progress=False)["damaged"] == []
    assert not any(m.startswith(PREFIX) for m in methods(store))  # classic models only
    ds = open_store(store)
    assert NORMAL not in ds
    image = relight(ds, directions=dome()[:3]).values
    assert image.shape[0] == 3 and np.isfinite(image).all() and image.max() > 0


def assert_same_arrays(a: Path, b: Path) -> None:
    """Every array of ``a`` and ``b`` holds the same values (and method_map the same names)."""
    ga, gb = (zarr.open_group(p, mode="r") for p in (a, b))
    assert sorted(ga.array_keys()) == sorted(gb.array_keys())
    for name in ga.array_keys():
        x, y = np.asarray(ga[name][...]), np.asarray(gb[name][...])
        assert x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
    assert methods(a) == methods(b)


def test_the_classic_stage_alone_relights_and_says_it_is_unrefined(store):
    info = reconstruct(store, stage="classic", progress=False)
    assert info["refinement"] == "pending"
    assert_unrefined_and_relightable(store)
    with pytest.raises(LtmError, match="already has an ltm.*the default, finishes its surface"):
        reconstruct(store, stage="classic", progress=False)  # nothing left to do there
    with pytest.raises(LtmError, match="refinement is pending for a run of other parameters"):
        reconstruct(store, lattice=(6, 6), progress=False)


def test_the_default_equals_the_stages_run_one_after_the_other(store, default_run):
    reconstruct(store, stage="classic", progress=False)
    info = reconstruct(store, progress=False)  # finishes the refinement
    assert info["refinement"] == "done" and info["exposure_fitted"]
    assert any(m.startswith(PREFIX) for m in methods(default_run))  # the surface paid
    assert_same_arrays(store, default_run)
    for path in (store, default_run):
        summary = store_summary(path)
        assert summary["complete"] and "damaged" not in summary
        assert verify_store(path, progress=False)["damaged"] == []
    with pytest.raises(LtmError, match="already has an ltm; pass --overwrite"):
        reconstruct(store, progress=False)


def side_copies(store: Path) -> list[Path]:
    """The linked copies the refinement builds beside the store."""
    return list(store.parent.glob(f".{store.name}.partial-copy-*"))


@pytest.mark.parametrize("written", [None, "exposure"])
def test_a_kill_during_the_refinement_leaves_the_classic_store_and_a_rerun_finishes_it(
        store, default_run, written):
    """SIGKILL the whole `ltm reconstruct` process group once the refinement has begun: as
    soon as its linked copy appears, or once it has written the photographs' exposures there
    (then the surface fit runs)."""
    def reached() -> bool:
        return any(written is None or (side / written).is_dir() for side in side_copies(store))

    proc = subprocess.Popen([BIN / "ltm", "reconstruct", store], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not reached():
            assert proc.poll() is None and time.monotonic() < deadline, "never reached stage 2"
            time.sleep(0.01)
    finally:
        kill_group(proc)
    assert side_copies(store)  # killed mid-refinement: its copy is left beside the store
    assert_unrefined_and_relightable(store)
    info = reconstruct(store, progress=False)
    assert info["refinement"] == "done" and not side_copies(store)
    assert stages(zarr.open_group(store, mode="r"))[REFINE]["separate_run"]
    assert store_summary(store)["complete"]
    assert_same_arrays(store, default_run)


def test_check_and_relight_say_the_refinement_is_pending(store, tmp_path):
    """`ltm check` passes a classic-only store and `ltm relight` relights it, each with one note
    saying its surface refinement is pending and how to finish it; none once it is done."""
    def notes(*argv) -> list[str]:
        run = subprocess.run([BIN / "ltm", *map(str, argv)], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        return [line for line in run.stderr.splitlines() if line.startswith("ltm: note:")]

    reconstruct(store, stage="classic", progress=False)
    relit = ("relight", store, "--direction", "0,0,1", "-o", tmp_path / "a.png", "--overwrite")
    for argv in (("check", store), relit):
        assert notes(*argv) == [f"ltm: note: store {str(store)!r} holds its classic fit only: "
                                f"its surface refinement is pending (`ltm reconstruct {store}` "
                                "finishes it)"]
    reconstruct(store, progress=False)
    assert notes("check", store) == notes(*relit) == []


def test_a_shard_of_several_tiles_holds_each_tile_where_it_lies(tmp_path):
    """8 x 9 tiles of 5 px: 2 x 2 tiles a shard of ``ltm`` (each written whole, in one call),
    and every tile's LTF the classic fit of its own pixels."""
    lp = write_capture(tmp_path / "capture", flash(sum(RINGS.values())), shape=(40, 44))
    ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    reconstruct(tmp_path / "s.zarr", stage="classic", tile=5, progress=False)
    group = zarr.open_group(tmp_path / "s.zarr", mode="r")
    fit = FarFit.prepare(group, lattice=None, method="auto", tile=5)
    assert fit.plan.shard_tiles == 2 and group["ltm"].shards == (10, 10, 8, 8)
    chosen, ltm = group["method_map"][...], group["ltm"][...]
    for index in np.ndindex(fit.plan.grid):
        rows, cols, values = fit.pixels(index)
        lattice = np.clip(fit.to_lattice[chosen[index]] @ values, 0, None)
        np.testing.assert_array_equal(ltm[rows, cols],
                                      srgb_to_linear(lattice).T.reshape(5, -1, 8, 8))
