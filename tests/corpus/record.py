"""The recorded-frames corpus: what every node's core outputs in fixed scenarios, kept as data.

Each scenario runs a mission on the virtual clock (:class:`FastFleet`, the same cores as
``zab run``) with seeded synthetic traffic, loss, restarts with and without saved state, and
queries where the mission has them. Everything each core outputs is recorded in order (frames
sent, publications, status, events, query outputs) with the state each node saved, and
compared byte for byte with what was recorded before a change (``tests/core/test_corpus.py``).

Recorded on main before the core was split (issue #28); record again only for a change of
behaviour that is meant, and say so in the commit::

    uv run python -m tests.corpus.record            # every scenario
    uv run python -m tests.corpus.record morph      # those whose name contains "morph"
"""

from __future__ import annotations

import dataclasses
import gzip
import random
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack

from bridge.core.events import Event
from bridge.core.loaded import LoadedMission, load_mission, parse_mission
from bridge.core.node import Publish, Status
from bridge.core.surfacing import Relay
from bridge.errors import DecodeError, EncodeError
from bridge.runtime.virtual_fleet import FastFleet, Timed

HERE = Path(__file__).resolve().parent
MISSIONS = HERE.parent.parent / "deploy" / "missions"
KEY = bytes(range(32))
"""The frame key of the authenticated scenarios."""


LOSSY = """\
mission: lossy
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im}}
mac: {type: tdma, slot_s: 2.0, guard_s: 0.2, order: [ops, auv]}
wire: {auth: {tag_bytes: 4}}
nodes:
  ops: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0}}
  auv: {address: 2, position: {x: 300, y: 0, depth: 20}}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 50
    elements:
      - in: cmd
        out: ops/cmd
        fields: [{field: n, type: int, min: 0, max: 1023}, {field: go, type: bool}]
  - name: image
    from: auv
    to: ops
    reliable: true
    elements:
      - in: image
        out: auv/image
        fields: [{field: jpeg, type: bytes, max_length: 400}]
  - name: nav
    from: auv
    to: ops
    latching: true
    elements:
      - in: nav
        out: auv/nav
        fields: [{field: depth, type: float, min: 0, max: 100, bits: 10}]
"""

ALOHA = """\
mission: aloha
modem: {backend: sim, frame_bytes: 32, options: {preset: evologics-s2c-im}}
mac: {type: aloha, backoff_s: 2.0, max_airtime_share: 0.3}
nodes:
  a: {address: 1, position: {x: 0, y: 0, depth: 5}}
  b: {address: 2, position: {x: 200, y: 0, depth: 10}}
  c: {address: 3, position: {x: 0, y: 250, depth: 15}}
channels:
  - name: status
    from: ".*"
    to: ".*"
    interval_s: 3
    elements:
      - in: status
        out: "{src}/status"
        fields:
          - {field: battery, type: int, min: 0, max: 100}
          - {field: depth, type: float, min: 0, max: 200, bits: 12}
  - name: alarm
    from: a
    to: [b, c]
    priority: 5
    ttl_s: 20
    elements:
      - in: alarm
        out: a/alarm
        fields: [{field: code, type: int, min: 0, max: 15}]
"""


@dataclass
class Scenario:
    """One recorded run."""

    name: str
    mission: Callable[[], LoadedMission]
    duration: float = 300.0
    seed: int = 3
    loss: float | None = 0.1
    restarts: tuple[tuple[float, int, bool], ...] = ((110.0, 1, True), (200.0, -1, False))
    """(time, index of the node in the mission, whether it keeps its saved state)."""
    puts: Callable[[FastFleet], None] | None = None
    subscribe: tuple[str, ...] = ("**",)
    """Key expressions the first node's applications subscribe to (demand missions)."""
    extra: dict[str, Any] = field(default_factory=dict)


def _shipped(name: str) -> Callable[[], LoadedMission]:
    return lambda: load_mission(MISSIONS / f"{name}.yaml")


