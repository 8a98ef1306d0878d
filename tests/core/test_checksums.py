"""Damaged stores are named, never served (issue 13, item 3): every chunk carries a CRC32C,
``ltm check`` reads them all, a missing shard or broken metadata is one line, never a traceback."""

from __future__ import annotations

import json
import math
import shutil
import warnings

import pytest
from pipeline_helpers import ltm_here, run_ltm

from ltmstore.core import checksum
from ltmstore.core.store import NoChecksumWarning, open_group, open_store, store_summary
from ltmstore.stages.ingest import ingest


@pytest.fixture
def store(small_store, tmp_path):
    out = tmp_path / "store.zarr"
    shutil.copytree(small_store, out)
    return out


def a_shard(store):
    return sorted(f for f in (store / "ltm" / "c").rglob("*") if f.is_file())[0]


def one_line_error(proc, *needles):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("ltm: error: "), proc.stderr
    for needle in needles:
        assert needle in proc.stderr, proc.stderr


def test_every_array_carries_checksums(store):
    group = open_group(store)
    assert all(checksum.has_checksums(a) for _, a in group.arrays())
    assert store_summary(store)["checksums"] is True


def light_major_shard(store):
    """A shard of the light-major copy (what relight reads) and the light at the centre of
    its first cell (the first inner chunk: the bytes flipped below reach it)."""
    group = open_group(store)
    size = group["ltm_by_light"].shards[2:]
    cells = [n if group[d].shape[0] > n else 0 for d, n in zip("rs", size, strict=True)]
    light = ",".join(str(float(group[d][c])) for d, c in zip("rs", cells, strict=True))
    return store.joinpath("ltm_by_light", "c", "0", "0",
                          *(str(c // n) for c, n in zip(cells, size, strict=True))), light


def test_flipped_bytes_are_found_and_named(store):
    shard, light = light_major_shard(store)
    array = open_group(store)["ltm_by_light"]
    inner = math.prod(s // c for s, c in zip(array.shards, array.chunks, strict=True))
    data = bytearray(shard.read_bytes())
    # every inner chunk's bytes (relight reads a few of them), not the index at the shard's
    # end (16 bytes per inner chunk and its CRC32C)
    for i in range(0, len(data) - 16 * inner - 4, 61):
        data[i] ^= 0xFF
    shard.write_bytes(bytes(data))
    key = shard.relative_to(store).as_posix()
    one_line_error(run_ltm("check", store), f"damaged: {store}/{key} fails its check "
                   "(checksum mismatch)", "is damaged: 1 part(s)")
    one_line_error(run_ltm("relight", store, "--light", light, "-o", store.parent / "a.png"),
                   "fails its checksum")
    assert not (store.parent / "a.png").exists()


def test_a_deleted_shard_is_damage(store, capsys):
    shard = a_shard(store)
    shard.unlink()
    key = shard.relative_to(store).as_posix()
    info = store_summary(store)
    assert info["complete"] is False and info["damaged"] == [f"{key} is missing"]
    one_line_error(run_ltm("relight", store, "--light", "0,0", "-o", store.parent / "a.png"),
                   f"is damaged: {key} is missing")
    one_line_error(ltm_here(capsys, "check", store), f"{key} is missing")


def test_broken_metadata_is_one_line(store, capsys):
    (store / "ltm" / "zarr.json").write_text('{"zarr_format": 3, "node_type": ')
    info = json.loads(ltm_here(capsys, "info", store).stdout)
    assert info["complete"] is False
    assert info["damaged"] == ["ltm/zarr.json cannot be read (JSONDecodeError)"]
    one_line_error(ltm_here(capsys, "check", store), "ltm/zarr.json cannot be read")
    (store / "zarr.json").write_text("{")
    one_line_error(run_ltm("info", store), "zarr.json")
    one_line_error(ltm_here(capsys, "check", store), "zarr.json cannot be read")


def test_a_store_without_checksums_opens_with_a_note(small_acquisition, tmp_path,
                                                      monkeypatch, capsys):
    monkeypatch.setattr(checksum, "COMPRESSORS", (checksum.ZstdCodec(level=0),))
    monkeypatch.setattr(checksum, "FAST_COMPRESSORS", (checksum.ZstdCodec(level=0),))
    monkeypatch.setattr(checksum, "ARRAY_CONFIG", {})
    old = tmp_path / "old.zarr"
    ingest(small_acquisition, old, progress=False)
    monkeypatch.undo()
    with pytest.warns(NoChecksumWarning, match="carries no checksums"):
        assert "frames" in open_store(old)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert store_summary(old)["checksums"] is False
    proc = ltm_here(capsys, "check", old)
    assert proc.returncode == 0, proc.stderr
    assert "carries no checksums" in proc.stderr and "no damage" in proc.stdout


def test_archive_status_fails_a_damaged_store(store):
    from ltmstore.archive import ArchiveParams, _store_state

    a_shard(store).unlink()
    status, reason = _store_state(store, ArchiveParams(), None)
    assert status == "failed" and "is damaged" in reason and "missing" in reason
    assert json.loads((store / "zarr.json").read_text())  # the store itself is untouched
