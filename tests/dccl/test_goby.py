"""Goby-compatible frames: DCCL messages back to back, as Goby3's QueueManager packs them."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from bridge.core.events import FrameSent, SendFailed
from bridge.core.loaded import load_mission, parse_mission
from bridge.dccl import load_message
from bridge.errors import DecodeError, FrameError, MissionError
from bridge.report.check import check_mission
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.goby import GobyFrameCodec, decode_repeated, encode_repeated, frame_codec_for
from tests.conftest import on_free_ports, udp_ports
from tests.dccl.test_mission import EXAMPLE, NAV
from tests.harness import Inbox, outside_session, put, running_fleet

AUV = EXAMPLE.parent / "dccl" / "auv.proto"
BATHY = {"depth": [10.0, 11.5, 12.0], "altitude": [3.0, 2.5, 2.0],
         "latitude": [41.5, 41.5001, 41.5002], "longitude": [-70.6, -70.6001, -70.6002]}


def test_frame_is_the_concatenated_dccl_encodings() -> None:
    """encode_repeated: each message's DCCL bytes, nothing between or after them."""
    nav, bathy = load_message(AUV, "NavStatus"), load_message(AUV, "Bathymetry")
    frame = encode_repeated([(nav, NAV), (bathy, BATHY)])
    assert frame == nav.encode(NAV) + bathy.encode(BATHY)
    by_id = {nav.id: nav, bathy.id: bathy}
    assert [(m.name, v) for m, v in decode_repeated(frame, by_id)] == [
        (nav.name, nav.decode(nav.encode(NAV))), (bathy.name, bathy.decode(bathy.encode(BATHY)))]


def test_decode_keeps_what_decoded_before_a_failure() -> None:
    """Goby3's decode_repeated: a bad message after the first ends the list; a bad first one
    (or trailing modem padding of zeros, id 0) raises only if nothing decoded."""
    nav = load_message(AUV, "NavStatus")
    data = nav.encode(NAV)
    assert len(decode_repeated(data + b"\x00\x00\x00", {nav.id: nav})) == 1
    assert len(decode_repeated(data + data[:5], {nav.id: nav})) == 1
    with pytest.raises(DecodeError):
        decode_repeated(b"\x00" + data, {nav.id: nav})


def test_example_mission_uses_goby_frames() -> None:
    loaded = load_mission(EXAMPLE)
    table = loaded.table
    codec = frame_codec_for(table)
    assert isinstance(codec, GobyFrameCodec)
    assert check_mission(loaded).ok
    nav, bathy = table.by_name("nav"), table.by_name("bathymetry")
    assert not bathy.fragmented  # 28 bytes fit a 32-byte frame: no zab overhead
    frame = codec.encode([(nav, nav.pack([NAV])), (bathy, bathy.pack([BATHY]))])
    assert frame == (load_message(AUV, "NavStatus").encode(NAV)
                     + load_message(AUV, "Bathymetry").encode(BATHY))
    decoded = codec.decode(frame)
    assert [e.channel.name for e in decoded.entries] == ["nav", "bathymetry"]
    assert decoded.entries[0].values == [load_message(AUV, "NavStatus").decode(
        load_message(AUV, "NavStatus").encode(NAV))]
    with pytest.raises(FrameError):
        codec.decode(b"\x02\x00")


GOBY_LAB = f"""\
mission: goby_lab
modem: {{backend: udp, frame_bytes: 32}}
mac: {{type: none, min_gap_s: 0.3}}
wire: {{format: goby}}
nodes:
  a: {{address: 1, modem: {{options: {{port: PORT_A}}}}}}
  b: {{address: 2, modem: {{options: {{port: PORT_B}}}}}}
channels:
  - name: nav
    from: a
    to: b
    elements: [{{in: nav, out: a/nav, dccl: "{AUV}:NavStatus"}}]
  - name: cmd
    from: b
    to: a
    elements: [{{in: cmd, out: b/cmd, dccl: "{AUV}:Command"}}]
"""


