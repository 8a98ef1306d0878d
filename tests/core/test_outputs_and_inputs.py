"""No command writes onto what it reads (issue 64, "Data lost"): an output that is an input,
lies inside one or holds one is refused in one line before anything is written; a swap journal
names its stores relative to their folder, so a copied or moved folder recovers only its own
stores, and a journal that does not match its folder is refused; ``ltm demo --overwrite``
replaces only a previous demo's outputs. Real stores, the real CLI, real files; every test
checks that the inputs are byte for byte as they were."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from ingest_helpers import tree_hashes
from pipeline_helpers import BIN, ltm_here, only_error_line

from ltmstore.core.errors import LtmError
from ltmstore.core.paths import check_output
from ltmstore.core.swap import PAUSE_ENV, journal_path


def copy_of(store: Path, folder: Path, name: str = "st.zarr") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return Path(shutil.copytree(store, folder / name, symlinks=True))


# --- the rule ---------------------------------------------------------------------------------

def test_the_rule_on_resolved_paths(tmp_path):
    store = tmp_path / "st.zarr"
    (store / "a").mkdir(parents=True)
    (store / "a" / "chunk").write_bytes(b"x")
    (tmp_path / "link").symlink_to(tmp_path)
    os.link(store / "a" / "chunk", tmp_path / "hard")
    for output, how in ((store, "is the input"), (tmp_path / "link" / "st.zarr", "is the input"),
                        (store / "out.ptm", "lies inside the input"),
                        (tmp_path, "holds the input"), (tmp_path / "link", "holds the input"),
                        (tmp_path / "st.zarr" / ".." / "st.zarr", "is the input")):
        with pytest.raises(LtmError, match=f"{how} '{store}'; nothing was written"):
            check_output(output, [None, store])
    with pytest.raises(LtmError, match="is the input"):  # one file under two names
        check_output(tmp_path / "hard", [store / "a" / "chunk"])
    for fine in (tmp_path / "st.zarr2", tmp_path / "out.ptm", tmp_path / "new" / "x"):
        assert check_output(fine, [store, None]) == Path(os.path.realpath(fine))


# --- item 1: export and maps onto their store or the folder holding it --------------------------

@pytest.mark.parametrize("args", [
    ("export", "{store}", "{store}", "--format", "relight", "--overwrite"),
    ("export", "{store}", "{store}", "--format", "ptm", "--overwrite"),
    ("export", "{store}", "{store}/out.ptm", "--format", "ptm"),
    ("maps", "{store}", "{store}", "--overwrite"),
    ("export", "{store}", "{parent}", "--format", "relight", "--overwrite"),
    ("maps", "{store}", "{parent}", "--overwrite"),
    ("export", "{link}/st.zarr", "{parent}", "--format", "relight", "--overwrite"),
    ("relight", "{store}", "--direction", "0,0,1", "-o", "{store}/relit.png", "--overwrite"),
], ids=["export-relight-onto-store", "export-ptm-onto-store", "export-into-store",
        "maps-onto-store", "export-onto-parent", "maps-onto-parent",
        "export-onto-parent-through-a-link", "relight-into-store"])
def test_a_share_command_never_lands_on_its_store(args, far_store, tmp_path, capsys):
    parent = tmp_path / "parent"
    store = copy_of(far_store, parent)
    (parent / "notes.txt").write_text("unrelated, precious")
    (tmp_path / "link").symlink_to(parent)
    before = tree_hashes(tmp_path)
    names = {"store": store, "parent": parent, "link": tmp_path / "link"}
    proc = ltm_here(capsys, *(a.format(**names) for a in args))
    only_error_line(proc, "input", "nothing was written")
    assert tree_hashes(tmp_path) == before
    assert sorted(p.name for p in parent.iterdir()) == ["notes.txt", "st.zarr"]


def test_the_error_maps_never_land_in_a_store(far_store, tmp_path):
    from ltmstore.judge.evaluate import compare_stores

    store = copy_of(far_store, tmp_path)
    before = tree_hashes(tmp_path)
    with pytest.raises(LtmError, match="lies inside the input"):
        compare_stores(store, store, maps_png=store / "maps.png")
    assert tree_hashes(tmp_path) == before


# --- item 2: ingest into its own acquisition folder -------------------------------------------

@pytest.fixture(scope="module")
def acquisition(tmp_path_factory) -> Path:
    """A tiny simulated acquisition with its truth.zarr inside (read-only for the tests)."""
    from ltmstore.synthetic.simulate import simulate_acquisition

    out = tmp_path_factory.mktemp("acq") / "acq"
    simulate_acquisition(out, scene="relief", size=16, seed=1, lattice=(8, 8), progress=False)
    return out


@pytest.mark.parametrize("target", ["truth.zarr", "new.zarr"])
def test_ingest_never_writes_into_its_acquisition(target, acquisition, tmp_path, capsys):
    acq = Path(shutil.copytree(acquisition, tmp_path / "acq"))
    assert (acq / "truth.zarr" / "zarr.json").is_file()
    before = tree_hashes(tmp_path)
    proc = ltm_here(capsys, "ingest", acq, acq / target, "--overwrite")
    only_error_line(proc, "input", str(acq))
    assert tree_hashes(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["acq"]  # no lock, no partial store


# --- item 3: a swap journal left by a killed `ltm compact`, then the folder copied or moved ----

def cp_a(source: Path, target: Path) -> None:
    subprocess.run(["cp", "-a", str(source), str(target)], check=True)


@pytest.fixture
def killed_compact(far_store, tmp_path) -> Path:
    """A folder ``A`` whose ``st.zarr`` was being compacted when the process was killed between
    the two renames of its swap: the journal, the compacted copy and the old store lie beside
    the store's (empty) place."""
    folder = tmp_path / "A"
    store = copy_of(far_store, folder)
    proc = subprocess.Popen([BIN / "ltm", "compact", str(store)],
                            env={**os.environ, PAUSE_ENV: "60"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 120
        while not (journal_path(store).exists() and not store.exists()):
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < end, "the compact never reached its swap"
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    return folder


def the_new_store(folder: Path) -> Path:
    """The compacted copy a killed compact left in ``folder``."""
    (side,) = folder.glob(".st.zarr.partial-copy-*")
    return side


def test_the_journal_holds_names_in_the_store_folder(killed_compact):
    record = json.loads(journal_path(killed_compact / "st.zarr").read_text())
    assert record["store"] == "st.zarr"
    assert {record["side"], record["old"]} == {
        the_new_store(killed_compact).name, next(killed_compact.glob(".st.zarr.old-*")).name}
    assert str(killed_compact) not in json.dumps(record)


def test_a_copied_folder_recovers_its_own_stores_only(killed_compact, tmp_path, capsys):
    a, c = killed_compact, tmp_path / "C"
    before = tree_hashes(a)
    compacted = tree_hashes(the_new_store(a))
    cp_a(a, c)
    info = ltm_here(capsys, "info", c / "st.zarr")
    assert info.returncode == 0, info.stderr
    assert tree_hashes(a) == before  # A is as the kill left it: its journal, both stores
    assert tree_hashes(c / "st.zarr") == compacted
    assert "compact" in json.loads(info.stdout)["stages"]
    assert not journal_path(c / "st.zarr").exists()


def test_a_moved_folder_recovers_its_stores(killed_compact, tmp_path, capsys):
    a, b = killed_compact, tmp_path / "B"
    compacted = tree_hashes(the_new_store(a))
    a.rename(b)  # mv A B
    info = ltm_here(capsys, "info", b / "st.zarr")
    assert info.returncode == 0, info.stderr
    assert tree_hashes(b / "st.zarr") == compacted
    assert sorted(p.name for p in b.iterdir()) == ["st.zarr"]


def test_a_journal_copied_without_its_stores_is_refused(killed_compact, tmp_path, capsys):
    a, c = killed_compact, tmp_path / "C"
    c.mkdir()
    cp_a(journal_path(a / "st.zarr"), c)  # `cp -a A/.st.zarr.swap.json C/`
    before = tree_hashes(tmp_path)
    for command in ("info", "check", "compact"):
        only_error_line(ltm_here(capsys, command, c / "st.zarr"),
                        f"swap journal {str(journal_path(c / 'st.zarr'))!r}", "none of which",
                        "nothing was moved or deleted")
    assert tree_hashes(tmp_path) == before


def test_an_older_journal_of_another_folder_is_refused(killed_compact, tmp_path, capsys):
    """A journal written before the names were relative held absolute paths: in a moved folder
    it names the folder it came from. Refused; both stores stay where they are."""
    a, b = killed_compact, tmp_path / "B"
    journal = journal_path(a / "st.zarr")
    record = json.loads(journal.read_text())
    journal.write_text(json.dumps({"side": str(a / record["side"]),
                                   "old": str(a / record["old"])}))  # as the swap wrote it
    a.rename(b)  # mv A B
    before = tree_hashes(b)
    only_error_line(ltm_here(capsys, "info", b / "st.zarr"),
                    f"swap journal {str(journal_path(b / 'st.zarr'))!r}", "copied or moved",
                    "nothing was moved or deleted")
    assert tree_hashes(b) == before


# --- item 4: ltm demo --overwrite empties only a previous demo's folder -----------------------

def test_demo_overwrite_never_empties_a_users_folder(tmp_path, capsys):
    folder = tmp_path / "mine"
    (folder / "photos").mkdir(parents=True)
    (folder / "photos" / "a.jpg").write_bytes(b"precious")
    (folder / "notes.txt").write_text("mine")
    before = tree_hashes(folder)
    proc = ltm_here(capsys, "demo", "--out", folder, "--overwrite", "--size", "16")
    only_error_line(proc, str(folder), "not a previous ltm demo's")
    assert tree_hashes(folder) == before
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "photos"]


def test_demo_overwrite_replaces_only_its_own_outputs(tmp_path):
    from flows.demo import DEMO_MARKER, DEMO_OUTPUTS, prepare_demo_folder

    folder = prepare_demo_folder(tmp_path / "demo")  # a new folder: marked before anything
    assert (folder / DEMO_MARKER).is_file()
    for name in DEMO_OUTPUTS:  # what a demo wrote
        (folder / name / "sub").mkdir(parents=True)
        (folder / name / "sub" / "f").write_bytes(b"demo")
    (folder / "notes.txt").write_text("the user's, added later")
    with pytest.raises(LtmError, match="pass --overwrite"):
        prepare_demo_folder(folder)
    prepare_demo_folder(folder, overwrite=True)
    assert sorted(p.name for p in folder.iterdir()) == [DEMO_MARKER, "notes.txt"]
    assert (folder / "notes.txt").read_text() == "the user's, added later"
