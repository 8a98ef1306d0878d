"""``ltm check``: verify every chunk of a store against its checksum; name what is damaged."""

from __future__ import annotations

import argparse
import sys

from ltmstore.core.errors import LtmError


def register(sub) -> None:
    """Add ``check`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("check", help="verify a store's checksums; name what is damaged",
                       description="Read every chunk of every variable of a store and check "
                       "its CRC32C; print one line per damaged part (exit status 2 if any).")
    p.add_argument("store")
    p.set_defaults(func=cmd_check)


def cmd_check(a: argparse.Namespace) -> None:
    from ltmstore.core.checksum import NO_CHECKSUMS
    from ltmstore.core.store import verify_store

    report = verify_store(a.store)
    if report["unchecked"]:
        print(f"ltm: note: store {a.store!r} {NO_CHECKSUMS}: "
              f"{', '.join(report['unchecked'])}", file=sys.stderr)
    for line in report["damaged"]:
        print(f"ltm: damaged: {a.store}/{line}", file=sys.stderr)
    if report["damaged"]:
        raise LtmError(f"store {a.store!r} is damaged: {len(report['damaged'])} part(s) above")
    print(f"{a.store}: {report['parts']} parts verified, no damage")


def damaged_read(store: str | None, exc: ValueError) -> str | None:
    """The one-line error for a read that failed its checksum, or None for another error."""
    from ltmstore.core.checksum import is_checksum_error

    if not is_checksum_error(exc):
        return None
    return (f"store {store!r} is damaged: a chunk fails its checksum; run ltm check {store!r} "
            "to name the damaged parts")
