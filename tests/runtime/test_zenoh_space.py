"""Zenoh as Zenoh users know it (issue 32), end to end: plain Zenoh applications (``zenoh`` and
``msgpack`` only, no import from the project) at two nodes of one ``zab sim`` process, shared
by every test of this module."""

from __future__ import annotations

import json
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import msgpack
import pytest
import zenoh

from tests.zsim import app, drain, mission_file, zab_sim

LONG = True  # a minute of one real-time fleet's tests: handed out first

MISSION = """
mission: zfid
wire: {auth: off}
link: {heartbeat_s: 2}
modem:
  backend: sim
  frame_bytes: 48
  options: {preset: evologics-s2c-im, seed: 1}
mac: {type: tdma, slot_s: 0.8, guard_s: 0.05, order: [top, auv1]}
nodes:
  top: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  auv1: {address: 2, position: {x: 40, y: 30, depth: 10}}
queries:
  - name: info
    key: auv1/info
    serve: auv1
    request: [{field: detail, type: int, min: 0, max: 3}]
    reply:
      - {field: depth_m, min: 0, max: 200, resolution: 0.5}
      - {field: detail, type: int, min: 0, max: 3}
    max_replies: 2
    deadline_bits: 4
  - name: state
    key: auv1/state
    serve: auv1
    reply: [{field: mode, type: enum, values: [idle, survey]}]
  - name: probe  # its queryable answers badly as asked (serve_at_auv1)
    key: auv1/x/probe
    serve: auv1
    request: [{field: detail, type: int, min: 0, max: 7}]
    reply: [{field: v, min: 0, max: 200, resolution: 1}]
channels:
  - name: status
    from: auv1
    to: top
    latching: true
    interval_s: 2
    deletes: true
    age: {step_s: 0.5, max_s: 60}
    attachment_bytes: 8
    elements:
      - in: status
        out: "{src}/status"
        encoding: as_sent
        fields:
          - {field: battery, min: 0, max: 100, resolution: 1}
  - name: depth
    from: auv1
    to: top
    elements:
      - in: depth
        out: "{src}/depth"
        fields: [{field: m, min: 0, max: 100, resolution: 0.5}]
"""


@dataclass
class Space:
    """The running ``zab sim`` and an application session at each node."""

    top: zenoh.Session
    auv1: zenoh.Session
    served: dict[str, int] = field(default_factory=dict)  # queryable runs at auv1, by key


@pytest.fixture(scope="module")
def space(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Space]:
    mission, endpoints = mission_file(MISSION, tmp_path_factory.mktemp("zfid"))
    with zab_sim(mission, endpoints, timeout=600):
        top, auv1 = app(endpoints["top"]), app(endpoints["auv1"])
        space = Space(top, auv1)
        try:
            serve_at_auv1(space)
            wait_until_answered(top)
            yield space
        finally:
            top.close()
            auv1.close()


def serve_at_auv1(space: Space) -> None:
    """auv1's applications: ``auv1/info`` answers twice, ``auv1/state`` once."""
    def info(query: zenoh.Query) -> None:
        space.served["info"] = space.served.get("info", 0) + 1
        detail = int(str(query.parameters).partition("detail=")[2] or 0)
        for depth in (10.5, 11.0):
            query.reply(query.key_expr, msgpack.packb({"depth_m": depth, "detail": detail}))
        query.drop()

    def state(query: zenoh.Query) -> None:
        space.served["state"] = space.served.get("state", 0) + 1
        query.reply(query.key_expr, msgpack.packb({"mode": "survey"}))
        query.drop()

    def probe(query: zenoh.Query) -> None:
        detail = int(str(query.parameters).partition("detail=")[2] or 0)
        if detail == 4:  # no answer before the local get's time is up
            threading.Timer(1.5, query.drop).start()
            return
        if detail == 1:
            query.reply_err(b"sensor offline")
        else:
            query.reply(query.key_expr, {0: msgpack.packb({"v": 5}), 2: b"\xc1\xff garbage",
                                         3: msgpack.packb({"v": 500}),
                                         5: msgpack.packb({"v": 5, "pad": "x" * 100_000})
                                         }[detail])
        query.drop()

    space.auv1.declare_queryable("auv1/info", info)
    space.auv1.declare_queryable("auv1/state", state)
    space.auv1.declare_queryable("auv1/x/probe", probe)


ALL = zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE)


def get(session: zenoh.Session, selector: str, timeout: float = 20.0
        ) -> tuple[list[tuple[str, Any]], list[str]]:
    """Every reply of a get (consolidation none): (key, value) in order, and the errors."""
    values, errors = [], []
    for reply in session.get(selector, timeout=timeout, consolidation=ALL):
        if reply.ok is not None:
            values.append((str(reply.ok.key_expr), msgpack.unpackb(reply.ok.payload.to_bytes())))
        else:
            errors.append(reply.err.payload.to_string())
    return values, errors


