"""Surfacing and the bridge's outputs, proven with the mission key, over real Zenoh sessions
(two bridges as Zenoh routers on loopback, a real UDP link between them):

- a local application declaring the peer's bridge token changes nothing: the peer is not
  treated as surfaced, its values keep crossing acoustically;
- a real surfacing (an access point joining both routers, as ``zab sim``'s surface WiFi) still
  switches both bridges to IP, and the dive switches them back, though the forged token lives on;
- with ``sign_outputs``, every sample a bridge puts carries a signature an application checks
  with the key; a copy of it on a forged payload (a fake delivery report) does not check;
- a get on a peer's keyspace that maps to nothing gets the bridge's reply error only while no
  peer's bridge token is on its Zenoh: with one, proven or not yet, it may be answered there.
  (In ``zab demo`` the surfaced cv2's error came beside ssv's own answer: ssv's get crossed
  the fresh WiFi join before cv2 had proven ssv, then one full suite run in eight.)
- a queryable on a peer's prove key that never ends its replies does not hold the switch: the
  first valid proof settles it, not the end of the challenge's get."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import msgpack
import pytest

from bridge.runtime import ip_watch
from bridge.runtime.ip_watch import PROVE_EVERY_S, PROVE_TIMEOUT_S
from bridge.runtime.surface_wifi import access_point
from bridge.wire.proofs import check_output
from tests.conftest import on_free_ports, udp_ports
from tests.harness import outside_session, running_fleet

KEY = b"a-mission-key-of-32-bytes-000000"
MISSION = """\
mission: proof
wire: {auth: {tag_bytes: 4, sign_outputs: true}}
surfacing: {republish: true}
modem: {backend: udp, frame_bytes: 32}
mac: {type: none, min_gap_s: 0.05}
nodes:
  top: {address: 1, modem: {options: {port: PORT_A}}, zenoh: {mode: router}}
  auv: {address: 2, modem: {options: {port: PORT_B}}, zenoh: {mode: router}}
channels:
  - name: nav
    from: auv
    to: top
    elements: [{in: nav, out: auv/nav, fields: [{field: x, type: int, min: 0, max: 1000}]}]