CMD = f'    elements: [{{in: cmd, out: b/cmd, dccl: "{AUV}:Command"}}]'


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("wire: {format: goby}", "wire: {format: goby, dlbl: true}", "no DLBL delays"),
    (CMD, "    elements: [{in: cmd, out: b/cmd, fields: [{field: v, type: bool}]}]",
     "exactly one element with a dccl message"),
    # a receiver took both as the first: a's value on a second NavStatus channel 'pos' came
    # out at b on a/nav; here b's cmd was dropped at a as a nav value from the wrong sender
    (CMD, CMD.replace("Command", "NavStatus"),
     r"lab.yaml:\d+:\d+: channels\[1\]\.elements\[0\]\.dccl: wire.format goby: channels 'nav' "
     r"and 'cmd' both carry DCCL message zab\.auv\.NavStatus \(id 124\); a Goby frame names "
     r"no channel, so a receiver would take both as 'nav'"),
    # nothing a Goby frame could hold: a heartbeat, an idle master's poll, a ranging round
    ("wire: {format: goby}", "wire: {format: goby}\nlink: {heartbeat_s: 30}",
     r"link\.heartbeat_s: wire.format goby frames cannot be empty"),
    ("mac: {type: none, min_gap_s: 0.3}", "mac: {type: polled, master: a, ipg_s: 5}",
     r"mac\.type: wire.format goby frames cannot be empty: a polled master"),
    ("mac: {type: none, min_gap_s: 0.3}",
     "mac: {type: none, ranging: {requester: a, anchors: [b], interval_s: 30, tmax_s: 2}}",
     r"mac\.ranging: wire.format goby frames cannot be empty"),
], ids=["dlbl", "not-dccl", "one-message-two-channels", "heartbeat", "polled", "ranging"])
def test_goby_missions_refuse_what_goby_frames_cannot_carry(old: str, new: str,
                                                              expected: str) -> None:
    text = GOBY_LAB.replace("PORT_A", "7001").replace("PORT_B", "7002")
    assert old in text
    with pytest.raises(MissionError, match=expected):
        parse_mission(text.replace(old, new), "lab.yaml")


def test_goby_frames_cross_end_to_end(tmp_path: Path) -> None:
    """A plain Zenoh app puts a NavStatus at a; b's app gets it as DCCL decoded it."""
    text = udp_ports(GOBY_LAB)
    loaded = on_free_ports(text, tmp_path / "lab.yaml")
    nav = load_message(AUV, "NavStatus")
    with running_fleet(loaded) as fleet:
        a, b = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = Inbox()
            b.declare_subscriber("a/nav", inbox)
            time.sleep(0.3)
            put(a, "nav", NAV)
            key, value, _ = inbox.get(timeout=5)
            assert key == "a/nav"
            assert value == nav.decode(nav.encode(NAV))
            assert fleet.nodes["b"].stats.received_per_channel["nav"] >= 1
        finally:
            a.close()
            b.close()


@pytest.mark.parametrize(("extra", "expected"), [
    ("queries:\n  - name: info\n    key: '{node}/info'\n    serve: a\n    ask: b\n"
     "    reply: [{field: ok, type: bool}]\n", "query 'info' cannot cross"),
    ("demand: {refresh_s: 30}\n", "cannot say what is wanted"),
])
def test_goby_missions_refuse_zab_s_own_entries(extra: str, expected: str) -> None:
    """A goby mission with a query loaded, then its bridge stopped at the first request
    ('channel ?info is not a DCCL channel', as zab demo --mission goby_dccl.yaml showed)."""
    text = GOBY_LAB.replace("PORT_A", "7001").replace("PORT_B", "7002") + extra
    with pytest.raises(MissionError, match=expected):
        parse_mission(text, "lab.yaml")


@pytest.mark.parametrize("mac", ["tdma", "none"])
def test_an_idle_goby_node_sends_nothing_and_data_still_crosses(
        mac: str, caplog: pytest.LogCaptureFixture) -> None:
    """goby_dccl's nodes built a heartbeat in every idle slot, which Goby frames encode as
    no bytes: the modem refused each ('cannot send an empty frame'), and with mac: none the
    node asked again at once, for ever (zab sim: thousands of warnings a second, then deaf
    to Ctrl-C; here the virtual clock stood still at the first heartbeat)."""
    text = EXAMPLE.read_text()
    if mac == "none":
        text = text.replace("  type: tdma\n", "  type: none\n").replace(
            "  slot_s: 10.0\n  guard_s: 0.5\n  order: [topside, auv1, topside, auv2]\n", "")
    fleet = FastFleet(parse_mission(text, EXAMPLE), seed=2)
    fleet.put("auv1", "nav_status", NAV, at=300.0)
    with caplog.at_level("WARNING"):
        fleet.run_until(600.0)
    events = [o for o in fleet.outputs if isinstance(o.output, FrameSent | SendFailed)]
    assert events and all(isinstance(o.output, FrameSent) for o in events), events[:3]
    assert {o.node for o in events} == {"auv1"}  # the others have had nothing to send
    assert all(o.time >= 300.0 and o.output.channels == ["nav"] and o.output.size > 0
               for o in events if isinstance(o.output, FrameSent))
    got = fleet.published("topside", "auv1/nav_status")
    assert got and got[0][1].value["mode"] == "survey"
    assert not [r for r in caplog.records if r.levelname == "WARNING"]


def test_fields_a_dccl_message_does_not_have_are_counted_as_left_out() -> None:
    """Fields no channel reads were counted for zab's own layouts only: a DCCL channel's
    extra fields vanished at the water unsaid."""
    fleet = FastFleet(load_mission(EXAMPLE), seed=2)
    fleet.put("auv1", "nav_status", {**NAV, "heading_deg": 90.0}, at=1.0)
    fleet.put("auv1", "nav_status", NAV, at=2.0)
    fleet.run_until(3.0)
    assert fleet.cores["auv1"].stats.fields_left_out == {"nav_status": 1}