def wait_until_answered(top: zenoh.Session) -> None:
    """Until the surface has heard auv1 (its link is up) and a get is answered."""
    deadline = time.time() + 30
    while True:
        values, errors = get(top, "auv1/state")
        if values or time.time() > deadline:
            break
        time.sleep(0.5)
    assert values, errors


def test_every_reply_of_the_far_queryable_arrives_in_order(space: Space) -> None:
    values, errors = get(space.top, "auv1/info?detail=2")
    assert values == [("auv1/info", {"depth_m": 10.5, "detail": 2}),
                      ("auv1/info", {"depth_m": 11.0, "detail": 2})], errors
    assert not errors


def test_a_get_whose_caller_gave_up_never_reaches_the_vehicle(space: Space) -> None:
    before = space.served.get("info", 0)
    for _ in range(4):
        values, _ = get(space.top, "auv1/info?detail=1;_timeout=0.3", timeout=0.3)
        assert values == []
    time.sleep(4.0)  # two TDMA cycles: any request sent would have been served by now
    assert space.served.get("info", 0) == before
    values, _ = get(space.top, "auv1/info?detail=1")  # the caller waits: it crosses
    assert len(values) == 2 and space.served["info"] == before + 1


def test_a_wildcard_get_asks_what_it_can_and_says_what_it_cannot(space: Space) -> None:
    values, errors = get(space.top, "auv1/**")
    assert ("auv1/state", {"mode": "survey"}) in values
    assert all(key != "auv1/info" for key, _ in values)
    assert len(errors) == 1 and "auv1/info needs detail" in errors[0]
    values, errors = get(space.top, "auv1/*?detail=3")  # parameters given: both are asked
    assert ("auv1/info", {"depth_m": 10.5, "detail": 3}) in values
    assert ("auv1/state", {"mode": "survey"}) in values
    assert not errors


