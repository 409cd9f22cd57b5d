"""The deploy configs over real mutual TLS on loopback: a throwaway fleet CA made with the
`openssl` CLI (the commands of docs/deploy.md), the configs loaded from `deploy/zenoh/` with only
their endpoints and certificate paths rewritten, and real zenoh sessions through the router."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, suppress
from pathlib import Path

import pytest
import zenoh

from tests.conftest import REPO, free_port
from tests.deploy.test_deploy_kit import _on_loopback

ZENOH = REPO / "deploy" / "zenoh"
OPENSSL = shutil.which("openssl")
DEADLINE = 20.0  # seconds: generous, for a loaded 2-core CI machine
QUIET = 4.0  # seconds a refused node keeps trying while we watch that nothing gets through
EC = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
SERVER_EXT = "subjectAltName = IP:127.0.0.1, DNS:localhost\nextendedKeyUsage = serverAuth\n"
CLIENT_EXT = "extendedKeyUsage = clientAuth\n"

pytestmark = pytest.mark.skipif(OPENSSL is None, reason="the openssl CLI is not installed")

Sample = tuple[str, bytes]
Opener = Callable[[zenoh.Config], zenoh.Session]


def _openssl(directory: Path, *args: str) -> None:
    assert OPENSSL is not None
    subprocess.run([OPENSSL, *args], cwd=directory, check=True, capture_output=True, timeout=60)


def _make_ca(directory: Path, name: str, common_name: str) -> None:
    _openssl(directory, "req", "-x509", "-new", *EC, "-days", "3650", "-subj", f"/CN={common_name}",
             "-keyout", f"{name}.key", "-out", f"{name}.pem",
             "-addext", "basicConstraints = critical, CA:TRUE",
             "-addext", "keyUsage = critical, keyCertSign, cRLSign")


def _make_cert(directory: Path, ca: str, file: str, common_name: str, ext: str) -> None:
    _openssl(directory, "req", "-new", *EC, "-subj", f"/CN={common_name}",
             "-keyout", f"{file}.key", "-out", f"{file}.csr")
    _openssl(directory, "x509", "-req", "-in", f"{file}.csr", "-CA", f"{ca}.pem",
             "-CAkey", f"{ca}.key", "-CAcreateserial", "-days", "825", "-out", f"{file}.pem",
             "-extfile", ext)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fleet CA with the router's and clients' certificates, and a foreign CA's certificate
    that claims to be an operator console."""
    directory = tmp_path_factory.mktemp("tls")
    (directory / "server.ext").write_text(SERVER_EXT)
    (directory / "client.ext").write_text(CLIENT_EXT)
    _make_ca(directory, "ca", "zab-fleet-ca")
    _make_ca(directory, "other-ca", "other-fleet-ca")
    _make_cert(directory, "ca", "surface-router", "surface-router", "server.ext")
    for name in ("operator-console", "viewer", "lsv"):
        _make_cert(directory, "ca", name, name, "client.ext")
    _make_cert(directory, "other-ca", "intruder", "operator-console", "client.ext")
    return directory


def _load(name: str) -> zenoh.Config:
    return zenoh.Config.from_file(str(ZENOH / f"{name}.json5"))


def _set(config: zenoh.Config, key: str, value: object) -> None:
    config.insert_json5(key, json.dumps(value))


def _tls(config: zenoh.Config, **paths: Path | None) -> None:
    """Point the config's TLS files at the generated ones (None: no such file)."""
    for key, path in paths.items():
        _set(config, f"transport/link/tls/{key}", None if path is None else str(path))


def _connect_with(config: zenoh.Config, pki: Path, cert: str | None) -> zenoh.Config:
    """The connecting side's TLS files: the fleet CA and ``cert`` (None: no certificate)."""
    _tls(config, root_ca_certificate=pki / "ca.pem",
         connect_certificate=None if cert is None else pki / f"{cert}.pem",
         connect_private_key=None if cert is None else pki / f"{cert}.key")
    return config


