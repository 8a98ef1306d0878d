"""Archives: status, provenance, the reprocess_archive flow (isolation, retries, artifact)."""

from __future__ import annotations

import hashlib
import json

import pytest
import zarr
from archive_helpers import ARGS, PARAMS, build_archive, make_good_store, tree_digest
from pipeline_helpers import run_ltm

from ltmstore.archive import STATE_FILE, ArchiveParams, archive_status
from ltmstore.core.provenance import software
from ltmstore.core.store import open_group


@pytest.fixture(scope="module")
def good_store(small_store, tmp_path_factory, dask_cluster):
    return make_good_store(small_store, tmp_path_factory, dask_cluster)


@pytest.fixture
def archive(tmp_path, small_acquisition, good_store):
    root = tmp_path / "archive"
    build_archive(root, small_acquisition, good_store)
    return root


def file_bytes(folder) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())


def statuses(root) -> dict[str, str]:
    return {e.name: e.status for e in archive_status(root, PARAMS)}


def test_status_lists_new_stale_failed_and_up_to_date(archive):
    proc = run_ltm("archive", "status", archive, *ARGS, "--json")
    assert proc.returncode == 0, proc.stderr
    entries = {e["name"]: e for e in json.loads(proc.stdout)}
    assert {k: e["status"] for k, e in entries.items()} == {
        "a": "up to date", "b": "stale", "c": "new", "d": "failed", "e": "failed"}
    assert "made by 'ltmstore 0.0.1'" in entries["b"]["reason"]
    assert "acquisition.json is not valid JSON" in entries["d"]["reason"]
    assert "leaves the archive root" in entries["e"]["reason"]
    a = entries["a"]
    assert a["store_bytes"] == file_bytes(archive / "a.zarr")
    assert a["acquisition_bytes"] == file_bytes(archive / "a")
    recorded = open_group(archive / "a.zarr").attrs["stages"]["reconstruct"]
    assert a["timings"]["solve_s"] == recorded["timings"]["solve_s"]
    assert a["summary"]["sampling_ratio"] == pytest.approx(0.486, rel=0.05)  # measured 70 / 144
    table = run_ltm("archive", "status", archive, *ARGS).stdout
    assert "up to date" in table and "stale" in table and "K/M" in table


def test_other_parameters_or_changed_inputs_make_a_store_stale(archive):
    other = {e.name: e for e in archive_status(archive, ArchiveParams(lattice=(10, 10), tile=16))}
    assert other["a"].status == "stale" and "lattice [12, 12] -> [10, 10]" in other["a"].reason
    with open(archive / "a" / "poses.csv", "a") as fh:
        fh.write("\n")
    changed = {e.name: e for e in archive_status(archive, PARAMS)}
    assert changed["a"].status == "stale" and "['poses'] changed" in changed["a"].reason


def test_info_prints_the_provenance(good_store):
    proc = run_ltm("info", good_store)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["complete"] is True
    assert info["software"]["version"] == f"ltmstore {software()['version']}"
    assert "commit" in info["software"]
    assert info["parameters"]["run"]["lattice"] == [12, 12]
    assert info["parameters"]["method"] == "auto" and info["parameters"]["run"]["tile"] == 16
    assert set(info["inputs"]["sha256"]) == {"video", "poses"}
    assert {"ingest_s", "resample_s", "solve_s"} <= set(info["timings"])
    assert all(s["complete"] for s in info["stages"].values())
    assert 0 < info["sampling"]["sampling_ratio"] < 1


