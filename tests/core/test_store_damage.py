"""Damage that ``ltm check`` once missed (issue 27, items 3, 4 and 11): each is named by
``ltm check``, makes ``ltm info`` say the store is not complete, and makes ``ltm relight`` stop
with one line (exit 2) before it writes any image, on near and far stores alike."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from pipeline_helpers import ltm_here, only_error_line

from ltmstore.stages.reconstruct import reconstruct

LIGHTS = {"near": ["--light", "0.05,-0.05"], "colour": ["--light", "0.05,-0.05"],
          "far": ["--direction", "0.3,0.2,1"]}


@pytest.fixture(scope="module")
def colour_store(small_store, tmp_path_factory, dask_cluster) -> Path:
    """``small_store`` reconstructed again with a colour LTM (``ltm_cb``, ``ltm_cr``)."""
    from distributed import Client

    store = tmp_path_factory.mktemp("colour") / "store.zarr"
    shutil.copytree(small_store, store)
    with Client(dask_cluster) as client:
        reconstruct(store, client=client, lattice=(16, 16), color=True, overwrite=True,
                    progress=False)
    return store


@pytest.fixture
def stores(small_store, colour_store, far_store, tmp_path):
    """A fresh copy of the store of each kind (to damage)."""
    sources = {"near": small_store, "colour": colour_store, "far": far_store}

    def copy(kind: str) -> Path:
        out = tmp_path / f"{kind}.zarr"
        shutil.copytree(sources[kind], out)
        return out
    return copy


def first_part(store: Path, name: str) -> Path:
    return sorted(f for f in (store / name / "c").rglob("*") if f.is_file())[0]


def truncate(name):
    def damage(store):
        part = first_part(store, name)
        part.write_bytes(b"")
        return f"{part.relative_to(store).as_posix()} is empty (0 bytes)"
    return damage


def to_folder(name):
    def damage(store):
        part = first_part(store, name)
        part.unlink()
        part.mkdir()
        return f"{part.relative_to(store).as_posix()} is a folder, not a chunk file"
    return damage


def remove(name, why):
    def damage(store):
        shutil.rmtree(store / name)
        return f"{name} is missing ({why})"
    return damage


def remove_metadata(name):
    def damage(store):
        (store / name / "zarr.json").unlink()
        return f"{name}/zarr.json is missing"
    return damage


def edit_metadata(name, edit, said):
    def damage(store):
        path = store / name / "zarr.json"
        meta = json.loads(path.read_text())
        edit(meta)
        path.write_text(json.dumps(meta))
        return said
    return damage


def without_crc(meta):
    meta["codecs"] = [c for c in meta["codecs"] if c["name"] != "crc32c"]


CASES = {  # kind, damage -> what ltm check names
    "ltm chunk truncated": ("near", truncate("ltm")),
    "light-major shard truncated": ("near", truncate("ltm_by_light")),
    "light-major shard a folder": ("near", to_folder("ltm_by_light")),
    "ltm/zarr.json deleted": ("near", remove_metadata("ltm")),
    "r deleted": ("near", remove("r", "the coordinate of dimension r")),
    "chroma deleted": ("near", remove("chroma", "the ingest stage wrote it")),
    "ltm_cb deleted": ("colour", remove("ltm_cb", "the reconstruct stage wrote it")),
    "crc32c removed (near)": ("near", edit_metadata("samples", without_crc,
                                                     "samples/zarr.json: codecs bytes, zstd")),
    "ltm data type changed": ("near", edit_metadata(
        "ltm_by_light", lambda m: m.update(data_type="float64"),
        "ltm_by_light/zarr.json: data type float64, expected float32 or float16")),
    "frames a folder (far)": ("far", to_folder("frames")),
    "normal deleted (far)": ("far", remove("normal", "the reconstruct stage wrote it")),
    "exposure deleted (far)": ("far", remove("exposure", "the reconstruct stage wrote it")),
    "crc32c removed (far)": ("far", edit_metadata("frames", without_crc,
                                                   "frames/zarr.json: codecs bytes, blosc")),
    "frames data type changed (far)": ("far", edit_metadata(
        "frames", lambda m: m.update(data_type="int32"),
        "frames/zarr.json cannot be read (TypeError)")),
    "pose data type changed (far)": ("far", edit_metadata(
        "pose_r", lambda m: m.update(data_type="float32"),
        "pose_r/zarr.json: data type float32, expected float64")),
}


@pytest.mark.parametrize("case", list(CASES))
def test_damage_is_named_and_never_relit(case, stores, capsys):
    kind, damage = CASES[case]
    store = stores(kind)
    said = damage(store)
    check = ltm_here(capsys, "check", store)
    assert check.returncode == 2 and "Traceback" not in check.stderr, check.stderr
    assert f"ltm: damaged: {store}/{said}" in check.stderr, check.stderr
    info = ltm_here(capsys, "info", store)
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    assert summary["complete"] is False, summary
    assert any(line.startswith(said) for line in summary["damaged"]), summary["damaged"]
    image = store.parent / f"{kind}.png"
    relit = ltm_here(capsys, "relight", store, *LIGHTS[kind], "-o", image)
    only_error_line(relit, "is damaged", said.split(" ")[0], "ltm check")
    assert not image.exists()


@pytest.mark.parametrize("kind", list(LIGHTS))
def test_an_undamaged_store_passes(kind, stores, capsys):
    store = stores(kind)
    check = ltm_here(capsys, "check", store)
    assert check.returncode == 0 and "no damage" in check.stdout, check.stderr
    assert json.loads(ltm_here(capsys, "info", store).stdout)["complete"] is True
    relit = ltm_here(capsys, "relight", store, *LIGHTS[kind], "-o", store.parent / "a.png")
    assert relit.returncode == 0, relit.stderr


def test_a_removed_light_major_copy_is_no_damage(stores, capsys):
    """Relight falls back on ``ltm`` (the copy is optional): the same image, exit 0."""
    import imageio.v3 as iio

    store = stores("near")
    assert ltm_here(capsys, "relight", store, *LIGHTS["near"], "-o",
                    store.parent / "a.png").returncode == 0
    shutil.rmtree(store / "ltm_by_light")
    assert ltm_here(capsys, "check", store).returncode == 0
    assert ltm_here(capsys, "relight", store, *LIGHTS["near"], "-o",
                    store.parent / "b.png").returncode == 0
    a, b = (iio.imread(store.parent / n).astype(int) for n in ("a.png", "b.png"))
    assert np.abs(a - b).max() <= 1  # measured 0: the copy holds the same values
