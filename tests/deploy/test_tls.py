"""The deploy configs over real mutual TLS on loopback: a throwaway fleet CA made with the
`openssl` CLI (the commands of docs/deploy.md), the configs loaded from `deploy/zenoh/` with only
their endpoints and certificate paths rewritten, and real zenoh sessions through the router.
Who may do what once connected: tests/deploy/test_acl.py."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from tests.conftest import free_port
from tests.deploy.tls_kit import (
    OPENSSL,
    QUIET,
    Opener,
    client_config,
    collect,
    load,
    local_config,
    put_until_received,
    router_config,
    tls_links,
    vehicle_config,
    wait,
)

pytestmark = pytest.mark.skipif(OPENSSL is None, reason="the openssl CLI is not installed")


def test_every_tls_config_asks_for_mutual_tls() -> None:
    """Zenoh only sends a client certificate with `enable_mtls: true` on the connecting side."""
    for name in ("surface-router", "surface-client", "vehicle"):
        tls = json.loads(load(name).get_json("transport/link/tls"))
        assert tls["enable_mtls"] is True, name
        assert tls["root_ca_certificate"], name
    for name in ("surface-client", "vehicle"):
        tls = json.loads(load(name).get_json("transport/link/tls"))
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
    router = sessions(router_config(pki, free_port(), tls_port))
    operator = sessions(client_config(pki, tls_port, "operator-console"))
    viewer = sessions(client_config(pki, tls_port, "viewer"))
    got = collect(viewer, "command")
    put_until_received(operator, "command", b"hold position", got)
    assert got[0] == ("command", b"hold position")
    assert list(tls_links(operator)) == ["surface-router"]
    wait(lambda: {"operator-console", "viewer"} <= set(tls_links(router)),
          "the router lists both clients by certificate name")


@pytest.mark.parametrize("cert", ["intruder", None], ids=["other-ca", "no-certificate"])
def test_router_refuses_a_client_without_a_fleet_certificate(pki: Path, sessions: Opener,
                                                             cert: str | None) -> None:
    """A foreign CA's certificate (even one named operator-console) or none: no session."""
    tls_port = free_port()
    router = sessions(router_config(pki, free_port(), tls_port))
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        sessions(client_config(pki, tls_port, cert))
    assert tls_links(router) == {}
    fleet = sessions(client_config(pki, tls_port, "viewer"))  # the listener is still fine
    assert fleet.info.routers_zid() == [router.info.zid()]


@pytest.mark.parametrize("cert", ["intruder", None], ids=["other-ca", "no-certificate"])
def test_vehicle_without_a_fleet_certificate_gets_nothing_through(pki: Path, sessions: Opener,
                                                                  cert: str | None) -> None:
    """The vehicle router keeps retrying and its apps keep publishing, but nothing reaches the
    surface, and the vehicle has no router peer."""
    tcp_port, tls_port, vehicle_port = free_port(), free_port(), free_port()
    surface = sessions(router_config(pki, tcp_port, tls_port))
    bridge = sessions(local_config(tcp_port))
    at_surface = collect(bridge, "**")
    vehicle = sessions(vehicle_config(pki, vehicle_port, tls_port, cert))
    app = sessions(local_config(vehicle_port))
    on_vehicle = collect(vehicle, "lsv/**")
    end = time.monotonic() + QUIET
    while time.monotonic() < end:  # several connection attempts (retry from 1 s, doubling)
        app.put("lsv/nav", b"fix")
        time.sleep(0.2)
    wait(lambda: len(on_vehicle) >= 5, "the vehicle's own subscriber hears its app")
    assert at_surface == []
    assert vehicle.info.routers_zid() == []
    assert tls_links(surface) == {}
    operator = sessions(client_config(pki, tls_port, "operator-console"))
    put_until_received(operator, "command", b"still listening", at_surface)


def test_surfaced_vehicle_joins_with_its_certificate_and_routes(pki: Path,
                                                                sessions: Opener) -> None:
    """vehicle.json5 with the `lsv` certificate: the vehicle's navigation reaches a viewer at
    the surface and an operator's command reaches the vehicle's applications."""
    tls_port, vehicle_port = free_port(), free_port()
    surface = sessions(router_config(pki, free_port(), tls_port))
    viewer = sessions(client_config(pki, tls_port, "viewer"))
    operator = sessions(client_config(pki, tls_port, "operator-console"))
    vehicle = sessions(vehicle_config(pki, vehicle_port, tls_port, "lsv"))
    app = sessions(local_config(vehicle_port))
    wait(lambda: vehicle.info.routers_zid() == [surface.info.zid()],
          "the vehicle router joins the surface router")
    assert list(tls_links(vehicle)) == ["surface-router"]
    assert "lsv" in tls_links(surface)
    at_surface = collect(viewer, "lsv/**")
    put_until_received(app, "lsv/nav", b"fix", at_surface)
    on_vehicle = collect(app, "command")
    put_until_received(operator, "command", b"come home", on_vehicle)
