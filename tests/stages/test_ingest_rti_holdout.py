"""Held-out lights kept in the store (issue 61 item 4).

``ltm ingest-rti --holdout-lights N`` records which photographs it left out (file names,
indices, directions and N) in its stage record; ``ltm info`` lists them, ``ltm evaluate
--holdout-lights`` without a number scores them, and a number that disagrees is refused in one
line. A store without the record behaves as before.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from ingest_helpers import DIRS, write_capture

from ltmstore.capture.lp import hidden_lights
from ltmstore.cli import main
from ltmstore.core.errors import LtmError
from ltmstore.stages.ingest_rti import ingest_rti

EVERY = 4  # of the 11 lights of the tiny capture: lights 3 and 7 held out


def run(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The tiny capture and a store ingested from it with ``--holdout-lights 4``."""
    tmp = tmp_path_factory.mktemp("holdout")
    lp = write_capture(tmp / "cap")
    store = tmp / "s.zarr"
    code = main(["ingest-rti", str(lp), str(store), "--holdout-lights", str(EVERY)])
    assert code == 0
    return lp, store


def test_hidden_lights_is_index_arithmetic_in_capture():
    np.testing.assert_array_equal(np.flatnonzero(hidden_lights(11, 4)), [3, 7])
    with pytest.raises(LtmError, match="--holdout-lights 12 must be a whole number from 2"):
        hidden_lights(11, 12)


def test_ingest_records_the_held_out_photographs_and_info_lists_them(capture, capsys):
    lp, store = capture
    code, out, _ = run(capsys, "info", store)
    assert code == 0
    info = json.loads(out)
    assert info["holdout_every"] == EVERY
    assert [h["index"] for h in info["held_out"]] == [3, 7]
    assert [h["image"] for h in info["held_out"]] == ["im03.png", "im07.png"]
    for h in info["held_out"]:
        d = DIRS[h["index"]] / np.linalg.norm(DIRS[h["index"]])
        np.testing.assert_allclose(h["direction"], d, atol=1e-12)
    assert info["frames"]["n_frames"] == len(DIRS) - 2
    # the ingest's own output lists them as before (index, direction, image)
    code, out, _ = run(capsys, "ingest-rti", lp, store, "--holdout-lights", EVERY, "--overwrite")
    assert code == 0
    report = json.loads(out)
    assert report["held_out"] == info["held_out"] and report["holdout_every"] == EVERY


def test_evaluate_without_the_number_scores_the_recorded_ones(capture, capsys):
    _, store = capture
    code, out, _ = run(capsys, "evaluate", store, "--holdout-lights")
    assert code == 0
    recorded = json.loads(out)
    code, out, _ = run(capsys, "evaluate", store, "--holdout-lights", EVERY)
    assert code == 0
    given = json.loads(out)
    assert recorded["protocol"] == given["protocol"] == f"hide every {EVERY}th light"
    assert recorded["held_out"] == given["held_out"] and len(given["held_out"]) == 2
    for method, row in given["methods"].items():
        assert recorded["methods"][method]["psnr"] == row["psnr"]
        assert recorded["methods"][method]["ssim"] == row["ssim"]


def test_a_number_that_disagrees_is_refused_in_one_line(capture, capsys):
    _, store = capture
    code, out, err = run(capsys, "evaluate", store, "--holdout-lights", "3")
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert "--holdout-lights 3 disagrees with the store" in err
    assert "ingested with --holdout-lights 4" in err


def test_plain_evaluate_names_the_held_out_photographs(capture, capsys):
    """Without the option, evaluate runs the held-out cells test (this store is not
    reconstructed: refused) after a note on how to score the photographs."""
    _, store = capture
    _, _, err = run(capsys, "evaluate", store)
    assert "holds out 2 photographs (ingest-rti --holdout-lights 4)" in err
    assert "--holdout-lights` scores them" in err


def test_a_changed_lp_is_refused(capture, capsys, tmp_path):
    lp, store = capture
    text = lp.read_text()
    try:
        lp.write_text(text.replace("im03.png", "imXX.png").replace("im04.png", "im03.png")
                      .replace("imXX.png", "im04.png"))
        code, _, err = run(capsys, "evaluate", store, "--holdout-lights")
        assert code == 2 and "no longer lists the photographs" in err
    finally:
        lp.write_text(text)


def test_a_store_without_the_record(tmp_path, capsys):
    lp = write_capture(tmp_path / "cap")
    store = tmp_path / "old.zarr"
    assert run(capsys, "ingest-rti", lp, store)[0] == 0
    code, out, _ = run(capsys, "info", store)
    assert "held_out" not in json.loads(out)
    code, _, err = run(capsys, "evaluate", store, "--holdout-lights")
    assert code == 2 and "records no held-out lights" in err
    code, _, err = run(capsys, "evaluate", store)
    assert "holds out" not in err


def test_lights_and_holdout_every_exclude_each_other(tmp_path):
    lp = write_capture(tmp_path / "cap")
    with pytest.raises(LtmError, match="either lights or holdout_every"):
        ingest_rti(lp, tmp_path / "s.zarr", lights=[0, 1, 2], holdout_every=4, progress=False)


def test_ingest_rti_holdout_does_not_import_the_judge(tmp_path):
    lp = write_capture(tmp_path / "cap")
    code = (f"import sys; from ltmstore.cli import main; "
            f"assert main(['ingest-rti', {str(lp)!r}, {str(tmp_path / 's.zarr')!r}, "
            f"'--holdout-lights', '4']) == 0; "
            f"print(sorted(m for m in ('ltmstore.judge.photos', 'skimage') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