"""
HELD_S = 20.0
"""The challenge's timeout where a queryable never answers it (a switch held to its end would
come after it)."""
SWITCH_S = 2 * PROVE_EVERY_S + PROVE_TIMEOUT_S + 5.0  # generous: a loaded 2-core machine


def wait(condition: Callable[[], Any], what: str, timeout: float = SWITCH_S) -> Any:
    deadline = time.time() + timeout
    while not (result := condition()):
        assert time.time() < deadline, what
        time.sleep(0.05)
    return result


def test_a_forged_token_changes_nothing_and_a_real_surfacing_still_switches() -> None:
    loaded = on_free_ports(udp_ports(MISSION), "proof.yaml")
    with running_fleet(loaded, key=KEY) as fleet:
        top, auv = fleet.nodes["top"], fleet.nodes["auv"]
        top_app, auv_app = outside_session(loaded, "top"), outside_session(loaded, "auv")
        arrived: list[tuple[int, bytes, bytes]] = []
        reports: list[tuple[str, bytes, bytes]] = []
        try:
            top_app.declare_subscriber("auv/nav", lambda s: arrived.append((
                msgpack.unpackb(s.payload.to_bytes())["x"], s.payload.to_bytes(),
                s.attachment.to_bytes())))
            top_app.declare_subscriber("@zab/proof/top/**", lambda s: reports.append((
                str(s.key_expr), s.payload.to_bytes(), s.attachment.to_bytes())))
            forged = top_app.liveliness().declare_token("@zab/proof/auv/bridge")
            assert top.ip_watch is not None
            wait(lambda: top.ip_watch.unproven >= 2, "the forged token is challenged")
            assert top.core.surfacing is not None and top.core.surfacing.reachable == set()
            auv_app.put("nav", msgpack.packb({"x": 1}))
            _, payload, attachment = wait(lambda: next((a for a in arrived if a[0] == 1), None),
                                          "nav crosses acoustically")
            origin, counter = check_output(KEY, "auv/nav", payload, attachment) or ("", 0)
            assert origin == "zab/1 proof/top" and counter > 0  # decoded by top's bridge

            wifi = access_point([*loaded.mission.nodes["top"].zenoh.listen,
                                 *loaded.mission.nodes["auv"].zenoh.listen])
            try:
                wait(lambda: top.core.surfacing.reachable == {"auv"}, "top sees auv surfaced")
                assert auv.core.surfacing is not None
                wait(lambda: auv.core.surfacing.reachable == {"top"}, "auv sees top surfaced")
                auv_app.put("nav", msgpack.packb({"x": 2}))
                _, payload, attachment = wait(
                    lambda: next((a for a in arrived if a[0] == 2), None), "nav relayed over IP")
                relayed = check_output(KEY, "auv/nav", payload, attachment)
                assert relayed is not None and relayed[0] == "zab/1 proof/auv"  # (by IP)
            finally:
                wifi.close()
            wait(lambda: top.core.surfacing.reachable == set(),
                 "the dive is seen though the forged token lives on")
            forged.undeclare()

            status = wait(lambda: next((r for r in reports if r[0].endswith("/stats")), None),
                          "top's stats")
            assert check_output(KEY, status[0], status[1], status[2]) is not None
            fake = msgpack.packb({"channel": "nav", "state": "delivered"})
            assert check_output(KEY, "@zab/proof/top/delivery/nav", fake, status[2]) is None
            assert check_output(KEY, status[0], status[1], b"zab/1 proof/top") is None
        finally:
            top_app.close()
            auv_app.close()



def errors_of_get(session: Any, selector: str) -> list[str]:
    """The reply errors a get on ``selector`` gets (its values are not asked here)."""
    return [r.err.payload.to_string() for r in session.get(selector, timeout=3.0)
            if r.err is not None]


def test_a_peers_token_not_yet_proven_silences_the_error_on_its_keyspace() -> None:
    loaded = on_free_ports(udp_ports(MISSION), "proof.yaml")
    with running_fleet(loaded, key=KEY) as fleet:
        top = fleet.nodes["top"]
        app = outside_session(loaded, "top")
        try:
            errors = errors_of_get(app, "auv/health")
            assert len(errors) == 1 and "maps this key at top" in errors[0]
            token = app.liveliness().declare_token("@zab/proof/auv/bridge")
            assert top.ip_watch is not None
            wait(lambda: top.ip_watch.tokens == {"auv"}, "top sees the token")
            assert top.core.surfacing is not None and top.core.surfacing.reachable == set()
            assert errors_of_get(app, "auv/health") == []  # (an answer may come over IP)
            token.undeclare()
            wait(lambda: not top.ip_watch.tokens, "top sees the token go")
            errors = errors_of_get(app, "auv/health")
            assert len(errors) == 1 and "maps this key at top" in errors[0]
        finally:
            app.close()


def test_a_queryable_on_the_prove_key_that_never_ends_does_not_hold_the_switch(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The bridge waited for the challenge's get to end (every queryable on the key, else its
    timeout) before it took a valid proof: one that held its reply open delayed each switch by
    PROVE_TIMEOUT_S, and a zab sim surfacing by as much once, while gets at the surface were
    answered both over IP and across the water. The challenge's timeout is made long here and
    the switch is timed from the challenge that settled it (the last to reach the queryable
    that never answers before it): a first challenge sent before the peer's answer could reach
    it runs to its timeout either way, on a loaded machine now and then."""
    monkeypatch.setattr(ip_watch, "PROVE_TIMEOUT_S", HELD_S)
    loaded = on_free_ports(udp_ports(MISSION), "proof.yaml")
    with running_fleet(loaded, key=KEY) as fleet:
        top = fleet.nodes["top"]
        app = outside_session(loaded, "top")
        held: list[tuple[float, Any]] = []
        try:  # (a challenge reaching it: noted, never answered)
            app.declare_queryable("@zab/proof/auv/prove", lambda q: held.append((time.time(), q)))
            assert top.ip_watch is not None and top.core.surfacing is not None
            wifi = access_point([*loaded.mission.nodes["top"].zenoh.listen,
                                 *loaded.mission.nodes["auv"].zenoh.listen])
            try:
                wait(lambda: top.ip_watch.tokens == {"auv"}, "top sees auv's token")
                wait(lambda: top.core.surfacing.reachable == {"auv"}, "top sees auv surfaced",
                     timeout=3 * HELD_S)
                switched = time.time()
                asked = max(t for t, _ in held if t <= switched)  # the challenge that settled it
                assert switched - asked < HELD_S / 2  # (held to its end: HELD_S at least)
            finally:
                wifi.close()
        finally:
            held.clear()
            app.close()