def test_concurrent_wildcard_and_plain_gets_each_get_their_replies(space: Space) -> None:
    results: dict[str, Any] = {}

    def ask(selector: str) -> None:
        results[selector] = get(space.top, selector)

    threads = [threading.Thread(target=ask, args=(s,))
               for s in ("auv1/state", "auv1/**?detail=0")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert results["auv1/state"] == ([("auv1/state", {"mode": "survey"})], [])
    values, errors = results["auv1/**?detail=0"]
    assert {k for k, _ in values} >= {"auv1/state", "auv1/info"} and not errors



@dataclass(frozen=True)
class Seen:
    """One sample a subscriber got, as an application reads it."""

    kind: str
    key: str
    payload: bytes
    encoding: str
    attachment: bytes | None
    stamped: float | None  # its Zenoh timestamp, seconds since the epoch
    at: float  # when it arrived


class Watch:
    """Every sample on a key expression at a node, in order."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.items: queue.Queue[Seen] = queue.Queue()
        self.subscriber = session.declare_subscriber(key, self._got)

    def _got(self, sample: zenoh.Sample) -> None:
        stamp = sample.timestamp
        self.items.put(Seen(
            "delete" if sample.kind == zenoh.SampleKind.DELETE else "put",
            str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding),
            sample.attachment.to_bytes() if sample.attachment is not None else None,
            stamp.get_time().timestamp() if stamp is not None else None, time.time()))

    def next(self, timeout: float = 10.0) -> Seen:
        return self.items.get(timeout=timeout)

    def during(self, seconds: float) -> list[Seen]:
        return drain(self.items, seconds)

    def close(self) -> None:
        self.subscriber.undeclare()


@pytest.fixture
def status(space: Space) -> Iterator[Watch]:
    watch = Watch(space.top, "auv1/status")
    try:
        yield watch
    finally:
        watch.close()


def test_json_in_json_out_msgpack_in_msgpack_out(space: Space, status: Watch) -> None:
    for encoding, payload in (("application/json", b'{"battery": 41}'),
                              ("text/plain", b'{"battery": 42}'),
                              ("application/msgpack", msgpack.packb({"battery": 43}))):
        space.auv1.put("status", payload, encoding=zenoh.Encoding(encoding))
        seen = status.next()
        while seen.kind != "put" or seen.encoding != encoding:  # a re-send of the one before
            seen = status.next()
        value = msgpack.unpackb(seen.payload) if "msgpack" in encoding \
            else json.loads(seen.payload)
        assert value == {"battery": int(payload[-3:-1]) if b"{" in payload else 43}


def test_a_sample_carries_when_its_value_was_taken_even_when_latched(
        space: Space, status: Watch) -> None:
    taken = time.time()
    space.auv1.put("status", msgpack.packb({"battery": 64}),
                   encoding=zenoh.Encoding("application/msgpack"))
    seen = [s for s in status.during(8.0) if s.kind == "put"
            and msgpack.unpackb(s.payload) == {"battery": 64}]
    assert len(seen) >= 2  # the value, then re-sends of it (latching, every 2 s)
    step = 0.5
    for sample in seen:
        assert sample.stamped is not None and abs(sample.stamped - taken) <= step
    assert seen[-1].at - seen[-1].stamped > 2.0  # a re-send: its age shows
    replies = list(space.top.get("auv1/status", timeout=5.0))  # from the latched cache
    assert [r.ok.timestamp.get_time().timestamp() for r in replies if r.ok] == \
        [pytest.approx(seen[-1].stamped)]


def test_an_applications_own_timestamp_is_when_its_value_was_taken(
        space: Space, status: Watch) -> None:
    """A sensor's program stamps its value when it was measured and puts it later: the value
    comes out stamped then (within a step), not when the bridge took it (4 s off before; a
    value taken before the newest one published there would not come out at all)."""
    taken = time.time() - 4.0
    seconds = int(taken)
    stamp = zenoh.Timestamp(zenoh.NTP64(seconds, int((taken - seconds) * 1e9)),
                            space.auv1.new_timestamp().get_id())
    space.auv1.put("status", msgpack.packb({"battery": 41}),
                   encoding=zenoh.Encoding("application/msgpack"), timestamp=stamp)
    seen = status.next()
    while seen.kind != "put" or msgpack.unpackb(seen.payload) != {"battery": 41}:
        seen = status.next()
    assert seen.stamped is not None and abs(seen.stamped - taken) <= 0.5
    assert seen.at - seen.stamped > 3.0


def test_a_plain_channels_sample_is_stamped_when_its_frame_left(space: Space) -> None:
    watch = Watch(space.top, "auv1/depth")
    try:
        put_at = time.time()
        space.auv1.put("depth", msgpack.packb({"m": 12.5}),
                       encoding=zenoh.Encoding("application/msgpack"))
        seen = watch.next()
        assert seen.stamped is not None and put_at <= seen.stamped + 0.05 <= seen.at
    finally:
        watch.close()


def test_the_applications_attachment_crosses_behind_the_bridge_marker(
        space: Space, status: Watch) -> None:
    space.auv1.put("status", msgpack.packb({"battery": 12}),
                   encoding=zenoh.Encoding("application/msgpack"), attachment=b"trip-7")
    seen = status.next()
    while msgpack.unpackb(seen.payload) != {"battery": 12}:
        seen = status.next()
    assert seen.attachment == b"zab/1 zfid/top\x00trip-7"


def test_a_delete_crosses_and_clears_the_latched_value_on_both_sides(
        space: Space, status: Watch) -> None:
    space.auv1.put("status", msgpack.packb({"battery": 77}),
                   encoding=zenoh.Encoding("application/msgpack"))
    seen = status.next()
    while seen.kind != "put" or msgpack.unpackb(seen.payload) != {"battery": 77}:
        seen = status.next()
    assert [r.ok.key_expr for r in space.top.get("auv1/status", timeout=5.0) if r.ok]
    space.auv1.delete("status")
    seen = status.next()
    while seen.kind != "delete":
        seen = status.next()
    assert seen.key == "auv1/status"
    assert [r for r in space.top.get("auv1/status", timeout=5.0) if r.ok] == []
    later = status.during(5.0)  # two intervals of the latching channel
    assert [s.kind for s in later] == []  # neither the old value nor the delete again
    space.auv1.put("status", msgpack.packb({"battery": 78}),
                   encoding=zenoh.Encoding("application/msgpack"))
    seen = status.next()
    assert seen.kind == "put" and msgpack.unpackb(seen.payload) == {"battery": 78}


def stats_of(session: zenoh.Session, node: str, until: Any, timeout: float = 10.0
             ) -> dict[str, Any]:
    """The first ``@zab/zfid/<node>/stats`` for which ``until(stats)`` holds."""
    watch = Watch(session, f"@zab/zfid/{node}/stats")
    try:
        end = time.time() + timeout
        while True:
            stats = msgpack.unpackb(watch.next(max(0.1, end - time.time())).payload)
            if until(stats) or time.time() > end:
                return stats
    finally:
        watch.close()


def test_fields_no_channel_carries_are_counted_and_said_once(space: Space) -> None:
    events = Watch(space.auv1, "@zab/zfid/auv1/events")
    try:
        for n in range(3):
            space.auv1.put("status", msgpack.packb({"battery": 50 + n, "note": "hi", "x": 1}),
                           encoding=zenoh.Encoding("application/msgpack"))
        stats = stats_of(space.auv1, "auv1", lambda s: s.get("fields_left_out"))
        assert stats["fields_left_out"] == {"status": 3}
        said = [msgpack.unpackb(e.payload) for e in events.during(2.0)]
        left = [e for e in said if e["kind"] == "fields_left_out"]
        assert [(e["key"], e["fields"]) for e in left] == [("status", ["note", "x"])]
    finally:
        events.close()


def test_a_put_no_channel_reads_is_counted_and_said_once(space: Space) -> None:
    events = Watch(space.auv1, "@zab/zfid/auv1/events")
    try:
        for _ in range(2):
            space.auv1.put("auv1/statsu", msgpack.packb({"battery": 5}))  # a typo
        space.auv1.put("status", msgpack.packb({"battery": 5}))  # read: not counted
        stats = stats_of(space.auv1, "auv1", lambda s: s.get("unmapped_keys"))
        assert stats["unmapped_keys"] == {"auv1/statsu": 2}
        said = [msgpack.unpackb(e.payload) for e in events.during(2.0)]
        assert [e["key"] for e in said if e["kind"] == "unmapped_key"] == ["auv1/statsu"]
    finally:
        events.close()


def test_a_get_that_maps_to_nothing_says_so(space: Space) -> None:
    values, errors = get(space.top, "auv1/nothing/here")
    assert values == [] and len(errors) == 1
    assert "no query and no channel of the mission maps this key at top" in errors[0]
    values, errors = get(space.top, "auv1/depth")
    assert values == [] and "auv1/depth (channel depth) at top not latched" in errors[0]
    space.auv1.put("status", msgpack.packb({"battery": 9}))
    stats_of(space.top, "top", lambda s: s.get("received_age_s", {}).get("status", 99) < 1)
    values, errors = get(space.top, "auv1/status")
    assert values and not errors  # the latched value; nothing else to say


def test_a_get_payload_may_not_contradict_its_selector_nor_be_too_long(space: Space) -> None:
    asked = space.served.get("info", 0)
    for payload, said in ((msgpack.packb({"detail": 2}), "parameter 'detail' given twice, 0 "
                           "in the selector and 2 in the payload: give it once"),
                          (msgpack.packb({"detail": 0, "pad": "y" * 1_000_000}),
                           "a get payload of 1000018 bytes, over this query's cap of 16400"),
                          (b"\xc1junk", "nor msgpack (reserved byte 0xc1 at offset 0)")):
        replies = list(space.top.get("auv1/info?detail=0", payload=payload, timeout=20))
        assert len(replies) == 1 and replies[0].err is not None
        assert said in replies[0].err.payload.to_string()
    assert space.served.get("info", 0) == asked  # none crossed
    replies = list(space.top.get("auv1/info?detail=1", payload=msgpack.packb({"pad": "y"}),
                                 timeout=20, consolidation=ALL))
    assert [msgpack.unpackb(r.ok.payload.to_bytes())["detail"] for r in replies] == [1, 1]
    stats = stats_of(space.top, "top", lambda s: s.get("fields_left_out"))
    assert stats["fields_left_out"] == {"auv1/info": 1}
    assert stats["payload_drop_causes"] == {
        "auv1/info": {"unfit": 1, "too_large": 1, "undecodable": 1}}


def test_a_reply_the_vehicle_cannot_send_is_counted_and_the_getter_told_why(
        space: Space) -> None:
    said = {}
    for detail in (1, 2, 4, 5):
        values, errors = get(space.top, f"auv1/x/probe?detail={detail}")
        assert values == [] and len(errors) == 1
        said[detail] = errors[0]
    assert said[1] == ("auv1: query 'probe': app-error: its queryable replied with an error "
                       "(its text is in auv1's log)")
    assert said[2].startswith("auv1: query 'probe': not-usable: ")
    assert said[4].startswith("auv1: query 'probe': timeout: ")
    assert said[5].startswith("auv1: query 'probe': not-usable: ")  # (100 kB: over the cap)
    values, errors = get(space.top, "auv1/x/probe?detail=3")
    assert values == [("auv1/x/probe", {"v": 200.0})] and not errors  # clamped, and counted:
    stats = stats_of(space.auv1, "auv1", lambda s: "!probe" in s.get("clamped", {}))
    assert stats["clamped"] == {"!probe": {"v": 1}}
    assert {k: n for k, n in stats["queries"]["dropped"].items() if n} == {"probe:reply": 3}
    assert stats["payload_drop_causes"] == {"auv1/x/probe": {"error_reply": 1, "too_large": 1,
                                                            "undecodable": 1}}
