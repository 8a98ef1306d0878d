"""``ltm demo``: simulate an acquisition, run ``process_acquisition``, report accuracy and time."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from ltmstore.core.errors import LtmError

# The demo's own outputs in its folder, and the file that marks the folder as a demo's: only a
# marked folder is ever emptied by --overwrite, and then only of these names.
DEMO_OUTPUTS = ("acquisition", "store.zarr", "previews")
DEMO_MARKER = ".ltm-demo.json"


def prepare_demo_folder(out, *, overwrite: bool = False) -> Path:
    """Create the demo folder ``out`` or make room in a previous demo's.

    A new or empty folder is used as it is. A non-empty one is refused unless ``overwrite``,
    and even then unless it holds :data:`DEMO_MARKER` (a previous demo's folder); then only
    :data:`DEMO_OUTPUTS` are removed, whatever else lies there is left as it is. The marker is
    written before anything else, so a killed demo's folder is recognised too.

    Raises
    ------
    LtmError
        For a path that is not a folder, or a non-empty folder that is not a previous demo's
        (or is one, without ``overwrite``); nothing is removed then.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise LtmError(f"demo folder {str(out)!r} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not (out / DEMO_MARKER).is_file():
            raise LtmError(f"demo folder {str(out)!r} is not empty and is not a previous ltm "
                           f"demo's (no {DEMO_MARKER} in it); --overwrite replaces only a "
                           "demo's own outputs: choose a new or empty folder")
        if not overwrite:
            raise LtmError(f"demo folder {str(out)!r} is not empty; pass --overwrite to replace "
                           "the previous demo there")
        for name in DEMO_OUTPUTS:
            target = out / name
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            elif target.exists() or target.is_symlink():
                target.unlink()
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / DEMO_MARKER).write_text(json.dumps({"written_by": "ltm demo",
                                                   "outputs": list(DEMO_OUTPUTS)}) + "\n")
    except OSError as exc:
        raise LtmError(f"cannot create demo folder {str(out)!r}: {exc.strerror or exc}") from exc
    return out


def run_demo(out, *, scene: str = "relief", size: int = 96, seed: int = 0,
             overwrite: bool = False) -> dict:
    """Run the whole pipeline on embedded defaults and print a short report.

    Local Dask cluster, Prefect with no server configured (a temporary one starts), outputs
    under ``out``: ``acquisition/`` (with ``truth.zarr``), ``store.zarr``, ``previews/`` (at the
    capture's exposure, :func:`ltmstore.stages.preview.render_previews`). A folder that is
    not empty is used only when it is a previous demo's, and then only its outputs are replaced
    (:func:`prepare_demo_folder`).
    """
    out = prepare_demo_folder(out, overwrite=overwrite)  # before Prefect is imported
    from flows.process import process_acquisition
    from ltmstore.core.store import open_store
    from ltmstore.judge.evaluate import compare_stores
    from ltmstore.synthetic.simulate import simulate_acquisition

    acquisition, store = out / "acquisition", out / "store.zarr"

    times = {}
    start = time.perf_counter()
    sim = simulate_acquisition(acquisition, scene=scene, size=size, seed=seed)
    times["simulate"] = time.perf_counter() - start
    truth = acquisition / "truth.zarr"
    lattice = tuple(open_store(truth).sizes[d] for d in ("r", "s"))

    start = time.perf_counter()
    report = process_acquisition(str(acquisition), str(store), preview_dir=str(out / "previews"),
                                 reconstruct_options={"lattice": lattice})
    times["flow (ingest + reconstruct + previews)"] = time.perf_counter() - start
    times["  ingest"] = report["ingest"]["seconds"]
    times["  resample"] = report["reconstruct"]["timings"]["resample_s"]
    times["  solve"] = report["reconstruct"]["timings"]["solve_s"]
    accuracy = compare_stores(store, truth)

    rec = report["reconstruct"]
    print(f"\nltm demo: scene {scene!r}, {size}x{size} pixels, {sim['frames']} frames, "
          f"lattice {lattice[0]}x{lattice[1]}, K/M {rec['sampling_ratio']:.3f}, "
          f"path density {rec['path_density']:.1f}/m")
    print(f"SNR_Y against the ground truth: {accuracy['snr_y_db']:.2f} dB "
          f"(relit PSNR median {accuracy['psnr_db_median']:.2f} dB)")
    for name, seconds in times.items():
        print(f"  {name:<40s} {seconds:7.1f} s")
    print(f"outputs: {store}, {out / 'previews'} (relit_*.png, relight.gif, at the capture's "
          "exposure)")
    return {"simulate": sim, "flow": report, "accuracy": accuracy, "seconds": times}