def _lossy_puts(fleet: FastFleet) -> None:
    for i in range(120):
        fleet.put("ops", "cmd", {"n": i, "go": i % 2 == 0}, at=1.0 + i * 2.0, ref=f"c{i}")
    fleet.put("auv", "image", {"jpeg": bytes(random.Random(5).randbytes(300))}, at=5.0)
    fleet.put("auv", "image", {"jpeg": b"\x00" * 399}, at=150.0)
    fleet.put("auv", "image", {"jpeg": b"bad"}, at=151.0, encoding="json")


SCENARIOS = [
    *(Scenario(name, _shipped(name)) for name in (
        "bluerov_rf", "hippocampus", "morph", "morph_evologics", "remus_ccl",
        "remus_micromodem", "ros2_odometry", "zspace", "umci_relay", "acoustic_line")),
    # (Goby frames at 80 bit/s, and nothing sent when nothing is due: 300 s give 96 outputs)
    Scenario("goby_dccl", _shipped("goby_dccl"), duration=600.0),
    Scenario("zspace-nobody-wants", _shipped("zspace"), subscribe=(), seed=4),
    Scenario("lossy-reliable", lambda: parse_mission(LOSSY, "lossy.yaml"), loss=0.3,
             duration=400.0, puts=_lossy_puts),
    Scenario("aloha", lambda: parse_mission(ALOHA, "aloha.yaml"), loss=0.2, seed=9),
]


# -- recording -----------------------------------------------------------------------------------


def _plain(value: Any) -> Any:
    """``value`` as msgpack-able data, tuples as lists, dataclasses as dicts."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {_plain(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, set | frozenset):
        return sorted(_plain(v) for v in value)
    return value


def _record(timed: Timed) -> list[Any]:
    """One output as ``[time, node, what, ...]``."""
    out = timed.output
    head: list[Any] = [timed.time, timed.node]
    if isinstance(out, Publish):
        ros2 = None if out.ros2 is None else out.ros2.msgtype
        return [*head, "publish", out.key, _plain(out.value), out.encoding, out.latched, ros2]
    if isinstance(out, Status):
        return [*head, "status", out.topic, _plain(out.payload)]
    if isinstance(out, Event):
        return [*head, "event", out.kind, _plain(out.to_dict())]
    if isinstance(out, Relay):
        return [*head, "relay", out.key, out.data, out.encoding]
    return [*head, type(out).__name__, _plain(out)]


def _values(layout: Any, rng: random.Random) -> Any:
    """A value ``layout`` encodes, drawn from ``rng`` (DCCL layouts make their own)."""
    own = getattr(layout, "synthetic_value", None)
    if own is not None:
        return own(rng)
    try:
        value = layout.unpack(rng.getrandbits(layout.bits))
        layout.pack(value)
        return value
    except (DecodeError, EncodeError):
        return layout.unpack(0)


def _feed(fleet: FastFleet, rng: random.Random, until: float) -> None:
    """Every input key of every node (and every key family member) published now and then."""
    for name, core in fleet.cores.items():
        keys = [(key, bound[0][2].layout) for key, bound in core.bindings.items()]
        keys += list(core.families.feed_keys().items())
        for key, layout in keys:
            period = rng.choice((0.5, 2.0, 5.0, 11.0))

            def publish(n: str = name, k: str = key, lay: Any = layout, p: float = period
                        ) -> None:
                fleet.put(n, k, _values(lay, rng))
                if fleet.now + p <= until:
                    fleet.call_at(fleet.now + p * rng.uniform(0.5, 1.5), publish)

            fleet.call_at(rng.uniform(0, period), publish)


def _queries(fleet: FastFleet, rng: random.Random, until: float) -> None:
    """Every query asked every 37 s by each asker of each server, answered by a queryable."""
    for spec in fleet.loaded.table.queries:
        for server in spec.servers:
            fleet.queries.queryable(server, spec.served_key(server),
                                    lambda params, s=spec: [_values(s.reply, rng)])
            for asker in spec.askers:
                if asker == server:
                    continue

                fleet.call_at(13.0, _asker(fleet, rng, until, asker, spec.asked_key(server),
                                           spec.request))


def _asker(fleet: FastFleet, rng: random.Random, until: float, asker: str, key: str,
           layout: Any) -> Callable[[], None]:
    """``asker``'s get on ``key`` now and every 37 s after (each its own: a closure defined in
    a loop called back the last one, so only the last asker and server were asked again)."""
    def ask() -> None:
        fleet.queries.get(asker, key, _values(layout, rng) if layout.fields else {})
        if fleet.now + 37.0 <= until:
            fleet.call_at(fleet.now + 37.0, ask)
    return ask


def run(scenario: Scenario) -> dict[str, Any]:
    """Run ``scenario``: every node's outputs in order, and the states saved."""
    loaded = scenario.mission()
    records: list[list[Any]] = []
    fleet = FastFleet(loaded, seed=scenario.seed, loss=scenario.loss, key=KEY,
                      keep_outputs=False, on_output=lambda t: records.append(_record(t)),
                      kinds=(object,))
    nodes = list(loaded.mission.nodes)
    if loaded.mission.demand is not None:
        for key in scenario.subscribe:
            fleet.subscribe(nodes[0], key)
    rng = random.Random(f"corpus/{scenario.name}")
    _feed(fleet, rng, scenario.duration)
    _queries(fleet, rng, scenario.duration)
    if scenario.puts is not None:
        scenario.puts(fleet)
    if loaded.mission.surfacing is not None:  # the first two nodes meet over IP for a while
        fleet.call_at(60.0, lambda: fleet.ip_link(nodes[0], nodes[1], True))
        fleet.call_at(140.0, lambda: fleet.ip_link(nodes[0], nodes[1], False))
    states: list[list[Any]] = []
    for at, index, keep in scenario.restarts:
        fleet.run_until(at)
        node = nodes[index]
        states.append([at, node, _packed(fleet.saved.get(node))])
        fleet.restart(node, keep_state=keep)
    fleet.run_until(scenario.duration)
    states += [[fleet.now, n, _packed(fleet.saved.get(n))] for n in nodes]
    snapshots = {n: _plain(core.snapshot(fleet.now)) for n, core in fleet.cores.items()}
    return {"records": records, "states": states, "snapshots": snapshots}


