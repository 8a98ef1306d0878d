"""A store whose layout was changed silently (issue 64, items 5, 6 and 11): an attribute added
to an array, a chunk moved with its valid checksum, a bit flipped where ``ltm info`` did not look.
Each is named by ``ltm check`` (exit 2, the array named), makes ``ltm info`` say the store is not
complete, and makes ``ltm relight`` or ``ltm export`` stop with one line (exit 2), on near, far,
compacted and factored stores; a store written before the records of what its stages wrote still
opens, checks (saying what it could not verify) and relights.
"""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from pipeline_helpers import ltm_here, only_error_line

from ltmstore.core.integrity import WRITTEN
from ltmstore.stages.reconstruct import reconstruct

LIGHTS = {"near": ["--light", "0.05,-0.05"], "far": ["--direction", "0.3,0.2,1"]}


@pytest.fixture(scope="module")
def made(small_store, far_store, tmp_path_factory) -> dict[str, Path]:
    """The session's stores, and those made from them here: compacted (dense), factored, a far
    store of 8 px tiles (4 ``ltm`` shards), and a far store fitted by another method (its ``ltm``
    shard holds other values, with a valid checksum)."""
    from ltmstore.stages.compact import compact

    root = tmp_path_factory.mktemp("layout")
    out = {"near": small_store, "far": far_store}
    for kind, form in (("compact", "dense"), ("factored", "factored")):
        out[kind] = shutil.copytree(small_store, root / f"{kind}.zarr")
        compact(out[kind], form=form, tile=32, progress=False)
    for kind, tile in (("far_tiles", 8), ("far_other", None)):
        out[kind] = shutil.copytree(far_store, root / f"{kind}.zarr")
        reconstruct(out[kind], method="ptm", tile=tile, overwrite=True, progress=False)
    return out


@pytest.fixture
def stores(made, tmp_path):
    """A fresh copy of a store of each kind (to damage)."""
    def copy(kind: str) -> Path:
        return shutil.copytree(made[kind], tmp_path / f"{kind}.zarr")
    return copy


def light(kind: str) -> list[str]:
    return LIGHTS["far" if kind.startswith("far") else "near"]


def parts(store: Path, name: str) -> list[Path]:
    return sorted(f for f in (store / name / "c").rglob("*") if f.is_file())


def edit_attributes(store: Path, name: str, edit) -> None:
    path = store / name / "zarr.json"
    meta = json.loads(path.read_text())
    edit(meta["attributes"])
    path.write_text(json.dumps(meta))


def swap(a: Path, b: Path) -> None:
    side = a.with_name(a.name + ".swap")
    a.rename(side)
    b.rename(a)
    side.rename(b)


def flip(part: Path, where: float = 0.5) -> None:
    data = bytearray(part.read_bytes())
    data[int(len(data) * where)] ^= 0x10
    part.write_bytes(bytes(data))


def checked(capsys, store: Path, *said: str) -> None:
    """``ltm check`` names every line ``said`` (exit 2); ``ltm info`` says not complete."""
    check = ltm_here(capsys, "check", store)
    assert check.returncode == 2 and "Traceback" not in check.stderr, check.stderr
    for line in said:
        assert f"ltm: damaged: {store}/{line}" in check.stderr, check.stderr
    info = ltm_here(capsys, "info", store)
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    assert summary["complete"] is False, summary
    assert any(d.startswith(said[0]) for d in summary["damaged"]), summary["damaged"]


def refused(capsys, store: Path, kind: str, command: str, said: str) -> None:
    """``ltm relight`` or ``ltm export`` stops with one line naming ``said``, writing nothing."""
    out = store.parent / ("relit.png" if command == "relight" else "out.ptm")
    args = [*light(kind), "-o", out] if command == "relight" else [out, "--format", "ptm"]
    only_error_line(ltm_here(capsys, command, store, *args), "is damaged", said, "ltm check")
    assert not out.exists()


def set_attribute(**values):
    return lambda attrs: attrs.update(values)


