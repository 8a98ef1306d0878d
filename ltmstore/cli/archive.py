"""``ltm archive``: status, run and scheduled reprocessing of a folder of acquisitions."""

from __future__ import annotations

import argparse

from ltmstore.cli.args import number, print_json
from ltmstore.cli.names import DEFAULT_METHOD, METHOD_NAMES
from ltmstore.core.errors import LtmError


def register(sub) -> None:
    """Add ``ltm archive`` and its verbs to the ``ltm`` subparsers ``sub``."""
    from ltmstore.cli import Parser

    archive = sub.add_parser("archive", help="status, run and scheduled reprocessing of an archive",
                             description="An archive is a ROOT folder of acquisition folders, "
                             "each with its store NAME.zarr beside it (docs/archives.md).")
    verbs = archive.add_subparsers(dest="verb", required=True, metavar="VERB",
                                   parser_class=Parser)

    def common(p) -> None:
        p.add_argument("root", help="archive root folder")
        grid = p.add_mutually_exclusive_group()
        grid.add_argument("--lattice", help="RxS cells over the plane (default: automatic)")
        grid.add_argument("--delta-rs", type=number, help="cell size in plane units")
        p.add_argument("--method", default=DEFAULT_METHOD, choices=["auto", *METHOD_NAMES],
                       help="solver, as ltm reconstruct --method (default: %(default)s)")
        p.add_argument("--no-auto", action="store_true", help="fixed default regularisation")
        p.add_argument("--tile", type=int, default=32, help="pixel tile side (default: 32)")

    def running(p) -> None:
        p.add_argument("--max-concurrent", type=int, default=2,
                       help="acquisitions processed at once (default: %(default)s)")
        p.add_argument("--scheduler", help="Dask scheduler address (default: a local cluster)")

    p = verbs.add_parser("status", help="new / stale / failed / up to date, sizes, timings",
                         description="List every acquisition of the archive: new (no store), "
                         "stale (its inputs, the software or these parameters changed since its "
                         "store was made), failed or up to date, with store sizes and timings. "
                         "Reads only: nothing is processed.")
    common(p)
    p.add_argument("--json", action="store_true", help="JSON instead of a table")
    p.set_defaults(func=cmd_archive_status)

    p = verbs.add_parser("run", help="reprocess new, stale and failed acquisitions once",
                         description="Run the reprocess-archive Prefect flow once (a temporary "
                         "Prefect server starts when PREFECT_API_URL is not set).")
    common(p)
    running(p)
    p.set_defaults(func=cmd_archive_run)

    p = verbs.add_parser("serve", help="serve reprocess-archive on a cron schedule",
                         description="Serve the reprocess-archive flow as a deployment with a "
                         "cron schedule against the Prefect server of PREFECT_API_URL, or one "
                         "started here with `prefect server start` on 127.0.0.1.")
    common(p)
    running(p)
    p.add_argument("--cron", required=True, help='cron schedule, e.g. "0 2 * * *"')
    p.add_argument("--name", default="archive", help="deployment name (default: %(default)s)")
    p.set_defaults(func=cmd_archive_serve)


def _archive_params(a: argparse.Namespace):
    from ltmstore.archive import ArchiveParams
    from ltmstore.core.dims import parse_lattice

    if a.tile < 1:
        raise LtmError(f"--tile {a.tile!r} must be a positive whole number of pixels")
    return ArchiveParams(lattice=parse_lattice(a.lattice) if a.lattice else None,
                         delta_rs=a.delta_rs, method=a.method, auto=not a.no_auto, tile=a.tile)


def _flow_params(a: argparse.Namespace) -> dict:
    """The flow's parameters, every one checked (and the root) before Prefect starts its
    temporary server (20-60 s)."""
    from pathlib import Path

    p = _archive_params(a)
    if not Path(a.root).is_dir():
        raise LtmError(f"archive root {a.root!r} does not exist or is not a folder")
    if a.max_concurrent < 1:
        raise LtmError(f"--max-concurrent {a.max_concurrent!r} must be a whole number from 1")
    return {"lattice": None if p.lattice is None else list(p.lattice), "delta_rs": p.delta_rs,
            "method": p.method, "auto": p.auto, "tile": p.tile,
            "max_concurrent": a.max_concurrent, "scheduler": a.scheduler}


def cmd_archive_status(a: argparse.Namespace) -> None:
    from ltmstore.archive import archive_status, format_status

    entries = archive_status(a.root, _archive_params(a))
    if a.json:
        print_json([e.to_json() for e in entries])
    else:
        print(format_status(entries))


def cmd_archive_run(a: argparse.Namespace) -> None:
    params = _flow_params(a)  # bad options fail before Prefect is imported
    from flows.archive import reprocess_archive

    rows = reprocess_archive(a.root, **params)
    for r in rows:
        km = "" if r["K/M"] is None else f"K/M {r['K/M']:.3f}"
        print(f"{r['acquisition']:<24s} {r['status']:<12s} {km} {r['reason']}".rstrip())
    failed = [r["acquisition"] for r in rows if r["status"] == "failed"]
    if failed:
        raise LtmError(f"{len(failed)} of {len(rows)} acquisition(s) failed: {failed}; "
                       "see ltm archive status")


def cmd_archive_serve(a: argparse.Namespace) -> None:
    params = _flow_params(a)
    check_cron(a.cron)
    from flows.archive import serve_archive

    serve_archive(a.root, cron=a.cron, name=a.name, parameters=params)


def check_cron(cron: str) -> None:
    """Refuse a ``--cron`` that Prefect's schedule does not accept, in one line."""
    from prefect.client.schemas.schedules import CronSchedule

    try:
        CronSchedule(cron=cron)
    except ValueError as exc:  # pydantic's ValidationError: its first error's message
        why = exc.errors()[0]["msg"] if hasattr(exc, "errors") else str(exc)
        raise LtmError(f"--cron {cron!r} is not a cron schedule ({why}); expected five fields, "
                       'e.g. "0 2 * * *"') from None
