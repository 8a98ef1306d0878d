"""Option values fuzzed over every ``ltm`` command (hypothesis, derandomized): out-of-range,
negative and huge numbers, NaN and infinities, empty strings, odd unicode, wrong choices,
malformed ``RxS`` lattices and paths that do not exist. Each run ends in exit 0, 2 or 75 (a
store being written), never a traceback, and at most one line besides warnings and notes.

The commands run in this process (``ltmstore.cli.main``), in a scratch folder. No command can
do long work: the inputs named are missing, or an existing folder that is not the command's
(``demo --out``, ``simulate OUT``), so every value is checked and then the run is refused;
``bench`` (only ``--out`` and ``--quick``, a sweep of minutes) is left out, and each run is
stopped by an alarm after :data:`RUN_LIMIT_S`.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import signal
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ltmstore.cli import build_parser, main

SKIPPED = {"bench"}  # a sweep of minutes whatever its options
EXAMPLES = 25  # per command (22 of them): 60 s for 30 at load 20, 2 cores
RUN_LIMIT_S = 60
EXIT_CODES = {0, 2, 75}  # 75: BUSY, a store being written (ltmstore.cli.check)
SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))
FOREIGN = "foreign"  # a non-empty folder in the scratch folder that no command wrote
MISSING = "missing/none.zarr"

ODD = ["", " ", "-1", "0", "-0", "1", "3.5", "1e309", "-1e309", "nan", "NaN", "inf", "-inf",
       "99999999999999999999", "1e9", "-2147483649", "0x10", "1,2", "1,2,3", "1,nan", "a,b",
       ",", "0x0", "300x300", "-3x4", "1x", "x", "32x32x32", "1e3x2", "4x4", "\u2713",
       "\u202etxt.png", "\u00e9t\u00e9", "\U0001f600", "a" * 300, MISSING, "/proc/x",
       FOREIGN, "--", "-", "auto"]
TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00/\\"),
               max_size=10)  # no folder separators: every path drawn stays in the scratch folder
VALUES = st.one_of(st.sampled_from(ODD), st.integers(-2**70, 2**70).map(str),
                   st.floats().map(repr), TEXT)


def commands() -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every runnable command of the parser: ``(("archive", "run"), its parser)``, ..."""
    found = []

    def walk(parser: argparse.ArgumentParser, prefix: tuple[str, ...]) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            found.append((prefix, parser))
        for sub in subs:
            for name, child in sub.choices.items():
                walk(child, (*prefix, name))

    walk(build_parser(), ())
    return [(name, parser) for name, parser in found if name[0] not in SKIPPED]


COMMANDS = commands()


def positional(command: tuple[str, ...], action: argparse.Action) -> str:
    """An input that does not exist, or a folder that is not the command's to write."""
    if action.dest in ("out", "folder", "output"):
        return FOREIGN
    return MISSING


@st.composite
def argvs(draw, command: tuple[str, ...], parser: argparse.ArgumentParser) -> list[str]:
    argv = list(command)
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction | argparse._VersionAction):
            continue
        if not action.option_strings:
            argv.append(positional(command, action))
            continue
        if not (action.required or draw(st.booleans())):
            continue
        flag = draw(st.sampled_from(action.option_strings))
        if action.nargs == 0:
            argv.append(flag)
            continue
        choices = list(action.choices or [])
        value = draw(st.one_of(VALUES, st.sampled_from(choices)) if choices else VALUES)
        argv.append(f"{flag}={value}")
    if command == ("demo",):  # its default --out would be a new folder: the whole demo
        argv.append(f"--out={FOREIGN}")
    return argv


class Hung(Exception):
    pass


def run_here(argv: list[str]) -> tuple[int, str]:
    """``ltm argv`` in this process: its exit status and stderr."""
    def hung(signum, frame):
        raise Hung(f"ltm {argv} ran past {RUN_LIMIT_S} s")

    err = io.StringIO()
    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(RUN_LIMIT_S)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 2
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return code, err.getvalue()


@pytest.fixture(scope="module")
def scratch():
    """A scratch working folder with :data:`FOREIGN` in it; the previous one restored after."""
    before = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="ltm-fuzz-") as folder:
        (Path(folder) / FOREIGN).mkdir()
        (Path(folder) / FOREIGN / "notes.txt").write_text("not an ltm output")
        os.chdir(folder)
        try:
            yield Path(folder)
        finally:
            os.chdir(before)


@pytest.mark.parametrize("command", [c for c, _ in COMMANDS], ids=" ".join)
def test_every_option_value_is_a_result_or_one_error_line(scratch, command):
    parser = dict(COMMANDS)[command]

    @SETTINGS
    @given(argvs(command, parser))
    def check(argv):
        code, err = run_here(argv)
        assert "Traceback" not in err, (argv, err[-3000:])
        assert code in EXIT_CODES, (argv, code, err[-3000:])
        said = [line for line in err.splitlines() if line.strip() and not line.startswith(
            ("ltm: warning:", "ltm: note:")) and "\r" not in line]  # progress bars: \r
        assert len(said) <= (0 if code == 0 else 1), (argv, err[-3000:])
        if code == 2:
            assert said and said[0].startswith(("ltm: error:", "ltm ")), (argv, err)
        assert (scratch / FOREIGN / "notes.txt").read_text() == "not an ltm output"

    check()


def test_the_walk_finds_every_command():
    names = {" ".join(c) for c, _ in COMMANDS}
    assert {"simulate", "relight", "export", "archive run", "archive serve", "view",
            "capture"} <= names
    assert len(names) >= 22, names