def _router_config(pki: Path, tcp_port: int, tls_port: int) -> zenoh.Config:
    """surface-router.json5: loopback TCP for the bridge and TLS for everyone else."""
    config = _on_loopback("surface-router",
                          [f"tcp/127.0.0.1:{tcp_port}", f"tls/127.0.0.1:{tls_port}"])
    _tls(config, root_ca_certificate=pki / "ca.pem",
         listen_certificate=pki / "surface-router.pem",
         listen_private_key=pki / "surface-router.key")
    return config


def _client_config(pki: Path, tls_port: int, cert: str | None) -> zenoh.Config:
    """surface-client.json5 with the certificate ``cert`` (None: no certificate at all)."""
    config = _on_loopback("surface-client", [], [f"tls/127.0.0.1:{tls_port}"])
    return _connect_with(config, pki, cert)


def _vehicle_config(pki: Path, listen_port: int, tls_port: int, cert: str | None) -> zenoh.Config:
    """vehicle.json5: loopback for the vehicle's apps, TLS to the surface router."""
    config = _on_loopback("vehicle", [f"tcp/127.0.0.1:{listen_port}"],
                          [f"tls/127.0.0.1:{tls_port}"])
    return _connect_with(config, pki, cert)


def _local_config(port: int) -> zenoh.Config:
    """A bridge or application on the same machine as a router: plain TCP on loopback."""
    config = zenoh.Config()
    _set(config, "mode", "client")
    _set(config, "connect/endpoints", [f"tcp/127.0.0.1:{port}"])
    _set(config, "listen/endpoints", [])
    _set(config, "scouting/multicast/enabled", False)
    return config


def _close(session: zenoh.Session) -> None:
    with suppress(zenoh.ZError):  # a close racing a link teardown may time out
        session.close()


@pytest.fixture
def sessions() -> Iterator[Opener]:
    """Opens sessions and closes every one of them, last opened first."""
    with ExitStack() as stack:
        def open_session(config: zenoh.Config) -> zenoh.Session:
            session = zenoh.open(config)
            stack.callback(_close, session)
            return session
        yield open_session


def _collect(session: zenoh.Session, key: str) -> list[Sample]:
    got: list[Sample] = []
    session.declare_subscriber(key, lambda s: got.append((str(s.key_expr),
                                                          s.payload.to_bytes())))
    return got


def _wait(condition: Callable[[], bool], what: str, seconds: float = DEADLINE) -> None:
    end = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < end, f"not within {seconds} s: {what}"
        time.sleep(0.05)


def _put_until_received(session: zenoh.Session, key: str, payload: bytes,
                        got: list[Sample]) -> None:
    """Put until the subscriber has it (declarations travel asynchronously)."""
    end = time.monotonic() + DEADLINE
    while (key, payload) not in got:
        assert time.monotonic() < end, f"{key}={payload!r} never arrived; got {got}"
        session.put(key, payload)
        time.sleep(0.1)


def _tls_links(session: zenoh.Session) -> dict[str | None, str]:
    """The session's TLS links: the other side's certificate name -> its locator."""
    return {link.auth_identifier: link.dst for link in session.info.links()
            if link.dst.startswith("tls/")}


def test_every_tls_config_asks_for_mutual_tls() -> None:
    """Zenoh only sends a client certificate with `enable_mtls: true` on the connecting side."""
    for name in ("surface-router", "surface-client", "vehicle"):
        tls = json.loads(_load(name).get_json("transport/link/tls"))
        assert tls["enable_mtls"] is True, name
        assert tls["root_ca_certificate"], name
    for name in ("surface-client", "vehicle"):
        tls = json.loads(_load(name).get_json("transport/link/tls"))
        assert tls["connect_certificate"] and tls["connect_private_key"], name
        assert tls["verify_name_on_connect"] is True, name