def test_reprocess_archive_flow(archive, prefect_harness, monkeypatch):
    """New and stale acquisitions are reprocessed, never the up-to-date one; a broken one
    fails alone; a transient I/O error is retried; the summary is a table artifact."""
    from prefect.client.orchestration import get_client

    import flows.archive as fa

    calls: dict[str, int] = {}
    real = fa.reprocess

    def flaky(folder, store, params, **kw):
        name = str(folder).rsplit("/", 1)[-1]
        calls[name] = calls.get(name, 0) + 1
        if name == "c" and calls[name] == 1:
            raise OSError(5, "Input/output error (injected, transient)")
        return real(folder, store, params, **kw)

    monkeypatch.setattr(fa, "reprocess", flaky)
    untouched = tree_digest(archive / "a.zarr")
    inputs = {n: tree_digest(archive / n) for n in "abcd"}
    rows = {r["acquisition"]: r for r in fa.reprocess_archive(
        str(archive), lattice=[12, 12], tile=16, max_concurrent=2)}
    assert {k: r["status"] for k, r in rows.items()} == {
        "a": "up to date", "b": "reprocessed", "c": "reprocessed", "d": "failed",
        "e": "failed"}
    assert calls == {"b": 1, "c": 2, "d": 1}  # never a; c retried once; e refused up front
    assert "not valid JSON" in rows["d"]["reason"] and "\n" not in rows["d"]["reason"]
    assert 0 < rows["b"]["K/M"] < 1 and rows["b"]["heldout_error"] > 0
    assert tree_digest(archive / "a.zarr") == untouched
    assert {n: tree_digest(archive / n) for n in "abcd"} == inputs  # inputs only read
    assert statuses(archive) == {"a": "up to date", "b": "up to date", "c": "up to date",
                                 "d": "failed", "e": "failed"}
    state = json.loads((archive / STATE_FILE).read_text())
    assert state["d"]["status"] == "failed" and state["b"]["status"] == "reprocessed"
    assert not [p.name for p in archive.iterdir() if p.name.startswith(".")
                and p.name != STATE_FILE]  # no side store left behind

    with get_client(sync_client=True) as client:
        artifact = client.read_latest_artifacts(limit=50)
    table = [a for a in artifact if a.key == fa.ARTIFACT_KEY]
    assert table and table[0].type == "table"
    data = json.loads(table[0].data) if isinstance(table[0].data, str) else table[0].data
    assert {r["acquisition"]: r["status"] for r in data} == {
        k: r["status"] for k, r in rows.items()}
    assert {"acquisition", "status", "seconds", "K/M", "heldout_error"} <= set(data[0])


def test_archive_serve_has_help():
    proc = run_ltm("archive", "serve", "--help")
    assert proc.returncode == 0 and "usage: ltm archive serve" in proc.stdout
    assert "--cron" in proc.stdout and "PREFECT_API_URL" in proc.stdout


@pytest.mark.parametrize(("args", "pattern"), [
    (["status", "{tmp}/missing"], "archive root '{tmp}/missing' does not exist"),
    (["run", "{tmp}", "--tile", "0"], "--tile 0 must be a positive"),
    (["serve", "{tmp}"], "the following arguments are required: --cron"),
])
def test_archive_bad_input_is_one_error_line(tmp_path, args, pattern):
    proc = run_ltm("archive", *[a.format(tmp=tmp_path) for a in args])
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert [line for line in lines if line.startswith("ltm")] == lines[-1:]
    assert pattern.format(tmp=tmp_path) in lines[-1], proc.stderr


def test_a_failed_reprocess_keeps_the_previous_good_store(archive):
    """b is stale; its video is now broken: reprocessing fails with one line, and b's previous
    store stays exactly as it was (the new one is built beside it and never swapped in)."""
    from ltmstore.archive import reprocess
    from ltmstore.core.errors import LtmError

    video = archive / "b" / "video.mkv"
    video.write_bytes(video.read_bytes()[:2000])
    before = tree_digest(archive / "b.zarr")
    with pytest.raises(LtmError, match="cannot be decoded") as err:
        reprocess(archive / "b", archive / "b.zarr", PARAMS)
    assert "\n" not in str(err.value)
    assert tree_digest(archive / "b.zarr") == before
    assert not [p.name for p in archive.iterdir() if p.name.startswith(".b.zarr")]
    assert statuses(archive)["b"] == "stale"  # the old store stays, reason: inputs changed


def test_a_change_after_the_first_mib_of_an_input_makes_it_stale(archive):
    """An input larger than 1 MiB whose last bytes change is stale: hashing reads it all."""
    poses = archive / "a" / "poses.csv"
    text = poses.read_text()
    last = float(text.splitlines()[-1].split(",")[0])
    text += "".join(f"{last + 1 + i / 100:.2f},0,0,0.5\n" for i in range(110_000))
    poses.write_text(text)
    assert poses.stat().st_size > 1.5 * 2**20
    group = zarr.open_group(str(archive / "a.zarr"), mode="r+")  # as if ingested from it
    acquisition = dict(group.attrs["acquisition"])
    acquisition["sha256"] = {**acquisition["sha256"],
                             "poses": hashlib.sha256(poses.read_bytes()).hexdigest()}
    group.attrs["acquisition"] = acquisition
    assert statuses(archive)["a"] == "up to date"
    poses.write_text(text[:-2] + "7\n")  # the last row's z: 0.5 -> 0.7
    assert statuses(archive)["a"] == "stale"
