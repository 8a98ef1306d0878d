"""Put a complete store in place of another, durably and recoverably.

:func:`swap_in` makes two renames (the old store aside, the new one in place). Before the first it
writes a journal beside the store naming both folders; it removes the journal only when the swap
is done. A process killed between the renames leaves the journal, and the next command that opens
the store (:func:`recover`) finishes the swap, or rolls it back when the new store is gone. Every
file of the new store and the parent folder are flushed to disk (``fsync``) before the journal
goes, so a power cut cannot leave a store that is named but not written.

The journal names the store, the new store and the old one by their names in the store's
folder (:data:`JOURNAL_FORMAT`), never by absolute paths: a folder copied (``cp -a``) or moved
(``mv``) with a journal in it recovers its own stores, never those of the folder it came from.
A journal that does not match its folder (another store's, names that are not entries of the
folder, none of the stores it names there, or an older journal's absolute paths into another
folder) is refused with :class:`SwapJournalError`; nothing is moved or deleted then.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from ltmstore.core.errors import LtmError

FSYNC_THREADS = 8
JOURNAL_FORMAT = "ltm-swap/2"  # names relative to the store's folder
# Tests only: seconds to pause between the two renames (to kill the process there), and before
# the swap begins (the new store complete beside the old one, which is still in place).
PAUSE_ENV = "LTM_TEST_SWAP_PAUSE_S"
PAUSE_BEFORE_ENV = "LTM_TEST_SWAP_PAUSE_BEFORE_S"


class SwapJournalError(LtmError):
    """A swap journal that does not match the folder it lies in: nothing was recovered."""


def journal_path(path: Path) -> Path:
    """The journal of a swap into ``path``."""
    return path.parent / f".{path.name}.swap.json"


def swap_in(side: Path, path: Path) -> None:
    """Move the complete store at ``side`` to ``path``, replacing any store there.

    A store already at ``path`` is moved aside first, put back if the move fails and removed
    only after it succeeded. ``side`` lies in the folder of ``path`` (the journal names both
    by their names there). Raises :class:`OSError` as the file system does.
    """
    side, path = Path(os.path.abspath(side)), Path(os.path.abspath(path))
    if side.parent != path.parent:
        raise ValueError(f"swap_in: {str(side)!r} must lie in the folder of {str(path)!r}")
    old = path.parent / f".{path.name}.old-{os.getpid()}"
    _pause(PAUSE_BEFORE_ENV)
    fsync_tree(side)
    journal = journal_path(path)
    _write_durably(journal, json.dumps({"format": JOURNAL_FORMAT, "store": path.name,
                                        "side": side.name, "old": old.name}))
    if path.exists():
        path.rename(old)
    _pause(PAUSE_ENV)
    try:
        side.rename(path)
    except OSError:
        if old.exists() and not path.exists():
            old.rename(path)
        journal.unlink()
        raise
    fsync_dir(path.parent)
    journal.unlink()
    fsync_dir(path.parent)
    shutil.rmtree(old, ignore_errors=True)


def recover(path: Path) -> str | None:
    """Finish or roll back a swap into ``path`` that a killed process left; clean its leftovers.

    The caller must hold the store's write lock. Returns what was done (``"finished"``,
    ``"rolled back"``) or None when there was nothing to recover.

    Raises
    ------
    SwapJournalError
        When the journal does not match its folder (see the module docstring): one line naming
        the journal; nothing is moved or deleted.
    """
    journal = journal_path(path)
    try:
        record = json.loads(journal.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):  # a journal torn before its first rename
        journal.unlink()
        return "rolled back"
    side, old = _entries(record, journal, path)
    done = "finished"
    if not path.exists():
        if side.exists():
            side.rename(path)
        elif old.exists():
            old.rename(path)
            done = "rolled back"
    fsync_dir(path.parent)
    journal.unlink()
    shutil.rmtree(old, ignore_errors=True)
    return done


def check_journal(path: Path) -> None:
    """Refuse (:class:`SwapJournalError`) a journal beside ``path`` that does not match its
    folder, before the caller takes the store's lock: a refused journal leaves every file as
    it was. Nothing is read but the journal; :func:`recover` checks again under the lock."""
    journal = journal_path(path)
    try:
        record = json.loads(journal.read_text())
    except (OSError, ValueError):  # none, or torn: recover() deals with it
        return
    _entries(record, journal, path)


def _entries(record, journal: Path, path: Path) -> tuple[Path, Path]:
    """The new and the old store a journal names, in the folder of ``path``; refused (nothing
    touched) when the journal does not match that folder."""
    folder = path.parent

    def refuse(why: str) -> SwapJournalError:
        return SwapJournalError(
            f"swap journal {str(journal)!r} {why}; nothing was moved or deleted (finish the "
            "swap in the folder where it began, or check the store and remove the journal)")

    if not isinstance(record, dict) or not all(isinstance(record.get(k), str)
                                               for k in ("side", "old")):
        raise refuse("is not a journal of ltm's swaps (expected the names 'side' and 'old')")
    if record.get("format") == JOURNAL_FORMAT:
        if record.get("store") != path.name:
            raise refuse(f"records a swap into {record.get('store')!r}, not into {path.name!r}")
        names = [record["side"], record["old"]]
        if any(Path(n).name != n or n in ("", ".", "..") for n in names):
            raise refuse(f"names {names} where it must name entries of its folder")
    else:  # written before JOURNAL_FORMAT: absolute paths, valid only in the folder they name
        recorded = {str(Path(record[k]).parent) for k in ("side", "old")}
        if {os.path.realpath(r) for r in recorded} != {os.path.realpath(folder)}:
            raise refuse(f"names stores in {' and '.join(sorted(map(repr, recorded)))}, not "
                         "in its own folder: the folder was copied or moved")
        names = [Path(record[k]).name for k in ("side", "old")]
    if len({path.name, *names}) != 3:
        raise refuse(f"names {names} for the new and the old store of {path.name!r}: three "
                     "different entries expected")
    side, old = folder / names[0], folder / names[1]
    present = [p for p in (path, side, old) if p.exists() or p.is_symlink()]
    if not present:
        raise refuse(f"names {path.name!r}, {names[0]!r} and {names[1]!r}, none of which is "
                     "beside it")
    if any(p.is_symlink() or not p.is_dir() for p in present):
        raise refuse(f"names {', '.join(repr(p.name) for p in present)} beside it, which must "
                     "be store folders")
    return side, old


def fsync_tree(root: Path) -> None:
    """Flush every file and folder under ``root`` to disk (all flushed when it returns).

    The flushes run on a few threads: each waits on the disk, not the CPU, and a store holds
    hundreds of chunk files (one at a time took 0.2-0.6 s for a 0.16 MP capture here).
    """
    paths = [os.path.join(folder, name) for folder, _, files in os.walk(root)
             for name in (*files, ".")]
    with ThreadPoolExecutor(max_workers=FSYNC_THREADS) as pool:
        list(pool.map(_fsync, paths))


def fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (renames, new names) to disk."""
    _fsync(folder)


def _fsync(path: str | Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_durably(file: Path, text: str) -> None:
    tmp = file.with_name(file.name + ".tmp")
    with open(tmp, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    tmp.rename(file)
    fsync_dir(file.parent)


def _pause(variable: str) -> None:
    seconds = float(os.environ.get(variable, "0") or 0)
    if seconds > 0:
        time.sleep(seconds)