def test_the_generated_certificates_are_what_the_configs_expect(pki: Path) -> None:
    def text(name: str) -> str:
        return subprocess.run([str(OPENSSL), "x509", "-in", str(pki / f"{name}.pem"), "-noout",
                               "-subject", "-ext", "subjectAltName"], capture_output=True,
                              text=True, check=True, timeout=60).stdout
    assert "IP Address:127.0.0.1" in text("surface-router")
    assert "DNS:localhost" in text("surface-router")
    assert "CN = lsv" in text("lsv") and "CN = operator-console" in text("intruder")
    verify = [str(OPENSSL), "verify", "-CAfile", str(pki / "ca.pem")]
    ok = subprocess.run([*verify, str(pki / "lsv.pem")], capture_output=True, timeout=60)
    foreign = subprocess.run([*verify, str(pki / "intruder.pem")], capture_output=True,
                             timeout=60)
    assert ok.returncode == 0 and foreign.returncode != 0


def test_fleet_clients_round_trip_through_the_router(pki: Path, sessions: Opener) -> None:
    """An operator console publishes, a viewer subscribes, both over mutual TLS; each side of
    each link has checked the other's certificate name."""
    tls_port = free_port()
    router = sessions(_router_config(pki, free_port(), tls_port))
    operator = sessions(_client_config(pki, tls_port, "operator-console"))
    viewer = sessions(_client_config(pki, tls_port, "viewer"))
    got = _collect(viewer, "command")
    _put_until_received(operator, "command", b"hold position", got)
    assert got[0] == ("command", b"hold position")
    assert list(_tls_links(operator)) == ["surface-router"]
    _wait(lambda: {"operator-console", "viewer"} <= set(_tls_links(router)),
          "the router lists both clients by certificate name")


@pytest.mark.parametrize("cert", ["intruder", None], ids=["other-ca", "no-certificate"])
def test_router_refuses_a_client_without_a_fleet_certificate(pki: Path, sessions: Opener,
                                                             cert: str | None) -> None:
    """A foreign CA's certificate (even one named operator-console) or none: no session."""
    tls_port = free_port()
    router = sessions(_router_config(pki, free_port(), tls_port))
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        sessions(_client_config(pki, tls_port, cert))
    assert _tls_links(router) == {}
    fleet = sessions(_client_config(pki, tls_port, "viewer"))  # the listener is still fine
    assert fleet.info.routers_zid() == [router.info.zid()]


@pytest.mark.parametrize("cert", ["intruder", None], ids=["other-ca", "no-certificate"])
def test_vehicle_without_a_fleet_certificate_gets_nothing_through(pki: Path, sessions: Opener,
                                                                  cert: str | None) -> None:
    """The vehicle router keeps retrying and its apps keep publishing, but nothing reaches the
    surface, and the vehicle has no router peer."""
    tcp_port, tls_port, vehicle_port = free_port(), free_port(), free_port()
    surface = sessions(_router_config(pki, tcp_port, tls_port))
    bridge = sessions(_local_config(tcp_port))
    at_surface = _collect(bridge, "**")
    vehicle = sessions(_vehicle_config(pki, vehicle_port, tls_port, cert))
    app = sessions(_local_config(vehicle_port))
    on_vehicle = _collect(vehicle, "lsv/**")
    end = time.monotonic() + QUIET
    while time.monotonic() < end:  # several connection attempts (retry from 1 s, doubling)
        app.put("lsv/nav", b"fix")
        time.sleep(0.2)
    _wait(lambda: len(on_vehicle) >= 5, "the vehicle's own subscriber hears its app")
    assert at_surface == []
    assert vehicle.info.routers_zid() == []
    assert _tls_links(surface) == {}
    operator = sessions(_client_config(pki, tls_port, "operator-console"))
    _put_until_received(operator, "command", b"still listening", at_surface)