def _packed(state: Any) -> bytes | None:
    return None if state is None else msgpack.packb(state, use_bin_type=True)


def normal(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` as it reads back from its file (msgpack's types)."""
    return msgpack.unpackb(msgpack.packb(result, use_bin_type=True), raw=False,
                           strict_map_key=False)


def path_of(scenario: Scenario) -> Path:
    return HERE / f"{scenario.name}.msgpack.gz"


def load(scenario: Scenario) -> dict[str, Any]:
    """What was recorded for ``scenario``."""
    return msgpack.unpackb(gzip.decompress(path_of(scenario).read_bytes()), raw=False,
                           strict_map_key=False)


def differences(expected: dict[str, Any], got: dict[str, Any]) -> Iterator[str]:
    """Where ``got`` first departs from ``expected``, readably."""
    for part in ("records", "states"):
        a, b = expected[part], got[part]
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            if x != y:
                yield f"{part}[{i}]: recorded {x!r}\n{' ' * len(part)}   now      {y!r}"
                break
        if len(a) != len(b):
            yield f"{part}: {len(a)} recorded, {len(b)} now"
    if expected["snapshots"] != got["snapshots"]:
        yield f"snapshots: recorded {expected['snapshots']!r}\n now {got['snapshots']!r}"


def main(argv: list[str]) -> None:
    for scenario in SCENARIOS:
        if argv and not any(word in scenario.name for word in argv):
            continue
        result = normal(run(scenario))
        data = gzip.compress(msgpack.packb(result, use_bin_type=True), mtime=0)
        path_of(scenario).write_bytes(data)
        print(f"{scenario.name}: {len(result['records'])} outputs, {len(data)} bytes")


if __name__ == "__main__":
    main(sys.argv[1:])