ATTRIBUTES = {  # kind, array, edit, what ltm check names, command refused
    "scale_factor on r": ("near", "r", set_attribute(scale_factor=2.0),
                          "r/zarr.json: attribute 'scale_factor' was added", "relight"),
    "add_offset on chroma": ("near", "chroma", set_attribute(add_offset=0.25),
                             "chroma/zarr.json: attribute 'add_offset' was added", "relight"),
    "scale_factor on frames": ("near", "frames", set_attribute(scale_factor=0.5),
                               "frames/zarr.json: attribute 'scale_factor' was added",
                               "export"),
    "_FillValue on ltm": ("near", "ltm", set_attribute(_FillValue="AAAAAAAAAAA="),
                          "ltm/zarr.json: attribute '_FillValue' was added", "export"),
    "scale_factor on exposure (far)": ("far", "exposure", set_attribute(scale_factor=2.0),
                                       "exposure/zarr.json: attribute 'scale_factor'",
                                       "relight"),
    "add_offset on normal (far)": ("far", "normal", set_attribute(add_offset=0.3),
                                   "normal/zarr.json: attribute 'add_offset'", "relight"),
    "methods reversed (far)": ("far", "method_map", lambda a: a["methods"].reverse(),
                               "method_map/zarr.json: attribute 'methods' is not what the "
                               "reconstruct stage wrote", "relight"),
    "tile removed (far)": ("far", "method_map", lambda a: a.pop("tile"),
                           "method_map/zarr.json: attribute 'tile' is missing", "export"),
    "scale_factor on chroma (compacted)": ("compact", "chroma", set_attribute(scale_factor=3.0),
                                           "chroma/zarr.json: attribute 'scale_factor'",
                                           "relight"),
    "add_offset on the light-major copy (compacted)": (
        "compact", "ltm_by_light", set_attribute(add_offset=0.1),
        "ltm_by_light/zarr.json: attribute 'add_offset' was added after the compact stage",
        "relight"),
    "scale_factor on chroma (factored)": ("factored", "chroma", set_attribute(scale_factor=3.0),
                                          "chroma/zarr.json: attribute 'scale_factor'",
                                          "relight"),
    "basis tile changed (factored)": ("factored", "ltm_basis", set_attribute(tile=16),
                                      "ltm_basis/zarr.json: attribute 'tile' is not what the "
                                      "compact stage wrote", "export"),
}


@pytest.mark.parametrize("case", list(ATTRIBUTES))
def test_a_changed_attribute_is_damage(case, stores, capsys):
    """Item 5: xarray's CF decoding applied these (18-134 grey levels of difference); nothing
    checked an array's attributes."""
    kind, name, edit, said, command = ATTRIBUTES[case]
    store = stores(kind)
    edit_attributes(store, name, edit)
    checked(capsys, store, said)
    refused(capsys, store, kind, command, said.split(" ")[0])


def test_readers_take_the_stored_values(made, tmp_path):
    """The reading half of item 5: with no integrity check in front (a Zarr store object),
    ``open_store`` still applies no attribute to the values: xarray's CF decoding is off."""
    import zarr

    from ltmstore.core.store import open_store

    store = shutil.copytree(made["near"], tmp_path / "near.zarr")
    expected = open_store(store)
    edit_attributes(store, "r", set_attribute(scale_factor=2.0, add_offset=1.0))
    edit_attributes(store, "chroma", set_attribute(scale_factor=2.0))
    edit_attributes(store, "expected_error", set_attribute(units="days since 2000-01-01"))
    ds = open_store(zarr.storage.LocalStore(str(store), read_only=True))
    for name in ("r", "chroma", "expected_error"):
        assert ds[name].dtype == expected[name].dtype
        np.testing.assert_array_equal(ds[name].values, expected[name].values)


def swap_parts(name: str, first: int = 0, second: int = 1):
    def damage(store: Path, made: dict) -> None:
        found = parts(store, name)
        swap(found[first], found[second])
    return damage


def swap_folders(a: str, b: str):
    return lambda store, made: swap(store / a, store / b)


def from_other(kind: str, name: str):
    def damage(store: Path, made: dict) -> None:
        for part in parts(made[kind], name):
            shutil.copyfile(part, store / part.relative_to(made[kind]))
    return damage


