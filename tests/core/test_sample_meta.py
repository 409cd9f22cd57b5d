"""What travels beside a value (issue 32), in the cores on the virtual clock: tombstones (also
of a key family's member), encodings, attachments, ages, fields left out, and a query's
carried deadline."""

from __future__ import annotations

import itertools

import msgpack
import pytest
import yaml

from bridge.core.events import FieldsLeftOut
from bridge.core.loaded import load_mission, parse_mission
from bridge.core.surfacing import Relay
from bridge.errors import MissionError
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.sample_meta import encoding_id
from tests.conftest import MISSIONS

ZSPACE = MISSIONS / "zspace.yaml"


def zspace(**status: object) -> FastFleet:
    """zspace with ``status`` and ``temps`` given the options, status wanted at the surface."""
    data = yaml.safe_load(ZSPACE.read_text())
    for channel in data["channels"]:
        if channel["name"] in ("status", "temps"):
            channel.update({k: v for k, v in status.items()
                            if channel["name"] == "status" or k == "deletes"})
    fleet = FastFleet(parse_mission(yaml.safe_dump(data, sort_keys=False), "z.yaml"), seed=1)
    fleet.subscribe("top", "**")
    return fleet


def test_the_fields_beside_a_value_are_appended_to_its_layout() -> None:
    fleet = zspace(deletes=True, age={"step_s": 0.5, "max_s": 100}, attachment_bytes=4)
    status = fleet.loaded.table.by_name("status")
    paths = [f.path for f in status.elements[0].layout.fields]
    assert paths == ["battery", "mode", "_zab_del", "_zab_att", "_zab_age"]
    # 7 + 2 + del 1 + attachment (length 3 + 32) + age 0..200 (8)
    assert status.bits == 7 + 2 + 1 + 3 + 32 + 8
    plain = load_mission(ZSPACE).table
    assert plain.by_name("status").bits == 9 and plain.fingerprint != fleet.loaded.table.fingerprint


def test_a_delete_crosses_once_and_the_latched_value_is_not_sent_again() -> None:
    fleet = zspace(deletes=True)
    fleet.put("auv1", "auv1/status", {"battery": 80, "mode": "survey"}, at=1.0)
    fleet.run_until(10.0)
    assert fleet.published("top", "auv1/status")[-1][1].value == {"battery": 80, "mode": "survey"}
    assert fleet.cores["top"].queries.cache["auv1/status"][0] == {"battery": 80, "mode": "survey"}
    fleet.cores["auv1"].delete("auv1/status", fleet.now)
    fleet.run_until(30.0)
    after = [p for t, p in fleet.published("top", "auv1/status") if t > 10.5]
    assert after and all(p.delete and p.value is None for p in after)  # the tombstone, latched
    assert "auv1/status" not in fleet.cores["top"].queries.cache
    fleet.put("auv1", "auv1/status", {"battery": 79, "mode": "idle"})
    fleet.run_until(40.0)
    assert fleet.published("top", "auv1/status")[-1][1].value == {"battery": 79, "mode": "idle"}


def test_a_key_familys_member_is_deleted_on_its_own_key() -> None:
    fleet = zspace(deletes=True)
    for member in ("a", "b"):
        fleet.put("auv1", f"auv1/sensors/{member}/temp", {"celsius": 10.0}, at=1.0)
    fleet.run_until(10.0)
    fleet.cores["auv1"].delete("auv1/sensors/a/temp", fleet.now)
    fleet.run_until(20.0)
    last = {key: p for _, p in fleet.published("top") if (key := p.key).endswith("/temp")}
    assert last["auv1/sensors/a/temp"].delete
    assert last["auv1/sensors/b/temp"].value == {"celsius": 10.0}


def test_a_receiver_stamps_each_value_with_when_it_was_taken() -> None:
    fleet = zspace(age={"step_s": 0.5, "max_s": 100})
    fleet.put("auv1", "auv1/status", {"battery": 80, "mode": "survey"}, at=1.3)
    fleet.run_until(30.0)
    arrivals = fleet.published("top", "auv1/status")
    assert len(arrivals) >= 3  # latched: sent again every interval_s
    for arrived, publish in arrivals:
        assert publish.taken == pytest.approx(1.3, abs=0.5) and arrived - publish.taken > 0.5
    plain = FastFleet(load_mission(ZSPACE), seed=1)
    plain.subscribe("top", "**")
    plain.put("auv1", "auv1/status", {"battery": 80, "mode": "survey"}, at=1.3)
    plain.run_until(30.0)
    arrived, publish = plain.published("top", "auv1/status")[-1]
    assert publish.taken is not None and arrived - 1.0 < publish.taken < arrived  # its frame's