def test_surfaced_vehicle_joins_with_its_certificate_and_routes(pki: Path,
                                                                sessions: Opener) -> None:
    """vehicle.json5 with the `lsv` certificate: the vehicle's navigation reaches a viewer at
    the surface and an operator's command reaches the vehicle's applications."""
    tls_port, vehicle_port = free_port(), free_port()
    surface = sessions(_router_config(pki, free_port(), tls_port))
    viewer = sessions(_client_config(pki, tls_port, "viewer"))
    operator = sessions(_client_config(pki, tls_port, "operator-console"))
    vehicle = sessions(_vehicle_config(pki, vehicle_port, tls_port, "lsv"))
    app = sessions(_local_config(vehicle_port))
    _wait(lambda: vehicle.info.routers_zid() == [surface.info.zid()],
          "the vehicle router joins the surface router")
    assert list(_tls_links(vehicle)) == ["surface-router"]
    assert "lsv" in _tls_links(surface)
    at_surface = _collect(viewer, "lsv/**")
    _put_until_received(app, "lsv/nav", b"fix", at_surface)
    on_vehicle = _collect(app, "command")
    _put_until_received(operator, "command", b"come home", on_vehicle)


def test_router_acl_follows_certificate_common_names(pki: Path, sessions: Opener) -> None:
    """The router's rules with TLS identities: only `operator-console` publishes commands, the
    `lsv` vehicle only under `lsv/**`, a viewer nothing; the local bridge everything.

    One change to the config's ACL: its `local` subject is "interface lo", which on a test
    machine every TLS link is on too; here it is also limited to TCP links, so that the TLS
    clients are judged by their certificates alone, as on the station's WiFi."""
    tcp_port, tls_port, vehicle_port = free_port(), free_port(), free_port()
    config = _router_config(pki, tcp_port, tls_port)
    subjects = json.loads(config.get_json("access_control/subjects"))
    [local] = [s for s in subjects if s["id"] == "local"]
    assert local["interfaces"] == ["lo"]
    local["link_protocols"] = ["tcp"]
    _set(config, "access_control/subjects", subjects)
    surface = sessions(config)
    bridge = sessions(_local_config(tcp_port))
    heard = bridge.declare_subscriber("**", zenoh.handlers.FifoChannel(1000))
    bridge.declare_queryable("fence/**", lambda q: q.reply(q.key_expr, b"ok"))
    operator = sessions(_client_config(pki, tls_port, "operator-console"))
    viewer = sessions(_client_config(pki, tls_port, "viewer"))
    sessions(_vehicle_config(pki, vehicle_port, tls_port, "lsv"))
    app = sessions(_local_config(vehicle_port))
    _wait(lambda: "lsv" in _tls_links(surface), "the vehicle joins")

    senders = [("operator", operator, ["lsv/nav", "command"]),
               ("viewer", viewer, ["command", "viewer/status"]),
               ("lsv", app, ["command", "gcv/nav", "ssv/status", "lsv/nav"])]
    publishers = [(f"{key} from {name}", session.declare_publisher(key))
                  for name, session, keys in senders for key in keys]
    _wait(lambda: all(p.matching_status.matching for _, p in publishers),
          "every publisher sees the bridge's subscriber")
    for payload, publisher in publishers:
        publisher.put(payload)
    # Each sender's puts leave in order on its one link, so once its last allowed put (or the
    # reply to a query behind them) is at the bridge, any earlier put the ACL let through is too.
    allowed = [("command", b"command from operator"), ("lsv/nav", b"lsv/nav from lsv")]
    got: list[Sample] = []

    def drain() -> bool:
        while (sample := heard.try_recv()) is not None:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))
        return set(allowed) <= set(got)

    _wait(drain, "the allowed puts arrive")
    _wait(lambda: any(r.ok for r in viewer.get("fence/viewer", timeout=5.0)),
          "a query from the viewer is answered by the bridge")
    drain()
    assert sorted(got) == allowed
    on_vehicle = _collect(app, "command")  # the local subject keeps its rights
    _put_until_received(bridge, "command", b"from the bridge", on_vehicle)
