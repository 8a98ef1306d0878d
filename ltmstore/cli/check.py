"""``ltm check``: verify every chunk of a store against its checksum; name what is damaged."""

from __future__ import annotations

import argparse
import sys

from ltmstore.core.errors import LtmError

BUSY = 75  # exit status of a store being written (sysexits' EX_TEMPFAIL: try again later)


def register(sub) -> None:
    """Add ``check`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("check", help="verify a store's checksums; name what is damaged",
                       description="Read every chunk of every variable of a store and check "
                       "its CRC32C; print one line per damaged part (exit status 2 if any). The "
                       "store is checked at rest: no writer can start meanwhile, and a store "
                       f"being written is not checked (one line, exit status {BUSY}: try again "
                       "when the writer finishes).")
    p.add_argument("store", help="store to verify")
    p.set_defaults(func=cmd_check)


def cmd_check(a: argparse.Namespace) -> None:
    from ltmstore.core.lock import LockHeld, reading

    try:
        _recover(a.store)
        with reading(a.store):  # shared: no writer starts until the check is done
            report = _verify(a.store)
    except LockHeld as exc:  # chunks read mid-write would look damaged: nothing is checked
        print(f"ltm: busy: store {a.store!r} is being written by {exc.owner}; try again when "
              "it finishes (not checked)", file=sys.stderr)
        raise SystemExit(BUSY) from None
    _report(a.store, report)


def _recover(store: str) -> None:
    """Finish (or roll back) a swap a killed writer left, as every reader does, before taking
    the shared lock (recovering takes the write lock, which the check's own would refuse)."""
    import os
    from pathlib import Path

    from ltmstore.core.store import writing
    from ltmstore.core.swap import journal_path

    if journal_path(Path(os.path.realpath(store))).exists():
        with writing(store):
            pass


def _verify(store: str) -> dict:
    from ltmstore.core.store import open_group, refinement_pending, verify_store

    report = verify_store(store)  # a damaged store is reported as such, nothing more
    report["refinement_pending"] = (not report["damaged"]
                                    and refinement_pending(dict(open_group(store).attrs)))
    return report


def _report(store: str, report: dict) -> None:
    from ltmstore.core.checksum import NO_CHECKSUMS

    if report["unchecked"]:
        print(f"ltm: note: store {store!r} {NO_CHECKSUMS}: "
              f"{', '.join(report['unchecked'])}", file=sys.stderr)
    if report.get("unverified"):
        from ltmstore.core.integrity import NOT_RECORDED

        print(f"ltm: note: store {store!r} {NOT_RECORDED}: "
              f"{', '.join(report['unverified'])}", file=sys.stderr)
    for line in report["damaged"]:
        print(f"ltm: damaged: {store}/{line}", file=sys.stderr)
    if report["damaged"]:
        raise LtmError(f"store {store!r} is damaged: {len(report['damaged'])} part(s) above")
    print(f"{store}: {report['parts']} parts verified, no damage")
    if report.get("refinement_pending"):
        from ltmstore.core.store import refinement_note

        print(refinement_note(store), file=sys.stderr)


def damaged_read(store: str | None, exc: ValueError) -> str | None:
    """The one-line error for a read that failed its checksum, or None for another error."""
    from ltmstore.core.checksum import is_checksum_error

    if not is_checksum_error(exc):
        return None
    return (f"store {store!r} is damaged: a chunk fails its checksum; run ltm check {store!r} "
            "to name the damaged parts")