def test_the_encoding_and_attachment_the_application_used_cross() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["channels"][3]["elements"][0]["encoding"] = "as_sent"
    data["channels"][3]["attachment_bytes"] = 6
    fleet = FastFleet(parse_mission(yaml.safe_dump(data, sort_keys=False), "z.yaml"), seed=1)
    fleet.subscribe("top", "**")
    fleet.cores["auv1"].ingest("auv1/status", b'{"battery": 60, "mode": "idle"}', "text/plain", 1.0,
                               attachment=b"run-42-and-more")
    fleet.run_until(10.0)
    publish = fleet.published("top", "auv1/status")[-1][1]
    assert (publish.value, publish.encoding) == ({"battery": 60, "mode": "idle"}, "text")
    assert publish.attachment == b"run-42"  # the first attachment_bytes bytes
    assert [encoding_id(e, b"{}") for e in ("application/msgpack", "application/json",
                                            "text/plain", "zenoh/bytes")] == [0, 1, 2, 3]
    assert encoding_id("zenoh/bytes", msgpack.packb({"a": 1})) == 0


def test_fields_no_channel_reads_are_counted_and_reported_once_per_key() -> None:
    fleet = zspace()
    for battery in (10, 20):
        fleet.put("auv1", "auv1/status", {"battery": battery, "mode": "idle", "note": "x"})
    core = fleet.cores["auv1"]
    assert core.stats.fields_left_out == {"auv1/status": 2}
    assert core.snapshot(fleet.now)["fields_left_out"] == {"auv1/status": 2}
    reported = [t.output for t in fleet.outputs if isinstance(t.output, FieldsLeftOut)]
    assert [(e.key, e.fields) for e in reported] == [("auv1/status", ["note"])]
    assert "fields_left_out" not in fleet.cores["top"].snapshot(fleet.now)


def test_a_flood_of_new_field_names_is_counted_and_told_at_a_bounded_rate() -> None:
    """Found by bench/flood.py: random field names put fast made four fields_left_out events
    a second (each new set of names was told)."""
    fleet = zspace()
    keys = ("auv1/status", "auv1/alarm")
    values = ({"battery": 10, "mode": "idle"}, {"leak": False})
    for i in range(900):  # 90 s, ten a second, a new field name each
        key, value = keys[i % 2], values[i % 2]
        fleet.put("auv1", key, {**value, f"x{i}": i}, at=1.0 + i / 10)
    fleet.run_until(95.0)
    core = fleet.cores["auv1"]
    assert core.stats.fields_left_out == {key: 450 for key in keys}
    told = [t.output for t in fleet.outputs if isinstance(t.output, FieldsLeftOut)]
    times = [e.time for e in told]
    assert all(b - a >= 1.0 for a, b in itertools.pairwise(times))  # one a second in all
    for key in keys:  # one a minute per key: at the start and a minute on
        assert len([e for e in told if e.key == key]) == 2


def test_a_request_that_arrives_after_its_callers_deadline_is_not_served() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["queries"][0]["deadline_bits"] = 8
    fleet = FastFleet(parse_mission(yaml.safe_dump(data, sort_keys=False), "q.yaml"), seed=1)
    served: list[dict] = []
    fleet.queries.queryable("auv1", "auv1/info", lambda p: served.append(p) or [
        {"depth_m": 1.0, "state": "idle", "detail": 0}])
    fleet.run_until(11.95)  # top's slot starts at 12: the request leaves then
    late = fleet.queries.get("top", "auv1/info", {"detail": 1}, timeout=0.3)
    fleet.run_until(20.0)
    assert late.error is not None and "caller's deadline" in late.error
    assert served == [] and fleet.cores["auv1"].queries.dropped["expired"] == 1
    fine = fleet.queries.get("top", "auv1/info", {"detail": 2}, timeout=8.0)
    fleet.run_until(30.0)
    assert fine.error is None and served == [{"detail": 2}]


def test_the_fields_beside_a_value_need_fields_of_the_mission() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["channels"][0]["age"] = {"step_s": 1, "max_s": 10}  # temps is a key family
    with pytest.raises(MissionError, match="age is carried on latest-value channels"):
        parse_mission(yaml.safe_dump(data, sort_keys=False))
    data = yaml.safe_load(ZSPACE.read_text())
    data["channels"][3]["elements"][0]["fields"][0]["field"] = "_zab_x"
    with pytest.raises(MissionError, match="names starting with _zab are the bridge's"):
        parse_mission(yaml.safe_dump(data, sort_keys=False))


def test_over_ip_a_relay_carries_the_attachment_and_a_delete_as_the_water_would() -> None:
    data = yaml.safe_load(ZSPACE.read_text())
    data["channels"][3].update(attachment_bytes=4, deletes=True)
    data["channels"][3]["elements"][0]["out"] = "surface/{src}/status"  # not the input key
    fleet = FastFleet(parse_mission(yaml.safe_dump(data, sort_keys=False), "z.yaml"), seed=1)
    fleet.run_until(10.0)
    fleet.ip_link("auv1", "top", True)
    core = fleet.cores["auv1"]
    core.ingest("auv1/status", msgpack.packb({"battery": 1, "mode": "idle"}),
                "application/msgpack", fleet.now, attachment=b"tag1")
    core.delete("auv1/status", fleet.now + 1)
    relays = [o for o in core.take() if isinstance(o, Relay)]
    assert [(r.key, r.attachment, r.delete, r.taken) for r in relays] == [
        ("surface/auv1/status", b"tag1", False, 10.0), ("surface/auv1/status", None, True, 11.0)]
