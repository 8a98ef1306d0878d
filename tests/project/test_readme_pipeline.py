"""The README's pipeline block runs top to bottom, as a person pastes it into a shell.

The ```bash block under "## The pipeline" is run as one ``set -euo pipefail`` script in a
temporary folder, with the ``ltm`` of this environment first on ``PATH``. To keep it fast the
test makes two documented substitutions and nothing else:

* ``ltm simulate`` gets ``--size 32`` (32 x 32 pixels instead of the default 128 x 128), and
* ``--lattice 32x32`` becomes ``--lattice 16x16``;

and ``../shared/data`` (relative to the clone's root, where the README is run) becomes that
folder's absolute path. Without ``../shared/data`` the test is skipped.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from locations import ROOT

DATA = ROOT.parent / "shared" / "data"
SUBSTITUTIONS = [(r"(ltm simulate \S+ [^#\n]*?)\s*(#|$)", r"\1 --size 32  \2"),
                 (r"--lattice 32x32", "--lattice 16x16")]
# What the block must leave behind (checked after it ran).
OUTPUTS = ["acq/", "acq/truth.zarr/", "store.zarr/", "relit-0.png", "relit-1.png", "both.png",
           "err.png", "rti.zarr/", "raking.png"]


def pipeline_block(readme: str) -> str:
    """The first ```bash block after the heading "## The pipeline"."""
    section = readme.split("\n## The pipeline\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"^```bash\n(.*?)^```", section, re.S | re.M)
    assert match, "no ```bash block under ## The pipeline"
    return match.group(1)


def test_block_has_no_placeholders_and_writes_no_tracked_file():
    block = pipeline_block((ROOT / "README.md").read_text())
    commands = [line.split("#", 1)[0] for line in block.splitlines()]
    assert commands and all(c.strip().startswith("ltm ") for c in commands if c.strip())
    text = " ".join(commands)
    assert not re.search(r"tcp://|HOST|host:|<[a-z_]+>|bench/results", text), text
    compact = [i for i, c in enumerate(commands) if c.startswith("ltm compact store.zarr")]
    rebuild = [i for i, c in enumerate(commands)
               if re.match(r"ltm (reconstruct|ingest) .*store\.zarr", c)]
    assert compact and max(rebuild) < compact[0], "store.zarr is rebuilt after ltm compact"


def test_block_outputs_are_ignored_by_git():
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout")
    run = subprocess.run(["git", "check-ignore", "--no-index", *OUTPUTS, "bench-out/"],
                         cwd=ROOT, capture_output=True, text=True)
    ignored = set(run.stdout.split())
    assert ignored == {*OUTPUTS, "bench-out/"}, f"not ignored: {set(OUTPUTS) - ignored}"


@pytest.mark.skipif(not (DATA / "loewenkopf" / "dirs.lp").is_file(),
                    reason=f"the README's RTI capture {DATA}/loewenkopf is absent")
def test_readme_pipeline_block_runs(tmp_path):
    script = pipeline_block((ROOT / "README.md").read_text())
    for pattern, replacement in SUBSTITUTIONS:
        script, n = re.subn(pattern, replacement, script, flags=re.M)
        assert n, f"the README's block no longer has {pattern!r}: update this test"
    script = script.replace("../shared/data", shlex.quote(str(DATA)))
    (tmp_path / "pipeline.sh").write_text("set -euo pipefail\nset -x\n" + script)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    run = subprocess.run(["bash", "pipeline.sh"], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=540)
    assert run.returncode == 0, run.stderr[-6000:]
    for name in OUTPUTS:
        path = tmp_path / name.rstrip("/")
        assert path.is_dir() if name.endswith("/") else path.stat().st_size > 0, name
    # each command ran (set -x echoes it) and on the substituted sizes
    ran = [line[2:] for line in run.stderr.splitlines() if line.startswith("+ ltm ")]
    assert len(ran) == sum(1 for line in script.splitlines() if line.startswith("ltm ")), ran
    summary = subprocess.run(["ltm", "info", "store.zarr"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, check=True).stdout
    info = json.loads(summary)
    assert info["complete"] and info["frames"]["stored"] is False, info["frames"]  # compacted
    assert info["parameters"]["lattice"]["shape"] == [16, 16]  # the substituted lattice
    assert info["parameters"]["plan"]["image"] == [32, 32]  # the substituted size
