"""Fidelity that follows the link: a vehicle reachable over IP gets no acoustic (quantised)
copies; after the dive acoustic bridging resumes within a cycle, latched state and all."""

from __future__ import annotations

import yaml

from bridge.core.loaded import load_mission, parse_mission
from bridge.core.surfacing import Relay
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.payloads import encode_payload
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"
CYCLE_S = 3.0  # the example's TDMA cycle


def fleet(status_out: str | None = None) -> FastFleet:
    """The example's fleet 10 s in, auv1's status and alarm put; ``status_out``: the status
    channel's output key instead of its input key ``{node}/status``."""
    loaded = load_mission(ZSPACE)
    if status_out is not None:
        data = yaml.safe_load(ZSPACE.read_text())
        data["channels"][3]["elements"][0]["out"] = status_out
        loaded = parse_mission(yaml.safe_dump(data, sort_keys=False), "z.yaml")
    f = FastFleet(loaded, seed=1)
    f.subscribe("top", "auv1/status")
    f.put("auv1", "auv1/status", {"battery": 77.3, "mode": "survey"}, at=0.5)
    f.put("auv1", "auv1/alarm", {"leak": False}, at=0.5)
    f.run_until(10.0)
    return f


def test_surfaced_vehicle_sends_nothing_acoustic_and_relays_full_fidelity() -> None:
    f = fleet(status_out="{src}/status/raw")  # apart from the input key: the bridge relays it
    f.subscribe("top", "auv1/status/raw")
    f.run_until(20.0)
    assert f.published("top", "auv1/status/raw")[-1][1].value == {"battery": 77,
                                                                  "mode": "survey"}
    f.ip_link("auv1", "top", True)
    sent = dict(f.cores["auv1"].stats.sent_per_channel)
    start, put_at = len(f.outputs), f.now
    f.put("auv1", "auv1/status", {"battery": 66.6, "mode": "transit"})
    f.run_until(50.0)
    assert f.cores["auv1"].stats.sent_per_channel == sent  # neither status nor alarm
    later = f.outputs[start:]
    assert not [o for o in later if o.node == "top" and getattr(o.output, "key", "")
                == "auv1/status/raw"]
    relays = [o.output for o in later if isinstance(o.output, Relay)]
    data, enc = encode_payload({"battery": 66.6, "mode": "transit"}, "msgpack")
    # unquantised, on the output key, stamped when the bridge took it
    assert relays == [Relay("auv1/status/raw", data, enc, taken=put_at)]
    snap = f.cores["top"].snapshot(50.0)["surfacing"]
    assert snap["ip_reachable"] == ["auv1"]


def test_after_the_dive_latched_state_resumes_within_a_cycle_without_a_burst() -> None:
    f = fleet()
    f.ip_link("auv1", "top", True)
    f.put("auv1", "auv1/status", {"battery": 66.6, "mode": "transit"}, at=12.0)
    f.put("auv1", "auv1/status", {"battery": 55.0, "mode": "transit"}, at=14.0)
    f.run_until(30.0)
    dive = f.now
    f.ip_link("auv1", "top", False)
    f.run_until(dive + CYCLE_S)
    got = [(t, p.value) for t, p in f.published("top", "auv1/status") if t > dive]
    assert got == [(got[0][0], {"battery": 55, "mode": "transit"})]  # the latest, once
    alarms = [t for t, _ in f.published("top", "auv1/alarm") if t > dive]
    assert len(alarms) == 1  # always-on latched state comes back too


def test_a_sender_that_has_not_noticed_is_not_published_twice() -> None:
    f = fleet()
    f.cores["top"].ip_reachable("auv1", True, f.now)  # only the surface sees the token yet
    before = len(f.published("top", "auv1/status"))
    f.put("auv1", "auv1/status", {"battery": 50.0, "mode": "idle"})
    f.run_until(20.0)
    assert len(f.published("top", "auv1/status")) == before
    assert f.cores["top"].surfacing.duplicates >= 1





def test_zab_check_warns_of_an_input_key_two_vehicles_read_alike() -> None:
    """Two vehicles up at once share one Zenoh: an input key both read alike would take each
    one's samples as the other's, so check says where and how to name the sender."""
    from bridge.report.check import check_mission

    def warned(text: str) -> list[str]:
        found = check_mission(parse_mission(text, "z.yaml")).warnings
        return [w for w in found if "both read" in w]

    text = ZSPACE.read_text()
    assert warned(text) == []  # the example names the sender in every vehicle's input
    bare = text.replace('in: "{node}/status"', "in: status")
    assert warned(bare) == [
        "channels[3].elements[0].in: auv1 and auv2 both read 'status': with surfacing, two "
        "vehicles up at once share one Zenoh, and each bridge would take the other's samples "
        "as its own; name the sender in the key, e.g. '{node}/status'"]
    family = text.replace('in: "{node}/contacts/{key}"', 'in: "contacts/{key}"')
    assert warned(family) == [w.replace("status", "contacts/*").replace("[3]", "[1]")
                              for w in warned(bare)]
    assert warned(bare.replace("surfacing:\n  republish: true\n", "")) == []  # no IP join
