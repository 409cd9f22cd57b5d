"""Large byte strings in a node's state (an image channel's pictures) are kept in blob files
of their own: written once, however many saves name them, and removed once no saved state
names them, also past a full disk; a state naming a blob missing or altered is moved aside as
corrupt."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from bridge.runtime.persistence import RETRY_S, Persistence
from bridge.runtime.state_file import BLOB_BYTES, StateFile
from tests.runtime.tmpfs import fill, small_tmpfs

PICTURE = os.urandom(100_000)
OTHER = os.urandom(50_000)


def blobs(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.blob"))


def test_a_picture_is_written_once_however_many_saves_name_it(tmp_path: Path) -> None:
    state_file = StateFile(tmp_path, "m", "rov")
    writes: list[Path] = []
    write = state_file._write

    def counted(path: Path, data: bytes) -> None:
        writes.append(path)
        write(path, data)

    state_file._write = counted  # type: ignore[method-assign]
    for n in range(20):  # (a frame's counters change at every save; the picture does not)
        state_file.save({"counter": n, "images": {"camera": {"last": PICTURE,
                                                             "small": b"s" * 100}}})
    assert len(writes) == 21 and len(blobs(tmp_path)) == 1  # the picture once, the state 20x
    assert state_file.path.stat().st_size < 1000
    state = StateFile(tmp_path, "m", "rov").load()
    assert state == {"counter": 19, "images": {"camera": {"last": PICTURE,
                                                           "small": b"s" * 100}}}


def test_a_picture_no_state_names_is_removed(tmp_path: Path) -> None:
    state_file = StateFile(tmp_path, "m", "rov")
    state_file.save({"last": PICTURE, "latest": OTHER})
    assert len(blobs(tmp_path)) == 2
    state_file.save({"last": OTHER, "latest": None})  # the one waiting went out
    assert len(blobs(tmp_path)) == 1
    state_file.save({"last": None, "latest": bytearray(OTHER), "short": b"x" * (BLOB_BYTES - 1)})
    assert len(blobs(tmp_path)) == 1
    assert StateFile(tmp_path, "m", "rov").load() == {
        "last": None, "latest": OTHER, "short": b"x" * (BLOB_BYTES - 1)}
    state_file.save({"last": None})
    assert blobs(tmp_path) == []


def test_a_blob_left_by_a_crash_is_removed_at_the_next_start(tmp_path: Path) -> None:
    state_file = StateFile(tmp_path, "m", "rov")
    state_file.save({"last": PICTURE})
    stray = tmp_path / f"m.rov.state.{'0' * 64}.blob"  # (a save that never came to name it)
    stray.write_bytes(b"half a picture")
    assert StateFile(tmp_path, "m", "rov").load() == {"last": PICTURE}
    assert len(blobs(tmp_path)) == 1 and not stray.exists()


@pytest.mark.parametrize("damage", ["missing", "altered"])
def test_a_state_whose_picture_is_missing_or_altered_starts_afresh(
        tmp_path: Path, damage: str, caplog: pytest.LogCaptureFixture) -> None:
    StateFile(tmp_path, "m", "rov").save({"epoch": 3, "last": PICTURE})
    [blob] = blobs(tmp_path)
    if damage == "missing":
        blob.unlink()
    else:
        blob.write_bytes(PICTURE[:-1] + bytes([PICTURE[-1] ^ 0xFF]))  # (b"?" could be it)
    with caplog.at_level(logging.WARNING, logger="zab.state"):
        assert StateFile(tmp_path, "m", "rov").load() is None
    assert f"its blob {blob.name.split('.')[-2]}" in caplog.text
    assert "starting afresh" in caplog.text
    assert (tmp_path / "m.rov.state.corrupt").exists()


def test_a_state_file_msgpack_cannot_read_says_why(tmp_path: Path,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    StateFile(tmp_path, "m", "rov").save({"epoch": 3})
    (tmp_path / "m.rov.state").write_bytes(b"\x81\xa5epoch\xc1")
    with caplog.at_level(logging.WARNING, logger="zab.state"):
        assert StateFile(tmp_path, "m", "rov").load() is None
    assert "is corrupt (reserved byte 0xc1 at offset 7): moved to" in caplog.text


def test_a_picture_that_comes_while_the_disk_is_full_is_saved_once_it_has_room(
        tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "state", size="512k") as where:
        saves = Persistence(StateFile(where, "m", "rov"), "rov")
        assert saves.save(lambda: {"epoch": 1}, 0.0, first=True)
        filler = fill(where)
        state = {"epoch": 1, "last": PICTURE}
        assert saves.save(lambda: state, 1.0) is False
        assert sorted(where.iterdir()) == sorted([filler, saves.state_file.path])  # nothing half
        filler.unlink()
        assert saves.save(lambda: state, 1.0 + RETRY_S) is True
        assert StateFile(where, "m", "rov").load() == state
        assert len(blobs(where)) == 1
