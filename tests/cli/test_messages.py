"""Messages a person can act on: one error prefix, the closest option for a misspelt one, one
unit for the path density, no advice that does not apply, and the browser tests' skip."""

from __future__ import annotations

import re
import shutil
import warnings

import numpy as np
import pytest
from conftest import SMALL_PATH_DENSITY
from locations import ROOT
from pipeline_helpers import ltm_here

from ltmstore.cli import main
from ltmstore.core.errors import LtmWarning


def error_of(argv: list[str], capsys) -> str:
    """The one stderr line of ``ltm ARGV`` refused with exit status 2."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1, (code, err)
    return err.strip()


@pytest.mark.parametrize(("argv", "hint"), [
    (["relight"], "(see ltm relight --help)"),
    (["reconstruct", "s.zarr", "--method", "magic"], "(see ltm reconstruct --help)"),
    (["archive", "run"], "(see ltm archive run --help)"),
    (["reconstrct"], "(see ltm --help)"),
])
def test_every_command_prints_the_one_prefix(argv, hint, capsys):
    err = error_of(argv, capsys)
    assert err.startswith("ltm: error: ") and err.endswith(hint), err


@pytest.mark.parametrize(("argv", "suggestion"), [
    (["reconstruct", "s.zarr", "--latice", "16x16"], "did you mean --lattice?"),
    (["reconstruct", "s.zarr", "--latice=16x16"], "did you mean --lattice?"),
    (["reconstruct", "s.zarr", "--latice", "8x8", "--metod", "cs"],
     "did you mean --lattice instead of --latice, --method instead of --metod?"),
    (["reconstrct", "s.zarr"], "did you mean 'reconstruct'?"),
    (["reconstruct", "s.zarr", "--method", "lar"], "did you mean 'lars'?"),
    (["archive", "runn"], "did you mean 'run'?"),
    # argparse names the missing required option before the unknown one
    (["relight", "s.zarr", "--drection", "0,0,1"],
     "did you mean --direction instead of --drection?"),
])
def test_a_misspelt_option_or_command_names_the_right_one(argv, suggestion, capsys):
    err = error_of(argv, capsys)
    assert err.startswith("ltm: error: ") and suggestion in err, err


def test_nothing_close_is_suggested_for_a_word_far_from_every_option(capsys):
    err = error_of(["reconstruct", "s.zarr", "--foo"], capsys)
    assert "unrecognized arguments: --foo" in err and "did you mean" not in err, err


def test_path_density_is_per_metre_where_it_is_printed(small_store, dask_cluster, tmp_path,
                                                        capsys):
    """`ltm reconstruct` printed `/unit`; `ltm demo`, `ltm simulate --help` and the bench say
    `/m` (the plane's unit)."""
    store = shutil.copytree(small_store, tmp_path / "s.zarr")
    done = ltm_here(capsys, "reconstruct", store, "--lattice", "16x16", "--overwrite",
                    "--scheduler", dask_cluster.scheduler_address)
    assert done.returncode == 0, done.stderr
    density = re.search(r"path density ([0-9.]+)/m ", done.stdout)
    assert density, done.stdout
    # achieved on the 0.4 m plane of the small capture; simulated at 14/m
    assert float(density[1]) == pytest.approx(SMALL_PATH_DENSITY, rel=0.2), density[1]
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert "(1/m)" in capsys.readouterr().out


def test_view_of_a_far_store_gives_no_advice_that_does_not_apply(tmp_path):
    """A far-light store relights from its frames: it has no light-major copy to miss, and
    `ltm compact` would not write one (it warned and advised `ltm compact` before)."""
    from ingest_helpers import write_capture

    from ltmstore.core.lights import elevation_azimuth
    from ltmstore.core.store import open_store
    from ltmstore.share.view import Viewer
    from ltmstore.stages.by_light import by_light_name
    from ltmstore.stages.ingest_rti import ingest_rti
    from ltmstore.stages.reconstruct import reconstruct

    lights = elevation_azimuth(np.repeat([30, 50, 75], 6), np.tile(np.arange(0, 360, 60), 3))
    ingest_rti(write_capture(tmp_path / "cap", dirs=lights), tmp_path / "s.zarr", progress=False)
    reconstruct(tmp_path / "s.zarr", progress=False)
    assert by_light_name("ltm") not in open_store(tmp_path / "s.zarr")
    with warnings.catch_warnings():
        warnings.simplefilter("error", LtmWarning)
        Viewer(tmp_path / "s.zarr")


def test_a_missing_browser_skips_with_its_name_unless_ci_requires_it(monkeypatch):
    """The README's test command passes where chromium is not installed; .ci/run fails."""
    import browser

    monkeypatch.setattr(browser, "CHROMIUM", ("no-such-chromium-here",))
    monkeypatch.delenv(browser.REQUIRE, raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"chromium is missing.*apt-get install "
                                                     r"chromium"):
        browser.chromium_path()
    monkeypatch.setenv(browser.REQUIRE, "1")
    with pytest.raises(AssertionError, match="LTM_REQUIRE_BROWSER is set"):
        browser.chromium_path()
    assert f"export {browser.REQUIRE}=1" in (ROOT / ".ci" / "run").read_text()
