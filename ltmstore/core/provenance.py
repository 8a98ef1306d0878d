"""Provenance: which software and which parameters made a store, from which inputs, and when.

Every stage record (group attribute ``stages``) holds ``software`` (:func:`software`), its
parameters, its timings and ``complete``, written last. :func:`summary` gathers them into the
one record that ``ltm info STORE`` prints and that ``ltm archive status`` compares against the
current software and the requested parameters.
"""

from __future__ import annotations

import functools
import subprocess
from importlib import metadata
from pathlib import Path

STAGE_ORDER = ("ingest", "resample", "reconstruct")


@functools.cache
def commit() -> str | None:
    """The git commit of the source tree ltmstore runs from (``None`` when not a checkout)."""
    source = Path(__file__).resolve().parents[2]
    if not (source / ".git").exists():
        return None
    try:
        out = subprocess.run(["git", "-C", str(source), "rev-parse", "HEAD"], check=True,
                             capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(source), "status", "--porcelain",
                                "--untracked-files=no", "ltmstore"], capture_output=True,
                               text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    sha = out.stdout.strip()
    return f"{sha}+dirty" if dirty.stdout.strip() else sha or None


def version() -> str:
    """The installed ltmstore's version (``0.0.0+unknown`` when running from a bare source tree)."""
    try:
        return metadata.version("ltmstore")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0.0.0+unknown"


def software() -> dict:
    """``{"name", "version", "commit"}`` of the running ltmstore."""
    return {"name": "ltmstore", "version": version(), "commit": commit()}


def _placement(record: dict) -> dict:
    """Where the surface model placed the object (``ltm info``): the source, the extent used,
    and the estimate from the capture with its uncertainty (plane units and pixels), its
    orientation and how the surface model levelled it."""
    found = record.get("estimate") or {}
    out = {"source": record.get("source"), "extent": record.get("extent")}
    if found:
        out["estimated"] = {"extent": found.get("extent"), "sigma": found.get("sigma"),
                            "uncertainty": found.get("uncertainty"),
                            "sigma_pixels": found.get("sigma_pixels"),
                            "uncertainty_pixels": found.get("uncertainty_pixels"),
                            "support": found.get("support"),
                            **{key: found[key] for key in ("orientation", "levelled")
                               if key in found}}
    for key in ("disagreement", "reason"):
        if key in record:
            out[key] = record[key]
    return out


def summary(attrs: dict) -> dict:
    """A store's provenance from its group attributes.

    Parameters
    ----------
    attrs : dict
        The store's group attributes (``zarr.Group.attrs.asdict()``).

    Returns
    -------
    dict
        ``complete`` (every recorded stage finished and ``reconstruct`` among them),
        ``software`` (of the last completed stage), ``inputs`` (source, file names, sha256),
        ``parameters`` (of the reconstruct stage: lattice, method, solver settings, the run
        key), ``sampling`` (K, M, K/M, path density), ``placement`` (near light: where the
        surface model placed the object, declared or estimated, with the estimate's
        uncertainty), ``frames`` (of ingest: how many, how
        many valid, rejected per reason, e.g. ``occluded``, and dropped from a damaged video;
        ``stored: false`` once ``ltm compact`` removed them), ``holdout_every`` and ``held_out``
        (a classic capture ingested with ``--holdout-lights EVERY``: the photographs left out,
        each with its ``index``, ``image`` and ``direction``), ``compact`` (when the store was
        compacted: precision, SNR of a lossy LTM, whether frames were dropped),
        ``timings`` (seconds per stage) and ``stages`` (started/finished/complete per stage).
    """
    stages = dict(attrs.get("stages") or {})
    acquisition = dict(attrs.get("acquisition") or {})
    rec = stages.get("reconstruct") or {}
    res = stages.get("resample") or {}
    ingest = stages.get("ingest") or {}
    compact = stages.get("compact") or {}
    timings = {}
    if "seconds" in (stages.get("ingest") or {}):
        timings["ingest_s"] = stages["ingest"]["seconds"]
    timings.update(rec.get("timings") or {})
    last = [stages[n] for n in STAGE_ORDER if (stages.get(n) or {}).get("complete")]
    sampling = rec if "K" in rec else res
    return {
        "complete": bool(rec.get("complete")) and all(e.get("complete")
                                                       for e in stages.values()),
        "software": ({"version": last[-1].get("software"), "commit": last[-1].get("commit")}
                     if last else None),
        "inputs": {k: acquisition[k] for k in ("source", "folder", "video", "poses", "lp",
                                               "images", "sha256") if k in acquisition},
        "parameters": {k: rec[k] for k in ("run", "method", "params", "auto", "color",
                                           "lattice", "lattice_choice", "plan") if k in rec},
        "sampling": {k: sampling[k] for k in ("K", "M", "sampling_ratio", "path_density")
                     if k in sampling},
        **({"placement": _placement(rec["placement"])} if rec.get("placement") else {}),
        "frames": {**{k: ingest[k] for k in ("n_frames", "n_valid", "rejected",
                                              "dropped_frames") if k in ingest},
                   **({"stored": False, "removed_by": "ltm compact"}
                      if compact.get("frames_dropped") else {})},
        **({k: ingest[k] for k in ("holdout_every", "held_out")} if ingest.get("held_out")
           else {}),
        **({"compact": {k: compact[k] for k in ("precision", "form", "snr_db", "target_db",
                                                "rank_rule", "heldout_fraction",
                                                "tile", "ranks", "factor_bytes",
                                                "dense_bytes", "frames_dropped",
                                                "bytes_before", "finished") if k in compact}}
           if compact else {}),
        "timings": timings,
        "stages": {name: {k: e[k] for k in ("complete", "started", "finished", "software",
                                            "commit", "tiles_solved", "tiles_resumed")
                          if k in e}
                   for name, e in stages.items()},
    }
