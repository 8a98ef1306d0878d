"""Help that explains, and a parser that starts fast: every command and sub-command has a help
line and a description, every argument a help string; building the parser (``ltm --help``)
imports none of the heavy libraries; ``ltm ingest`` given a classic RTI capture names
``ltm ingest-rti``. Start-up time itself is measured by hand (hyperfine), never asserted here."""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys

import pytest
from pipeline_helpers import BIN, one_line_error, run_ltm

from ltmstore.cli import build_parser, main
from ltmstore.cli import names as cli_names

HEAVY = ("numpy", "zarr", "xarray", "dask", "distributed", "prefect", "numba", "scipy", "cv2",
         "sklearn", "skimage", "PIL")


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """``(path, help line, parser)`` of every command and nested sub-command under ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            for name, sub in action.choices.items():
                yield (*path, name), helps.get(name), sub
                yield from commands(sub, (*path, name))


COMMANDS = list(commands(build_parser()))
IDS = [" ".join(path) for path, _, _ in COMMANDS]


def test_the_walk_sees_every_command_and_the_nested_ones():
    assert {"simulate", "ingest", "ingest-rti", "calibrate", "relight", "archive",
            "archive status", "archive run", "archive serve"} <= set(IDS)


@pytest.mark.parametrize(("path", "line", "parser"), COMMANDS, ids=IDS)
def test_every_command_has_a_help_line_and_a_description(path, line, parser):
    assert line and line.strip(), f"`ltm {' '.join(path)}` has no line in its parent's --help"
    assert parser.description and parser.description.strip(), (
        f"`ltm {' '.join(path)} --help` has no description")


@pytest.mark.parametrize(("path", "line", "parser"), COMMANDS, ids=IDS)
def test_every_argument_has_a_help_string(path, line, parser):
    missing = [action.option_strings or [action.dest] for action in parser._actions
               if not isinstance(action, argparse._HelpAction | argparse._SubParsersAction)
               and not (action.help and action.help.strip())]
    assert not missing, f"`ltm {' '.join(path)}`: no help for {missing}"


@pytest.mark.parametrize(("path", "line", "parser"), COMMANDS, ids=IDS)
def test_help_shows_the_description(path, line, parser, capsys):
    with pytest.raises(SystemExit) as done:
        main([*path, "--help"])
    assert done.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert " ".join(parser.description.split())[:60] in out


def test_the_top_level_help_lists_every_command_with_its_line(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    for path, line, _ in COMMANDS:
        if len(path) == 1:
            assert f"{path[0]} {' '.join(line.split())}" in out, path


def loaded_after(code: str) -> list[str]:
    """The heavy modules a fresh interpreter holds after running ``code``."""
    probe = (f"import sys\n{code}\n"
             f"print(__import__('json').dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_building_the_parser_imports_no_heavy_module():
    assert loaded_after("import ltmstore.cli as c\nc.build_parser()") == []


@pytest.mark.parametrize("command", [[], ["relight"], ["ingest-rti"], ["reconstruct"],
                                     ["archive", "run"], ["capture"], ["export"]])
def test_help_of_a_command_imports_no_heavy_module(command):
    code = ("import ltmstore.cli as c\n"
            f"try:\n    c.main({[*command, '--help']!r})\nexcept SystemExit:\n    pass")
    assert loaded_after(code) == []


def test_the_ltm_script_help_imports_no_heavy_module():
    """The console script itself, as a user runs it: ``-X importtime`` lists what it imported."""
    proc = subprocess.run([sys.executable, "-X", "importtime", BIN / "ltm", "--help"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "usage: ltm" in proc.stdout, proc.stderr
    imported = {line.rpartition("|")[2].strip() for line in proc.stderr.splitlines()
                if line.startswith("import time:")}
    assert "ltmstore.cli" in imported
    assert not imported & set(HEAVY), sorted(imported & set(HEAVY))


@pytest.mark.parametrize("name", sorted(cli_names.ORIGINALS))
def test_the_parsers_names_agree_with_the_library(name):
    module, attribute = cli_names.ORIGINALS[name]
    assert getattr(cli_names, name) == getattr(importlib.import_module(module), attribute)


def test_the_parsers_method_names_agree_with_the_solver_registry():
    from ltmstore.solve import METHODS

    assert cli_names.METHOD_NAMES == tuple(sorted(METHODS))
    assert "auto" not in METHODS  # offered beside the registry's names


def rti_folder(tmp_path, *names: str):
    folder = tmp_path / "rti"
    folder.mkdir()
    for name in names:
        (folder / name).write_text("1\nim00.jpg 0.0 0.0 1.0\n")
    return folder


def test_ingest_of_a_classic_capture_folder_names_ingest_rti(tmp_path):
    folder = rti_folder(tmp_path, "lights.lp")
    store = tmp_path / "s.zarr"
    proc = run_ltm("ingest", folder, store)
    one_line_error(proc, f"use `ltm ingest-rti {folder / 'lights.lp'} {store}`")
    assert not store.exists()


def test_ingest_of_a_lp_file_names_ingest_rti(tmp_path, capsys):
    lp = rti_folder(tmp_path, "dome.LP") / "dome.LP"
    assert main(["ingest", str(lp), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ltm: error: ") and err.count("\n") == 1, err
    assert f"ltm ingest-rti {lp} {tmp_path / 's.zarr'}" in err, err


def test_ingest_of_a_folder_with_several_lp_files_names_them(tmp_path, capsys):
    folder = rti_folder(tmp_path, "a.lp", "b.lp")
    assert main(["ingest", str(folder), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert f"ltm ingest-rti {folder / 'a.lp'}" in err and "a.lp, b.lp" in err, err


def test_an_acquisition_folder_with_a_lp_file_is_read_as_an_acquisition(tmp_path, capsys):
    """acquisition.json decides: its own problems are reported, not ingest-rti."""
    folder = rti_folder(tmp_path, "lights.lp")
    (folder / "acquisition.json").write_text("{")
    assert main(["ingest", str(folder), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert "not valid JSON" in err and "ingest-rti" not in err, err
