"""The vehicle router's access control (deploy/zenoh/vehicle.json5, unchanged but for its
endpoints) over real Zenoh sessions: the bridge joins over its Unix socket, an application over
loopback TCP. Only the bridge may put on `@zab/**` or on the keys it publishes from the water,
declare a liveliness token under `@zab/**` (a link up, a peer surfaced), or answer there; the
application's own inputs and every read go through.

A refusal is shown by a fence: after its refused attempts, the application asks a query the
bridge answers; a link's messages are handled in order, so once the answer is back the router
has judged the attempts, and anything it let through has been forwarded."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from bridge.core.interest import output_keys
from bridge.core.loaded import load_mission
from tests.conftest import MISSIONS, free_port
from tests.deploy.test_deploy_kit import _on_loopback
from tests.deploy.tls_kit import bridge_socket_config, close, local_config, wait

NODE = "lsv"  # the vehicle the shipped config is written for, in deploy/missions/morph.yaml


def bridged_outputs(mission: Path, node: str) -> list[str]:
    """The keys ``node``'s bridge publishes from the water: the config's deny list with
    `@zab/**`."""
    loaded = load_mission(mission)
    return sorted({key for keys in output_keys(loaded.table, node).values() for key in keys})


@dataclass
class Vehicle:
    router: zenoh.Session
    bridge: zenoh.Session
    app: zenoh.Session
    watcher: zenoh.Session
    heard: list[tuple[str, bytes]] = field(default_factory=list)
    tokens: list[tuple[str, zenoh.SampleKind]] = field(default_factory=list)

    def fence(self) -> None:
        """Returns once the router has judged everything the application sent before."""
        wait(lambda: any(r.ok for r in self.app.get("fence/app", timeout=5.0)),
             "the bridge answers the application's query")


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    socket = tmp_path_factory.mktemp("zenoh") / "bridge.sock"
    port = free_port()
    with ExitStack() as stack:
        def opened(config: zenoh.Config) -> zenoh.Session:
            session = zenoh.open(config)
            stack.callback(close, session)
            return session

        router = opened(_on_loopback("vehicle", [f"tcp/127.0.0.1:{port}",
                                                 f"unixsock-stream/{socket}"], []))
        found = Vehicle(router=router, bridge=opened(bridge_socket_config(socket)),
                        app=opened(local_config(port)), watcher=opened(local_config(port)))
        found.bridge.declare_queryable("fence/**", lambda q: q.reply(q.key_expr, b"ok"))
        for key in ("**", "@zab/**"):
            found.watcher.declare_subscriber(key, lambda s: found.heard.append(
                (str(s.key_expr), s.payload.to_bytes())))
            found.watcher.liveliness().declare_subscriber(
                key, lambda s: found.tokens.append((str(s.key_expr), s.kind)), history=True)
        yield found


def test_the_deny_list_is_the_vehicles_bridged_outputs() -> None:
    config = zenoh.Config.from_file(str(MISSIONS.parent / "zenoh" / "vehicle.json5"))
    [rule] = json.loads(config.get_json("access_control/rules"))
    assert rule["key_exprs"] == ["@zab/**", *bridged_outputs(MISSIONS / "morph.yaml", NODE)]


def test_only_the_bridge_speaks_for_the_bridge(vehicle: Vehicle) -> None:
    spoofs = {"@zab/morph/lsv/delivery/command": b"app: a fake delivery report",
              "@zab/morph/lsv/stats": b"app: fake stats", "gcv/nav": b"app: as if from gcv",
              "ssv/command": b"app: as if the surface commanded"}
    own = {"nav": b"app: its own navigation", "lsv/status": b"app: its own status"}
    publishers = [(vehicle.app.declare_publisher(k), v) for k, v in {**spoofs, **own}.items()]
    wait(lambda: all(p.matching_status.matching for p, _ in publishers),
         "every publisher sees the watcher")
    for publisher, payload in publishers:
        publisher.put(payload)
    tokens = [vehicle.app.liveliness().declare_token(key) for key in (
        "@zab/morph/gcv/bridge", "@zab/morph/lsv/link/ssv")]
    vehicle.app.declare_queryable("gcv/nav", lambda q: q.reply(q.key_expr, b"app: latched"))
    vehicle.fence()
    wait(lambda: set(own.items()) <= set(vehicle.heard), "the application's own keys")
    time.sleep(1.0)  # a refused declaration, were it let through, would be here by now
    assert [s for s in vehicle.heard if s[0] in spoofs] == []
    assert vehicle.tokens == []
    assert [r for r in vehicle.watcher.get("gcv/nav", timeout=2.0) if r.ok] == []

    vehicle.bridge.put("@zab/morph/lsv/delivery/command", b"bridge: delivered")
    vehicle.bridge.put("gcv/nav", b"bridge: decoded")
    bridge_token = vehicle.bridge.liveliness().declare_token("@zab/morph/lsv/link/gcv")
    wait(lambda: {("@zab/morph/lsv/delivery/command", b"bridge: delivered"),
                  ("gcv/nav", b"bridge: decoded")} <= set(vehicle.heard), "the bridge's puts")
    wait(lambda: ("@zab/morph/lsv/link/gcv", zenoh.SampleKind.PUT) in vehicle.tokens,
         "the bridge's link token")
    for token in (*tokens, bridge_token):
        token.undeclare()
