"""``ltm check`` and a writer of the same store: the check reads the store at rest or not at all
(a chunk read mid-write looked damaged)."""

from __future__ import annotations

import json
import os
import socket

import pytest

from ltmstore.cli import main
from ltmstore.cli.check import BUSY
from ltmstore.core.errors import LtmError
from ltmstore.core.lock import lock_path, reading
from ltmstore.core.store import writing


def test_check_of_a_store_being_written_says_so_and_reports_no_damage(far_store, capsys):
    with writing(far_store):  # as ltm reconstruct holds an existing store
        with pytest.raises(SystemExit) as exit_:
            main(["check", str(far_store)])
    assert exit_.value.code == BUSY != 2  # 2: damage
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        f"ltm: busy: store {str(far_store)!r} is being written by process {os.getpid()} on host "
        f"{socket.gethostname()}; try again when it finishes (not checked)"]
    assert "damage" not in err

    assert main(["check", str(far_store)]) == 0  # the writer is done: checked
    assert "no damage" in capsys.readouterr().out
    assert not lock_path(far_store).exists()


def test_no_writer_starts_while_the_store_is_checked(far_store):
    with reading(far_store), reading(far_store):  # readers together
        with pytest.raises(LtmError, match="is in use by another process .*ltm check"):
            with writing(far_store):
                pass
    with writing(far_store):  # the last reader out left no lock behind
        pass
    assert not lock_path(far_store).exists()


def test_a_dead_writers_lock_file_does_not_stop_the_check(far_store, capsys):
    """The kernel released a killed writer's lock; its file still names it."""
    lock_path(far_store).write_text(json.dumps({"pid": 999999999, "host": "gone"}))
    assert main(["check", str(far_store)]) == 0
    assert "no damage" in capsys.readouterr().out
    assert not lock_path(far_store).exists()


def test_a_read_only_folder_is_checked_without_a_lock(far_store, tmp_path, capsys):
    """No lock file can be made there (nor by any writer): the check runs unlocked."""
    if os.geteuid() == 0:
        pytest.skip("root writes into a read-only folder")
    folder = far_store.parent
    folder.chmod(0o555)
    try:
        assert main(["check", str(far_store)]) == 0
    finally:
        folder.chmod(0o755)
    assert "no damage" in capsys.readouterr().out
