"""A mission log cut short: a node killed with ``kill -9`` left an empty file (nothing was
flushed while it ran), and ``zab log`` could not read a file without its footer at all."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from typer.testing import CliRunner

from bridge.cli.app import app as zab
from bridge.core.events import FrameReceived, FrameSent
from bridge.core.loaded import parse_mission
from bridge.runtime.logbook import LogError, MissionLog, read_log, summarise
from tests.conftest import REPO
from tests.runtime.test_logbook import SIM
from tests.zsim import Inbox, app, mission_file, zab_sim

INDEPENDENT = True  # the kill test runs a `zab sim` of its own

MISSION = SIM.replace("mission: simlog", "mission: cutlog")  # (a log of its own name)
GROUPS = 6


def _written(path: Path) -> tuple[list[int], list[int]]:
    """A log of ``GROUPS`` groups of three records, flushed after each: the file's size after
    each flush (the first: before any record) and how many records were whole by then."""
    log = MissionLog(path, parse_mission(MISSION), "b", flush_s=None)
    sizes, whole = [path.stat().st_size], [0]  # (the mission: on disk at once)
    for i in range(GROUPS):
        t = 1000.0 + i
        log(FrameSent(time=t, size=3, channels=[], dest=None, data=bytes([i, 1, 2])))
        log(FrameReceived(time=t + 0.5, src="a", size=4, channels=["ping"], data=bytes(4),
                          meta={"snr": i}, values={"ping": [{"n": i}]}))  # (and channel/ping)
        log.flush()
        sizes.append(path.stat().st_size)
        whole.append(3 * (i + 1))
    log.close()
    return sizes, whole


def _chunk_ends(path: Path) -> list[int]:
    """Where each chunk of a whole MCAP file ends (a flush writes its message indexes after)."""
    ends = []
    with path.open("rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                ends.append(stream.tell())
    return ends


def _cuts(sizes: list[int], end: int) -> list[int]:
    """Byte offsets to cut at: in the header, at each flush's end and one byte either side,
    half way between two, at the end of a flush's message indexes, and inside the summary
    that ``close`` wrote."""
    cuts = {4, 8, 9, 30, sizes[0] // 2, end - 1, (sizes[-1] + end) // 2, sizes[-1] + 1}
    for a, b in itertools.pairwise(sizes):
        cuts |= {a - 1, a, a + 1, (a + b) // 2, b - 2}  # (b - 2: in the message indexes)
    return sorted(c for c in cuts if 0 <= c < end)


def test_a_log_cut_anywhere_gives_its_whole_records_and_says_it_was_cut(tmp_path: Path) -> None:
    """Cut at ~40 offsets (mid-record, between records, in the header and the summary):
    ``read_log`` never raises anything but :class:`LogError`, and returns exactly the records
    whole before the cut, with a one-line note."""
    path = tmp_path / "full.mcap"
    sizes, whole = _written(path)
    content = path.read_bytes()
    full = read_log(path)
    assert full.complete and len(full.records) == whole[-1]
    assert [r.kind for r in full.records[:3]] == ["frame_sent", "frame_received", "channel"]
    chunk_ends = _chunk_ends(path)  # (a group's records are whole once its chunk is)
    assert len(chunk_ends) == GROUPS and all(a < end < b for a, end, b in
                                             zip(sizes, chunk_ends, sizes[1:], strict=False))
    cut = tmp_path / "cut.mcap"
    for offset in _cuts(sizes, len(content)):
        cut.write_bytes(content[:offset])
        try:
            log = read_log(cut)
        except LogError as exc:  # cut before the 'zab' metadata
            assert offset < sizes[0], (offset, exc)
            assert str(exc).count("\n") == 0 and ("cut short" in str(exc)
                                                 or "not a readable MCAP" in str(exc)), exc
            continue
        expected = full.records[:3 * sum(end <= offset for end in chunk_ends)]
        assert log.records == expected, offset
        if offset > len(content) - 8:  # the footer whole, only the closing magic cut
            assert log.complete
            continue
        assert log.node == "b" and not log.complete and log.note is not None
        assert log.note == f"{cut}: the log ends without its footer (its node was stopped " \
            f"abruptly, or still runs): {len(expected)} record{'' if len(expected) == 1 else 's'}"\
            " read", offset
        if offset >= sizes[0]:
            assert log.loaded is not None and log.loaded.mission.mission == "cutlog"


def test_a_log_damaged_inside_gives_the_records_before_the_damage(tmp_path: Path) -> None:
    path = tmp_path / "damaged.mcap"
    sizes, whole = _written(path)
    full = read_log(path)
    content = bytearray(path.read_bytes())
    middle = (sizes[3] + sizes[4]) // 2  # inside the fourth group's chunk
    content[middle] ^= 0xFF
    path.write_bytes(bytes(content))
    log = read_log(path)
    assert log.records == full.records[:whole[3]]
    assert log.note is not None and f"damaged at byte {sizes[3]} of {len(content)}" in log.note
    assert log.note.endswith(f"{whole[3]} records read before it")


def test_zab_log_reads_a_cut_log_and_says_so_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    sizes, whole = _written(path)
    path.write_bytes(path.read_bytes()[:sizes[2] + 7])
    result = CliRunner().invoke(zab, ["log", "summary", "--json", str(path)])
    assert result.exit_code == 0, result.output
    note = f"the log ends without its footer (its node was stopped abruptly, or still runs): " \
        f"{whole[2]} records read"
    assert note in result.output.replace("\n", "")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    result = CliRunner().invoke(zab, ["log", "summary", str(empty)])
    assert result.exit_code == 2 and "an empty file" in result.output


def test_a_zab_sim_killed_outright_leaves_a_log_that_zab_log_reads(tmp_path: Path) -> None:
    """A real ``zab sim --log``, a value put by a plain Zenoh app, ``kill -9``: each node's
    log was 0 bytes and ``zab log summary`` said 'not a readable MCAP file'. Now it holds
    what was recorded until about a second before the kill."""
    mission, endpoints = mission_file(MISSION, tmp_path)
    with zab_sim(mission, endpoints, "--log", str(tmp_path / "logs")) as proc:
        a, b = app(endpoints["a"]), app(endpoints["b"])
        try:
            inbox = Inbox()
            b.declare_subscriber("a/ping", inbox)
            time.sleep(0.5)
            a.put("ping", b"\x81\xa1n\x07")  # msgpack {"n": 7}
            assert inbox.drain(10)[:1] == [("a/ping", {"n": 7})], "ping never crossed"
            time.sleep(2.5)  # a few more TDMA cycles, and flushes
        finally:
            a.close()
            b.close()
        killed = time.time()
        proc.kill()  # SIGKILL: no close, no footer
        proc.wait()
    for node in ("a", "b"):
        log = tmp_path / "logs" / f"cutlog-{node}.mcap"
        result = subprocess.run([sys.executable, "-m", "bridge", "log", "summary", "--json",
                                 str(log)], capture_output=True, text=True, timeout=60, cwd=REPO)
        assert result.returncode == 0, result.stderr
        assert "the log ends without its footer" in result.stderr
        data = json.loads(result.stdout)
        assert data["node"] == node and data["events"]["frame_sent"] >= 2
        # frames every TDMA cycle (1 s) and a flush every second: a 3 s margin for a busy host
        assert killed - data["end"] < 3.0, (killed, data["end"])
    b_log = summarise(read_log(tmp_path / "logs" / "cutlog-b.mcap"))
    assert b_log["channels"]["ping"]["received"] >= 1


@pytest.mark.parametrize("flush_s", [None, 0.05])
def test_a_closed_log_is_complete_with_or_without_its_flusher(tmp_path: Path,
                                                              flush_s: float | None) -> None:
    log = MissionLog(tmp_path / "x.mcap", parse_mission(MISSION), "a", flush_s=flush_s)
    for i in range(3):
        log(FrameSent(time=1.0 + i, size=1, channels=[], dest=None, data=b"\x00"))
        time.sleep(0.1)
    log.close()
    log.close()
    got = read_log(tmp_path / "x.mcap")
    assert got.complete and [r.time for r in got.records] == [1.0, 2.0, 3.0]
