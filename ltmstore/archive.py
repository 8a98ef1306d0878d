"""Archives: a root folder of acquisition folders, each with its store beside it.

```
ROOT/
  painting-01/            acquisition folder (acquisition.json, video, poses.csv)
  painting-01.zarr        its store (ingest + reconstruct), written by reprocessing
  .ltm-archive.json       the last run of each acquisition: status, reason, seconds
```

:func:`archive_status` classifies each acquisition as ``new`` (no store), ``stale`` (its store's
provenance differs from the running software version, the requested parameters or the input
files' sha256), ``failed`` (its last run failed, or its store is incomplete: the reason says
which) or ``up to date``. :func:`reprocess` rebuilds one acquisition into a side store
(``.NAME.zarr.next``) and swaps it into place only when complete, so a failure (a bad file, a
full disk, a killed process) never touches the previous good store; an interrupted side store of
the same inputs and software is resumed (only its missing pixel tiles are solved).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ltmstore.capture.acquisition import load_acquisition
from ltmstore.core.errors import LtmError
from ltmstore.core.lock import locked
from ltmstore.core.provenance import software
from ltmstore.solve import DEFAULT_METHOD

STORE_SUFFIX = ".zarr"
NEXT_SUFFIX = ".next"
STATE_FILE = ".ltm-archive.json"
LOCK_FILE = ".ltm-archive.lock"
STATUSES = ("new", "stale", "failed", "up to date")


@dataclass(frozen=True)
class ArchiveParams:
    """The reconstruction parameters an archive is kept up to date with.

    Attributes
    ----------
    lattice : tuple of int, optional
        ``(R, S)`` cells (default: the automatic lattice, or ``delta_rs``).
    delta_rs : float, optional
        Cell size in plane units.
    method : str
        Solver name (:data:`ltmstore.solve.METHODS`, or ``auto``, the default of
        ``ltm reconstruct``).
    auto : bool
        Choose the regularisation per tile by held-out error.
    tile : int
        Pixel tile side.
    """

    lattice: tuple[int, int] | None = None
    delta_rs: float | None = None
    method: str = DEFAULT_METHOD
    auto: bool = True
    tile: int = 32

    def options(self) -> dict:
        """Keyword arguments of :func:`ltmstore.stages.reconstruct.reconstruct`."""
        return {"lattice": self.lattice, "delta_rs": self.delta_rs, "method": self.method,
                "auto": self.auto, "tile": self.tile}

    def key(self, color: bool) -> dict:
        """The run key a store made with these parameters records (see ``run_key``)."""
        from ltmstore.stages.reconstruct import run_key

        return run_key(params={}, color=color, **self.options())


@dataclass
class Entry:
    """One acquisition of an archive and its state.

    Attributes
    ----------
    name : str
        The acquisition folder's name.
    folder, store : Path
        The acquisition folder and its store beside it.
    status : str
        One of :data:`STATUSES`.
    reason : str
        Why it is stale or failed (empty otherwise).
    acquisition_bytes, store_bytes : int
        Sizes on disk (0 when absent).
    timings : dict
        Seconds per stage of the store's last run.
    summary : dict
        K/M and held-out error of the store (when it has an ltm).
    """

    name: str
    folder: Path
    store: Path
    status: str
    reason: str = ""
    acquisition_bytes: int = 0
    store_bytes: int = 0
    timings: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {**asdict(self), "folder": str(self.folder), "store": str(self.store)}


def _root(root: str | os.PathLike) -> Path:
    path = Path(root)
    if not path.is_dir():
        raise LtmError(f"archive root {str(path)!r} does not exist or is not a folder")
    return path.resolve()


def folder_bytes(path: Path) -> int:
    """Bytes of the regular files under ``path`` (symlinks not followed)."""
    if path.is_file():
        return path.stat().st_size
    total = 0
    for base, _, files in os.walk(path):
        for name in files:
            try:
                st = os.lstat(os.path.join(base, name))
            except OSError:
                continue
            total += st.st_size
    return total


def read_state(root: Path) -> dict:
    """The archive's record of last runs (empty when none or unreadable)."""
    try:
        state = json.loads((root / STATE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return state if isinstance(state, dict) else {}


def record_runs(root: str | os.PathLike, rows: list[dict]) -> None:
    """Merge the rows of a run into the archive's state file (replaced atomically)."""
    root = _root(root)
    state = read_state(root)
    for row in rows:
        state[row["acquisition"]] = row
    tmp = root / f".{STATE_FILE}.{os.getpid()}"
    try:
        tmp.write_text(json.dumps(state, indent=1, default=str), encoding="utf-8")
        tmp.replace(root / STATE_FILE)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise LtmError(f"cannot write {str(root / STATE_FILE)!r}: {exc.strerror or exc}") from exc


def find_acquisitions(root: str | os.PathLike) -> list[tuple[str, Path, str]]:
    """Every acquisition folder directly under ``root``: ``(name, folder, problem)``.

    A folder is an acquisition when it holds ``acquisition.json``. ``problem`` is empty, or
    says why the folder may not be processed (it or its store leaves the archive root through a
    symlink).
    """
    root = _root(root)
    found = []
    for child in sorted(root.iterdir()):
        if child.name.startswith(".") or child.name.endswith(STORE_SUFFIX):
            continue
        if not (child.is_dir() and (child / "acquisition.json").exists()):
            continue
        problem = ""
        store = child.with_name(child.name + STORE_SUFFIX)
        for what, path in (("acquisition folder", child), ("store", store)):
            if not path.resolve().is_relative_to(root):
                problem = (f"{what} {str(path)!r} leaves the archive root {str(root)!r} "
                           f"(resolves to {str(path.resolve())!r}); expected a folder inside it")
        found.append((child.name, child, problem))
    return found


def input_hashes(folder: Path) -> dict:
    """sha256 of the acquisition's video and poses (validated through its acquisition.json)."""
    return load_acquisition(folder).sha256()


def archive_lock(root: str | os.PathLike):
    """The archive's write lock (:func:`ltmstore.core.lock.locked`): one run per root."""
    root = _root(root)
    return locked(root, what="archive", file=root / LOCK_FILE)


def _store_state(store: Path, params: ArchiveParams, hashes: dict | None) -> tuple[str, str]:
    """``(status, reason)`` of an existing store against the current software and params."""
    from ltmstore.core.store import store_summary

    try:
        prov = store_summary(store)
    except LtmError as exc:
        return "failed", str(exc)
    if prov.get("damaged"):
        return "failed", f"store {str(store)!r} is damaged: {'; '.join(prov['damaged'][:3])}"
    if not prov["complete"]:
        stages = [n for n, e in prov["stages"].items() if not e.get("complete")]
        return "failed", (f"store {str(store)!r} is incomplete (stage(s) {stages} did not "
                          "finish: interrupted run?)")
    version = f"ltmstore {software()['version']}"
    made_by = (prov["software"] or {}).get("version")
    if made_by != version:
        return "stale", f"made by {made_by!r}; running {version!r}"
    run = prov["parameters"].get("run") or {}
    wanted = params.key(bool(run.get("color")))
    if run != wanted:
        diff = sorted(k for k in set(run) | set(wanted) if run.get(k) != wanted.get(k))
        return "stale", "parameters differ: " + ", ".join(
            f"{k} {run.get(k)!r} -> {wanted.get(k)!r}" for k in diff)
    stored = prov["inputs"].get("sha256") or {}
    if hashes is not None and stored != hashes:
        changed = sorted(k for k in hashes if stored.get(k) != hashes[k])
        return "stale", f"input file(s) {changed} changed since the store was made"
    return "up to date", ""


def archive_status(root: str | os.PathLike, params: ArchiveParams | None = None) -> list[Entry]:
    """Classify every acquisition of the archive at ``root``.

    Parameters
    ----------
    root : str or PathLike
        The archive root folder.
    params : ArchiveParams, optional
        The requested parameters (default: :class:`ArchiveParams` defaults).

    Returns
    -------
    list of Entry
        One per acquisition folder, sorted by name.
    """
    params = params or ArchiveParams()
    root = _root(root)
    state = read_state(root)
    entries = []
    for name, folder, problem in find_acquisitions(root):
        store = folder.with_name(name + STORE_SUFFIX)
        entry = Entry(name=name, folder=folder, store=store, status="new",
                      acquisition_bytes=0 if problem else folder_bytes(folder))
        last = state.get(name) or {}
        if problem:
            entry.status, entry.reason = "failed", problem
            entries.append(entry)
            continue
        try:
            hashes = input_hashes(folder)
        except LtmError as exc:
            hashes, entry.status, entry.reason = None, "failed", str(exc)
        if store.exists():
            entry.store_bytes = folder_bytes(store)
            if hashes is not None:
                entry.status, entry.reason = _store_state(store, params, hashes)
            _fill_summary(entry)
        if (entry.status != "up to date" and last.get("status") == "failed"
                and entry.status != "failed"):
            entry.status, entry.reason = "failed", last.get("reason", "")
        entries.append(entry)
    return entries


def _fill_summary(entry: Entry) -> None:
    from ltmstore.core.store import store_summary

    try:
        prov = store_summary(entry.store)
    except LtmError:
        return
    entry.timings = prov["timings"]
    rec = ((prov.get("stages") or {}).get("reconstruct") or {})
    entry.summary = {"sampling_ratio": prov["sampling"].get("sampling_ratio"),
                     "finished": rec.get("finished")}


def reprocess(folder: str | os.PathLike, store: str | os.PathLike, params: ArchiveParams, *,
              scheduler: str | None = None, progress: bool = False) -> dict:
    """Ingest and reconstruct ``folder`` into a side store, then swap it in for ``store``.

    The previous ``store`` stays untouched until the new one is complete. A side store left by
    an interrupted run of the same inputs and software is resumed.

    Returns
    -------
    dict
        ``seconds``, ``sampling_ratio``, ``heldout_error``, ``tiles_solved``,
        ``tiles_resumed``, ``resumed_ingest``.
    """
    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct

    start = time.perf_counter()
    folder, store = Path(folder), Path(store)
    work = store.with_name(f".{store.name}{NEXT_SUFFIX}")
    hashes = input_hashes(folder)
    reuse = work.exists() and _ingest_reusable(work, hashes)
    if not reuse:
        ingest(folder, work, overwrite=True, progress=progress, hashes=hashes)
    info = reconstruct(work, scheduler=scheduler, overwrite=True, progress=progress,
                       **params.options())
    _swap(work, store)
    return {"seconds": round(time.perf_counter() - start, 3),
            "sampling_ratio": info["sampling_ratio"], "heldout_error": info["heldout_error"],
            "tiles_solved": info["tiles_solved"], "tiles_resumed": info["tiles_resumed"],
            "resumed_ingest": reuse}


def _ingest_reusable(work: Path, hashes: dict) -> bool:
    from ltmstore.core.store import open_group, stages

    try:
        group = open_group(work)
        ingest = stages(group).get("ingest") or {}
        attrs = group.attrs.asdict()
    except (LtmError, OSError, ValueError):
        return False
    return (bool(ingest.get("complete"))
            and ingest.get("software") == f"ltmstore {software()['version']}"
            and (attrs.get("acquisition") or {}).get("sha256") == hashes)


def _swap(work: Path, store: Path) -> None:
    """Move the complete side store into place; the old store is removed only afterwards."""
    from ltmstore.core.store import swap_in, writing

    try:
        with writing(store):
            swap_in(work, store)
    except OSError as exc:
        raise LtmError(f"cannot move the new store into {str(store)!r}: "
                       f"{exc.strerror or exc}") from exc


def summary_row(name: str, status: str, *, seconds: float | None = None,
                sampling_ratio: float | None = None, heldout_error: float | None = None,
                reason: str = "") -> dict:
    """One row of a run's summary table (acquisition, status, time, K/M, held-out error)."""
    def rounded(v, n):
        return None if v is None else round(float(v), n)

    return {"acquisition": name, "status": status, "seconds": rounded(seconds, 1),
            "K/M": rounded(sampling_ratio, 3), "heldout_error": rounded(heldout_error, 4),
            "reason": reason,
            "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")}


def format_status(entries: list[Entry]) -> str:
    """A fixed-width table of :func:`archive_status`'s entries."""
    lines = [f"{'acquisition':<24s} {'status':<10s} {'acq MB':>8s} {'store MB':>8s} "
             f"{'K/M':>6s} {'ingest s':>8s} {'solve s':>8s}  reason"]
    for e in entries:
        km = e.summary.get("sampling_ratio")
        lines.append(
            f"{e.name:<24.24s} {e.status:<10s} {e.acquisition_bytes / 1e6:8.1f} "
            f"{e.store_bytes / 1e6:8.1f} {'' if km is None else f'{km:.3f}':>6s} "
            f"{_fmt(e.timings.get('ingest_s')):>8s} {_fmt(e.timings.get('solve_s')):>8s}  "
            f"{e.reason}")
    return "\n".join(lines)


def _fmt(value) -> str:
    return "" if value is None else f"{float(value):.1f}"