def swap_inner_chunks(name: str):
    """Swap two inner chunks of one size in a shard: its index (and index checksum) unchanged,
    every checksum valid, two lattice cells in each other's place."""
    def damage(store: Path, made: dict) -> None:
        part = parts(store, name)[0]
        data = bytearray(part.read_bytes())
        inner = json.loads((store / name / "zarr.json").read_text())
        config = inner["codecs"][0]["configuration"]
        n = int(np.prod(np.array(inner["chunk_grid"]["configuration"]["chunk_shape"])
                        // np.array(config["chunk_shape"])))
        index = np.frombuffer(bytes(data[-(16 * n + 4):-4]), "<u8").reshape(-1, 2)
        size = next(s for s, k in Counter(index[:, 1].tolist()).items() if k > 1)
        (a, _), (b, _) = index[index[:, 1] == size][:2].astype(int)
        data[a:a + size], data[b:b + size] = data[b:b + size], data[a:a + size]
        part.write_bytes(bytes(data))
    return damage


MOVES = {  # kind, damage, what ltm check names, command refused (None: read elsewhere)
    "light-major shards swapped": ("near", swap_parts("ltm_by_light"),
                                   "ltm_by_light/c holds chunks the reconstruct stage did not "
                                   "write there", "relight"),
    "frames chunks swapped": ("near", swap_parts("frames", 1, 4), "frames/c holds chunks",
                              "relight"),
    "ltm and samples swapped": ("near", swap_folders("ltm", "samples"),
                                "ltm/zarr.json: its metadata", "export"),
    "ltm shards swapped (far)": ("far_tiles", swap_parts("ltm", 0, 3), "ltm/c holds chunks",
                                 "export"),
    "ltm shard of another store (far)": ("far", from_other("far_other", "ltm"),
                                         "ltm/c holds chunks", "export"),
    "light-major shards swapped (compacted)": ("compact", swap_parts("ltm_by_light"),
                                               "ltm_by_light/c holds chunks the compact stage",
                                               "relight"),
    "inner chunks swapped in a shard": ("near", swap_inner_chunks("ltm_by_light"),
                                        "ltm_by_light/c holds chunks", None),
}


@pytest.mark.parametrize("case", list(MOVES))
def test_a_chunk_in_the_wrong_place_is_damage(case, made, stores, capsys):
    """Item 6: each chunk's checksum holds, so ``ltm check`` passed them, and ``ltm export``
    wrote something else."""
    kind, damage, said, command = MOVES[case]
    store = stores(kind)
    damage(store, made)
    checked(capsys, store, said)
    if command:
        refused(capsys, store, kind, command, said.split(" ")[0])


FLIPS = {  # kind, array, part: none of them the first chunk (the one ltm info decoded)
    "frames": ("near", "frames", 5),
    "light-major copy": ("near", "ltm_by_light", 1),
    "frames (far)": ("far", "frames", 1),
    "ltm shard (far)": ("far_tiles", "ltm", 2),
    "light-major copy (compacted)": ("compact", "ltm_by_light", 1),
    "basis (factored)": ("factored", "ltm_basis", 0),
}


@pytest.mark.parametrize("case", list(FLIPS))
def test_a_flipped_bit_is_never_complete(case, stores, capsys):
    """Item 11: ``ltm check`` named the flipped bit while ``ltm info`` said complete."""
    kind, name, index = FLIPS[case]
    store = stores(kind)
    part = parts(store, name)[index]
    flip(part, 0.6)
    key = part.relative_to(store).as_posix()
    checked(capsys, store, f"{key} fails its check (checksum mismatch)")


@pytest.mark.parametrize("kind", ["near", "far", "compact", "factored", "far_tiles"])
def test_undamaged_stores_pass(kind, stores, capsys):
    store = stores(kind)
    check = ltm_here(capsys, "check", store)
    assert check.returncode == 0 and "no damage" in check.stdout, check.stderr
    assert "note" not in check.stderr, check.stderr
    assert json.loads(ltm_here(capsys, "info", store).stdout)["complete"] is True


def written_before(store: Path) -> Path:
    """``store`` as ltmstore wrote it before it recorded what each stage wrote."""
    path = store / "zarr.json"
    meta = json.loads(path.read_text())
    del meta["attributes"][WRITTEN]
    path.write_text(json.dumps(meta))
    return store


@pytest.mark.parametrize("kind", ["near", "far"])
def test_a_store_written_before_the_records_opens_checks_and_relights(kind, made, stores,
                                                                      capsys):
    import imageio.v3 as iio

    store = written_before(stores(kind))
    check = ltm_here(capsys, "check", store)
    assert check.returncode == 0 and "no damage" in check.stdout, check.stderr
    assert "records nothing of how these arrays were written" in check.stderr, check.stderr
    assert "ltm" in check.stderr.split("not verified: ")[1]
    assert json.loads(ltm_here(capsys, "info", store).stdout)["complete"] is True
    images = []
    for source in (made[kind], store):
        out = store.parent / f"{len(images)}.png"
        assert ltm_here(capsys, "relight", source, *light(kind), "-o", out).returncode == 0
        images.append(iio.imread(out))
    assert np.array_equal(*images)


def test_a_cf_attribute_is_damage_without_the_records(stores, capsys):
    """What no record is needed for: ltmstore never writes an attribute xarray's CF decoding
    applies (plain ``xarray.open_zarr`` users would get other values)."""
    store = written_before(stores("near"))
    edit_attributes(store, "r", set_attribute(scale_factor=2.0))
    said = "r/zarr.json: attribute 'scale_factor', which ltmstore never writes"
    checked(capsys, store, said)
    refused(capsys, store, "near", "relight", "r/zarr.json")
