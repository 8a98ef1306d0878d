"""Held-out photographs on the real captures (../shared/data) and on a tiny synthetic one.

The acceptance of issue 17: the default pipeline's mean held-out PSNR is never more than
0.2 dB below the best of the project's own PTM, HSH2, HSH3, RBF and (issue 28) HSH3 + RBF
residual fits on the same lights. With the surface model (issue 15) it is above them, by about
what ``bench/heldout_table.py`` measured (:data:`MEASURED_GAIN_DB`).
"""

from __future__ import annotations

import numpy as np
import pytest
from ingest_helpers import write_capture
from locations import SHARED_DATA

from ltmstore.core.errors import LtmError
from ltmstore.judge.photos import CLASSIC, heldout_photos, score

SYNTH = "synthrti/single-obj1-material1"
CAPTURES = {"realrti-item9-coin": {}, "loewenkopf": {}, "realrti-item3-icon": {},
            SYNTH: {"test_lp": SHARED_DATA / SYNTH / "test" / "dirs.lp"}}
TOLERANCE_DB = 0.2
# default - best classic fit (dB), python bench/heldout_table.py, 2026-11-25 (HSH3 + RBF residual
# among the classic fits: it is single-obj1-material1's best, and the default takes it)
MEASURED_GAIN_DB = {"realrti-item9-coin": 0.94, "loewenkopf": 0.84, "realrti-item3-icon": 2.54,
                    SYNTH: 0.00}


@pytest.mark.parametrize("name", sorted(CAPTURES))
def test_default_is_never_far_below_the_best_classic_fit(name):
    folder = SHARED_DATA / name
    if not folder.is_dir():
        pytest.skip(f"shared/data/{name} not found: expected the real captures at {folder}")
    lp = folder / ("dome/dirs.lp" if "test_lp" in CAPTURES[name] else "dirs.lp")
    report = heldout_photos(lp, **CAPTURES[name])
    rows = report["methods"]
    assert set(rows) == {"default", *CLASSIC}
    n = len(report["held_out"])
    assert n >= 8 and all(len(r["psnr"]) == n and np.isfinite(r["psnr"]).all()
                          for r in rows.values())
    assert all(0 < r["mean_ssim"] <= 1 for r in rows.values())
    assert report["default_minus_best_classic_db"] >= MEASURED_GAIN_DB[name] - TOLERANCE_DB, report


def test_score_is_psnr_and_ssim_of_8_bit_srgb():
    photo = np.full((16, 16, 3), 128, np.uint8)
    from ltmstore.core.transfer import decode

    exact = decode(photo, "srgb")
    with np.errstate(divide="ignore"):
        assert score(exact, photo) == (float("inf"), 1.0)
    off = decode(photo + 1, "srgb")  # one level off everywhere: MSE 1
    assert score(off, photo)[0] == pytest.approx(10 * np.log10(255**2))


def test_tiny_capture_and_bad_arguments(tmp_path):
    lp = write_capture(tmp_path / "cap", dirs=np.column_stack([
        np.cos(np.arange(16)), np.sin(np.arange(16)), 1 + np.arange(16) % 3]))
    report = heldout_photos(lp, every=4, methods=("default", "ptm"))
    assert report["protocol"] == "hide every 4th light" and report["n_train"] == 12
    assert np.isfinite([r["mean_psnr"] for r in report["methods"].values()]).all()
    with pytest.raises(LtmError, match="--holdout-lights 1 must be a whole number from 2"):
        heldout_photos(lp, every=1)
    with pytest.raises(LtmError, match=r"unknown methods \['lars'\]"):
        heldout_photos(lp, methods=("lars",))


def test_cli_evaluate_holdout_lights(tmp_path, capsys):
    import json

    from ltmstore.cli import main

    lp = write_capture(tmp_path / "cap", dirs=np.column_stack([
        np.cos(np.arange(12)), np.sin(np.arange(12)), 1 + np.arange(12) % 3]))
    store = str(tmp_path / "s.zarr")
    assert main(["ingest-rti", str(lp), store]) == 0
    capsys.readouterr()
    assert main(["evaluate", store, "--holdout-lights", "4"]) == 0
    out = capsys.readouterr()
    report = json.loads(out.out)
    assert report["protocol"] == "hide every 4th light" and len(report["held_out"]) == 3
    assert set(report["methods"]) == {"default", *CLASSIC}
    assert out.err.count("PSNR") == 1 + len(CLASSIC)
    assert main(["evaluate", store, "--holdout-lights", "2", "--test-lights", str(lp)]) == 2
    assert "either --holdout-lights or --test-lights" in capsys.readouterr().err
