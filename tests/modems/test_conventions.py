"""Address conventions and per-rate frames, as ``zab check`` and a mixed fleet see them."""

from __future__ import annotations

import queue
import time
from typing import Any

import pytest
import yaml

from bridge.core.events import FrameReceived
from bridge.core.loaded import parse_mission
from bridge.mission.presets import MICROMODEM_PSK, get_preset
from bridge.modems.micromodem.rates import RATES
from bridge.report.check import check_mission
from tests.conftest import on_free_ports
from tests.harness import Inbox, outside_session, put, running_fleet

MICROMODEM = """
mission: conventions
wire: {auth: "off"}
modem:
  backend: micromodem
  frame_bytes: 32
  options: {device: /dev/null, rate: 1, preset: micromodem-rate1}
nodes:
  top: {address: 1}
  auv: {address: 2}
channels:
  - {name: c, from: top, to: auv, elements: [{in: c, out: c, fields: [{field: v, type: bool}]}]}
"""


def check(change: dict[str, Any] | None = None, **nodes: dict[str, Any]) -> Any:
    data = yaml.safe_load(MICROMODEM)
    data["modem"]["options"].update(change or {})
    for name, node in nodes.items():
        data["nodes"][name].update(node)
    return check_mission(parse_mission(yaml.safe_dump(data), "conventions.yaml"))


def test_presets_carry_a_whole_packet_of_their_rate() -> None:
    for rate, (packet, bps) in MICROMODEM_PSK.items():
        preset = get_preset(f"micromodem-rate{rate}")
        assert (preset.frame_bytes, preset.bitrate_bps) == (RATES[rate].max_bytes, bps)
        assert packet == RATES[rate].max_bytes
        assert RATES[rate].bitrate_bps == bps == preset.bitrate_bps
    assert get_preset("micromodem-rate0").frame_bytes == RATES[0].max_bytes


def test_check_warns_when_the_waters_preset_does_not_fit_the_rate() -> None:
    assert check().ok and not [w for w in check().warnings if "preset" in w]
    small = check({"rate": 3, "preset": "micromodem-rate1"})
    assert [w for w in small.warnings if "top: rate 3 sends packets of up to 512 B, the "
            "water's preset micromodem-rate1 carries 192 B" in w]
    other = check({"rate": 2, "preset": "micromodem-rate5"})
    assert [w for w in other.warnings if "times packets at another rate than rate 2" in w]


def test_check_refuses_the_broadcast_address_as_a_node_address() -> None:
    """Goby's BROADCAST_ID 0 is the micromodem default: a node at 0 is an error; a mission
    that says another broadcast address frees 0."""
    report = check(top={"address": 0})
    assert not report.ok
    assert "top: address 0 is the micromodem broadcast address" in report.errors[0]
    data = yaml.safe_load(MICROMODEM)
    data["modem"]["broadcast"] = 127
    data["nodes"]["top"]["address"] = 0
    assert check_mission(parse_mission(yaml.safe_dump(data), "c.yaml")).ok


def test_check_warns_when_nodes_disagree_on_broadcast() -> None:
    report = check(auv={"modem": {"broadcast": 127}})
    assert [w for w in report.warnings if w.startswith("nodes disagree on the broadcast ")
            and "top: 0" in w and "auv: 127" in w]


FLEET = """
mission: mixed
wire: {auth: "off"}
modem: {backend: sim, frame_bytes: 32, options: {preset: evologics-s2c-im}}
mac: {type: none}
link: {heartbeat_s: 3600}
nodes:
  goby: {address: 1, modem: {broadcast: 0}}
  zab1: {address: 2}
  zab2: {address: 3}
channels:
  - name: hello
    from: ".*"
    to: ".*"
    elements: [{in: hello, out: "{src}/hello", fields: [{field: n, type: int, min: 0, max: 9}]}]
"""


@pytest.mark.parametrize("agreed", [True, False])
def test_mixed_fleet_broadcasts_arrive_at_all(agreed: bool) -> None:
    """``zab sim``'s fleet, one node with Goby's convention (broadcast 0, addresses from 1).
    With the mission agreeing (``modem.broadcast: 0``), every node's broadcast reaches every
    other as a broadcast; when only the Goby node says 0, its frames still reach the others
    (every modem hears everything) but as frames to address 0: what ``zab check`` warns of."""
    data = yaml.safe_load(FLEET)
    if agreed:
        data["modem"]["broadcast"] = 0
    loaded = on_free_ports(yaml.safe_dump(data), "mixed.yaml")
    warned = [w for w in check_mission(loaded).warnings if "disagree" in w]
    assert bool(warned) is not agreed
    heard: queue.Queue[tuple[str, FrameReceived]] = queue.Queue()

    def on_event(node: str, event: Any) -> None:
        if isinstance(event, FrameReceived):
            heard.put((node, event))

    names = list(loaded.mission.nodes)
    with running_fleet(loaded, on_event=on_event):
        sessions = {n: outside_session(loaded, n) for n in names}
        try:
            inboxes = {n: Inbox() for n in names}
            for n, session in sessions.items():
                session.declare_subscriber("*/hello", inboxes[n])
            time.sleep(0.3)
            for i, n in enumerate(names):  # one at a time (mac none: together they collide)
                put(sessions[n], "hello", {"n": i})
                for receiver in names:
                    if receiver != n:  # every other node hears the value
                        assert inboxes[receiver].get(10)[:2] == (f"{n}/hello", {"n": i})
        finally:
            for session in sessions.values():
                session.close()
    dests: dict[tuple[str, str], Any] = {}
    while not heard.empty():
        node, event = heard.get()
        dests[(event.src, node)] = event.meta.get("dest")
    assert len(dests) == 6
    for (src, node), dest in dests.items():
        misrouted = not agreed and src == "goby"  # 0 means nothing special to the others
        assert dest == (0 if misrouted else None), (src, node)
