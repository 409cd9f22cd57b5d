"""Saving state when the disk cannot take it: a full or read-only state directory (a real
tmpfs) is reported once, retried, and recovered from by itself; at start it is one line."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from bridge.runtime.persistence import RETRY_S, Persistence
from bridge.runtime.state_file import StateError, StateFile
from tests.runtime.tmpfs import fill, remount, small_tmpfs

STATE = {"version": 1, "epoch": 7, "blob": b"x" * 200}


def test_a_full_then_freed_disk_fails_saves_then_recovers(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, "zab.state")
    with small_tmpfs(tmp_path / "state") as where:
        saves = Persistence(StateFile(where, "m", "a"), "a")
        assert saves.save(lambda: STATE, 0.0, first=True)
        filler = fill(where)
        assert saves.save(lambda: STATE, 1.0) is False
        assert saves.error is not None and "ENOSPC" in saves.error
        assert saves.save(lambda: STATE, 1.0 + RETRY_S / 2) is None  # not tried again yet
        assert saves.save(lambda: STATE, 1.0 + RETRY_S) is False
        assert saves.failed == 2
        assert list(where.iterdir()) == [filler, saves.state_file.path]  # no temporary left
        filler.unlink()
        assert saves.save(lambda: STATE, 2.0 + RETRY_S) is True
        assert saves.error is None
        assert StateFile(where, "m", "a").load() == STATE
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2  # one when it fails, one when it works again
    assert "cannot save its state" in lines[0] and "No space left on device" in lines[0]
    assert "saved again" in lines[1] and "2 saves had failed" in lines[1]


def test_a_read_only_disk_fails_saves_until_it_is_writable_again(tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "state") as where:
        saves = Persistence(StateFile(where, "m", "a"), "a")
        assert saves.save(lambda: STATE, 0.0, first=True)
        remount(where, "ro")
        assert saves.save(lambda: STATE, 1.0) is False
        assert saves.error is not None and "EROFS" in saves.error
        remount(where, "rw")
        assert saves.save(lambda: STATE, 1.0 + RETRY_S) is True


def test_a_full_disk_at_start_is_a_state_error_in_one_line(tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "state") as where:
        fill(where)
        saves = Persistence(StateFile(where, "m", "a"), "a")
        with pytest.raises(StateError) as info:
            saves.save(lambda: STATE, 0.0, first=True)
    assert str(info.value) == (f"a: cannot save its state in {where}: No space left on device "
                               "(ENOSPC)")


def test_one_holder_of_a_node_s_state_at_a_time_until_it_lets_go(tmp_path: Path) -> None:
    first, second = StateFile(tmp_path, "m", "a"), StateFile(tmp_path, "m", "a")
    first.hold()
    with pytest.raises(StateError, match=r"another bridge holds this node's state .*"
                       r"locked by process \d+"):
        second.hold()
    other = StateFile(tmp_path, "m", "b")
    other.hold()  # another node's state: its own lock
    other.release()
    first.release()
    second.hold()  # let go: the next bridge takes it
    second.release()
    assert (tmp_path / "m.a.state.lock").exists()
