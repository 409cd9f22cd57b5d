"""A node's Zenoh endpoints are checked when the mission loads, with their place: `zab check`
passed `listen: [127.0.0.1:28602]` (no protocol), port 99999 and two nodes listening on one
port, which `zab run` then refused as "invalid endpoint" or "invalid port value" without
naming it, and `zab sim` as "already in use"."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import MissionError
from bridge.mission.model import ZenohSettings
from bridge.report.check import check_mission
from bridge.runtime.session import session_problem

MISSION = """\
mission: ends
nodes:
  a: {address: 1, zenoh: {listen: [A]}}
  b: {address: 2, zenoh: {listen: [B], connect: [C]}}
channels:
  - name: pose
    from: a
    to: b
    elements:
      - {in: pose, out: a/pose, fields: [{field: x, bits: 8, min: 0, max: 10}]}
"""


def mission(a: str = "tcp/127.0.0.1:7001", b: str = "tcp/127.0.0.1:7002",
            c: str = "tcp/127.0.0.1:7001") -> str:
    return MISSION.replace("[A]", f"['{a}']").replace("[B]", f"['{b}']").replace(
        "[C]", f"['{c}']")


def refused(text: str) -> str:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return str(info.value)


@pytest.mark.parametrize(("ends", "line", "path", "why"), [
    ({"b": "127.0.0.1:28602"}, 4, "nodes.b.zenoh.listen[0]",
     "invalid endpoint '127.0.0.1:28602': not <protocol>/<address>"),
    ({"b": "tcp/127.0.0.1:99999"}, 4, "nodes.b.zenoh.listen[0]",
     "'99999' is not a port (0 to 65535)"),
    ({"a": "tcp/127.0.0.1"}, 3, "nodes.a.zenoh.listen[0]", "no port after the host"),
    ({"a": "tcpp/127.0.0.1:7001"}, 3, "nodes.a.zenoh.listen[0]", "unknown protocol 'tcpp'"),
    ({"c": "tcp/127.0.0.1:0"}, 4, "nodes.b.zenoh.connect[0]", "'0' is not a port (1 to 65535)"),
], ids=["no-protocol", "port-99999", "no-port", "protocol", "connect-port-0"])
def test_an_endpoint_zenoh_would_refuse_is_refused_with_its_place(
        ends: dict[str, str], line: int, path: str, why: str) -> None:
    first = refused(mission(**ends)).splitlines()[0]
    assert first.startswith(f"m.yaml:{line}:") and f": {path}: " in first, first
    assert why in first, first


@pytest.mark.parametrize("ends", [
    {"a": "tcp/127.0.0.1:0", "b": "tcp/127.0.0.1:0"},  # any free port, each its own
    {"a": "tcp/127.0.0.1:7001", "b": "udp/127.0.0.1:7001"},  # TCP and UDP: two sockets
    {"a": "tcp/127.0.0.1:7001", "b": "tcp/127.0.0.2:7001"},
    {"a": "tcp/[::1]:7001#iface=lo", "b": "quic/[::1]:7001?rel=1"},
    {"a": "unixsock-stream//tmp/a.sock", "b": "unixsock-stream//tmp/b.sock"},
])
def test_endpoints_zenoh_takes_load(ends: dict[str, str]) -> None:
    parse_mission(mission(**ends), "m.yaml")


def test_same_socket_is_one_machine_s_socket() -> None:
    from bridge.mission.endpoints import same_socket

    assert same_socket("tls/127.0.0.1:7447", "tcp/127.0.0.1:7447")
    assert same_socket("udp/[::]:7447", "quic/[::1]:7447")
    assert same_socket("unixsock-stream//tmp/z.sock", "unixsock-stream//tmp/z.sock")
    assert not same_socket("udp/127.0.0.1:7447", "tcp/127.0.0.1:7447")
    assert not same_socket("tcp/127.0.0.1:07447", "tcp/127.0.0.1:7448")


def test_zab_check_exits_2_naming_the_endpoint(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(mission(b="tcp/127.0.0.1:99999"))
    result = CliRunner().invoke(app, ["check", str(path)])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "Traceback" not in said, said
    assert f"{path}:4:" in said and "invalid endpoint 'tcp/127.0.0.1:99999'" in said, said
    as_json = CliRunner().invoke(app, ["check", str(path), "--json"])
    assert as_json.exit_code == 2 and "nodes.b.zenoh.listen[0]" in as_json.output


def test_a_refusal_zenoh_gives_without_the_endpoint_names_it() -> None:
    """What the model cannot tell (a host nothing resolves): Zenoh's reason said with the
    session's endpoints."""
    settings = ZenohSettings(listen=["tcp/nohost.invalid:7001"], connect=["tcp/10.0.0.9:7002"])
    assert session_problem("failed to lookup address information: Name or service not known "
                           "at /root/.cargo/x/lib.rs:62.", settings) == (
        "cannot open the Zenoh session (listen tcp/nohost.invalid:7001; connect "
        "tcp/10.0.0.9:7002): failed to lookup address information: Name or service not known")


def test_the_listen_and_put_endpoint_check_is_the_mission_s() -> None:
    """`zab listen`/`zab put` join a connect endpoint: port 0 is none."""
    from bridge.mission.endpoints import endpoint_problem

    assert endpoint_problem("tcp/127.0.0.1:0") is not None
    assert endpoint_problem("tcp/127.0.0.1:0", listen=True) is None
    assert endpoint_problem("tcp/127.0.0.1:٧٤٤٧") is not None  # (digits, but not ASCII)


@pytest.mark.parametrize(("ends", "said"), [
    ({"b": "tcp/127.0.0.1:7001"}, "node 'b' listens on tcp/127.0.0.1:7001, where node 'a' does"),
    ({"b": "ws/localhost:7001", "a": "tcp/LOCALHOST:7001"},
     "node 'b' listens on ws/localhost:7001, where node 'a' does"),  # (ws: over TCP)
    ({"a": "tcp/0.0.0.0:7001", "b": "tcp/127.0.0.1:7001"},
     "where node 'a' does"),  # (every address, that one too)
], ids=["same-listen", "ws-over-tcp", "any-host"])
def test_nodes_listening_on_one_port_load_and_check_warns(ends: dict[str, str], said: str
                                                          ) -> None:
    """Each vehicle its own machine may listen on the same port; only zab sim and zab demo,
    which run every node on one machine, cannot: a warning, not an error."""
    report = check_mission(parse_mission(mission(**ends), "m.yaml"))
    assert [w for w in report.warnings if said in w and "zab sim" in w], report.warnings
