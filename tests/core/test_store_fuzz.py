"""Random damage to a store (issue 27): whatever is truncated, emptied, deleted, replaced by a
folder or flipped, and whatever a ``zarr.json`` is made to say, ``ltm check``, ``ltm info`` and
``ltm relight`` print no traceback, and none exits 0 with a wrong result.

A fixed set of seeds, half on a near store, half on a far one, each damaging one to three
parts of a fresh copy. Byte flips are made in chunk files only: the metadata carries no
checksum (a flipped digit in an attribute, a plane's height, is a valid different store), so
what a ``zarr.json`` may say is fuzzed by structured edits instead.
"""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import imageio.v3 as iio
import pytest
from pipeline_helpers import ltm_here
from test_store_damage import LIGHTS

SEEDS = range(30)
DATA_TYPES = ("float16", "float32", "float64", "int16", "int32", "int64", "bool", "uint8")


def _files(store: Path) -> tuple[list[Path], list[Path]]:
    """The chunk files and the arrays' ``zarr.json`` files of ``store``."""
    chunks = sorted(f for f in store.rglob("*") if f.is_file() and f.name != "zarr.json")
    metadata = sorted(f for f in store.glob("*/zarr.json") if f.is_file())
    return chunks, metadata


def _editable(path: Path) -> bool:
    """Whether ``path`` is still an array's ``zarr.json`` with what :func:`edit_metadata`
    edits (an earlier damage may have broken it)."""
    try:
        meta = json.loads(path.read_text())
        return all(k in meta for k in ("shape", "codecs", "chunk_grid", "dimension_names",
                                       "chunk_key_encoding"))
    except ValueError:
        return False


def damage_file(rng: random.Random, path: Path) -> tuple[str, bool]:
    """Damage one file; returns what was done and whether it shows without reading data."""
    kind = rng.choice(["zero", "truncate", "delete", "folder", "flip"] if path.name != "zarr.json"
                      else ["zero", "truncate", "delete", "folder"])
    size = path.stat().st_size
    if kind == "zero":
        path.write_bytes(b"")
    elif kind == "truncate":
        path.write_bytes(path.read_bytes()[: rng.randrange(max(size, 1))])
    elif kind in ("delete", "folder"):
        path.unlink()
        if kind == "folder":
            path.mkdir()
    else:
        data = bytearray(path.read_bytes())
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(data))
    seen = kind not in ("flip",) and not (kind == "truncate" and path.name != "zarr.json")
    return f"{kind} {path.name}", seen


def edit_metadata(rng: random.Random, path: Path) -> str:
    """One structured edit of an array's ``zarr.json``."""
    meta = json.loads(path.read_text())
    grid = meta["chunk_grid"]["configuration"]["chunk_shape"]
    axis = rng.randrange(len(meta["shape"])) if meta["shape"] else None
    edits = {
        "data_type": lambda: meta.update(data_type=rng.choice(DATA_TYPES)),
        "shape": lambda: meta["shape"].__setitem__(axis, max(1, meta["shape"][axis]
                                                              + rng.choice([-1, 1, 5]))),
        "chunks": lambda: grid.__setitem__(axis, max(1, rng.choice([grid[axis] * 2,
                                                                    grid[axis] // 2]))),
        "codec": lambda: meta["codecs"].pop(rng.randrange(len(meta["codecs"]))),
        "endian": lambda: [c.setdefault("configuration", {}).update(endian="big")
                           for c in meta["codecs"] if c["name"] == "bytes"],
        "dims": lambda: meta.update(dimension_names=list(reversed(meta["dimension_names"]))),
        "dim name": lambda: meta["dimension_names"].__setitem__(axis, "w"),
        "key": lambda: meta.pop(rng.choice(["shape", "data_type", "codecs", "chunk_grid"])),
        "separator": lambda: meta["chunk_key_encoding"]["configuration"].update(separator="."),
        "node_type": lambda: meta.update(node_type="group"),
        "fill_value": lambda: meta.update(fill_value=rng.choice([0, 1, "NaN"])),
    }
    if axis is None:
        edits = {k: v for k, v in edits.items() if k not in ("shape", "chunks", "dim name")}
    name = rng.choice(sorted(edits))
    edits[name]()
    path.write_text(json.dumps(meta))
    return f"{name} in {path.parent.name}/zarr.json"


def damage(rng: random.Random, store: Path) -> tuple[list[str], bool]:
    """One to three random damages; whether all of them show without reading data."""
    done, seen = [], True
    for _ in range(rng.randint(1, 3)):
        chunks, metadata = _files(store)
        editable = [m for m in metadata if _editable(m)]
        if editable and rng.random() < 0.35:
            done.append(edit_metadata(rng, rng.choice(editable)))
        elif chunks or metadata:
            what, shows = damage_file(rng, rng.choice(chunks + metadata))
            done.append(what)
            seen &= shows
    return done, seen


def run(capsys, *args):
    """``ltm ARGS`` in this process; a traceback (an exception out of main) fails the test."""
    proc = ltm_here(capsys, *args)
    assert proc.returncode in (0, 2), (args, proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


@pytest.fixture(scope="module")
def originals(small_store, far_store, tmp_path_factory):
    """Each store kind with its image at ``LIGHTS``, undamaged (8-bit: relit twice, an
    undamaged store gives the same bytes)."""
    from ltmstore.cli import main

    root = tmp_path_factory.mktemp("fuzz-originals")
    out = {}
    for kind, store in (("near", small_store), ("far", far_store)):
        image = root / f"{kind}.png"
        assert main(["relight", str(store), *LIGHTS[kind], "-o", str(image)]) == 0
        out[kind] = (store, iio.imread(image))
    return out


@pytest.mark.parametrize("seed", SEEDS)
def test_random_damage_is_never_served(seed, originals, tmp_path, capsys):
    rng = random.Random(seed)
    kind = ("near", "far")[seed % 2]
    source, expected = originals[kind]
    store = tmp_path / f"{kind}.zarr"
    shutil.copytree(source, store)
    done, structural = damage(rng, store)

    check = run(capsys, "check", store)
    info = run(capsys, "info", store)
    if info.returncode == 0 and check.returncode == 2 and structural:
        assert json.loads(info.stdout)["complete"] is False, (done, check.stderr)
    image = tmp_path / "relit.png"
    relit = run(capsys, "relight", store, *LIGHTS[kind], "-o", image)
    if relit.returncode == 0:
        relit_image = iio.imread(image)
        assert relit_image.shape == expected.shape and (relit_image == expected).all(), (
            done, "exit 0 with a wrong image")
    else:
        lines = relit.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("ltm: error: "), (done, relit.stderr)
        assert not image.exists(), done
