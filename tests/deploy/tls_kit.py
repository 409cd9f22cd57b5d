"""A throwaway fleet PKI made with the `openssl` CLI (the commands of docs/deploy.md) and the
deploy configs of `deploy/zenoh/` loaded with only their endpoints and certificate paths
rewritten, for real Zenoh sessions over mutual TLS on loopback (tests/deploy/test_tls.py,
tests/deploy/test_acl.py)."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path

import zenoh

from bridge.mission.model import ZenohSettings
from bridge.runtime.session import zenoh_config
from tests.conftest import REPO
from tests.deploy.test_deploy_kit import _on_loopback

ZENOH = REPO / "deploy" / "zenoh"
OPENSSL = shutil.which("openssl")
DEADLINE = 20.0  # seconds: generous, for a loaded 2-core CI machine
QUIET = 4.0  # seconds a refused node keeps trying while we watch that nothing gets through
EC = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
SERVER_EXT = "subjectAltName = IP:127.0.0.1, DNS:localhost\nextendedKeyUsage = serverAuth\n"
CLIENT_EXT = "extendedKeyUsage = clientAuth\n"
CLIENTS = ("operator-console", "viewer", "lsv", "gcv", "surface-bridge")

Sample = tuple[str, bytes]
Opener = Callable[[zenoh.Config], zenoh.Session]


def _openssl(directory: Path, *args: str) -> None:
    assert OPENSSL is not None
    subprocess.run([OPENSSL, *args], cwd=directory, check=True, capture_output=True, timeout=60)


def make_ca(directory: Path, name: str, common_name: str) -> None:
    _openssl(directory, "req", "-x509", "-new", *EC, "-days", "3650", "-subj", f"/CN={common_name}",
             "-keyout", f"{name}.key", "-out", f"{name}.pem",
             "-addext", "basicConstraints = critical, CA:TRUE",
             "-addext", "keyUsage = critical, keyCertSign, cRLSign")


def make_cert(directory: Path, ca: str, file: str, common_name: str, ext: str) -> None:
    _openssl(directory, "req", "-new", *EC, "-subj", f"/CN={common_name}",
             "-keyout", f"{file}.key", "-out", f"{file}.csr")
    _openssl(directory, "x509", "-req", "-in", f"{file}.csr", "-CA", f"{ca}.pem",
             "-CAkey", f"{ca}.key", "-CAcreateserial", "-days", "825", "-out", f"{file}.pem",
             "-extfile", ext)


def make_pki(directory: Path) -> Path:
    """A fleet CA with the router's and clients' certificates, and a foreign CA's certificate
    that claims to be an operator console (`intruder`)."""
    (directory / "server.ext").write_text(SERVER_EXT)
    (directory / "client.ext").write_text(CLIENT_EXT)
    make_ca(directory, "ca", "zab-fleet-ca")
    make_ca(directory, "other-ca", "other-fleet-ca")
    make_cert(directory, "ca", "surface-router", "surface-router", "server.ext")
    for name in CLIENTS:
        make_cert(directory, "ca", name, name, "client.ext")
    make_cert(directory, "other-ca", "intruder", "operator-console", "client.ext")
    return directory


def load(name: str) -> zenoh.Config:
    return zenoh.Config.from_file(str(ZENOH / f"{name}.json5"))


def set_json(config: zenoh.Config, key: str, value: object) -> None:
    config.insert_json5(key, json.dumps(value))


def tls_files(config: zenoh.Config, **paths: Path | None) -> None:
    """Point the config's TLS files at the generated ones (None: no such file)."""
    for key, path in paths.items():
        set_json(config, f"transport/link/tls/{key}", None if path is None else str(path))


def connect_with(config: zenoh.Config, pki: Path, cert: str | None) -> zenoh.Config:
    """The connecting side's TLS files: the fleet CA and ``cert`` (None: no certificate)."""
    tls_files(config, root_ca_certificate=pki / "ca.pem",
              connect_certificate=None if cert is None else pki / f"{cert}.pem",
              connect_private_key=None if cert is None else pki / f"{cert}.key")
    return config


def router_config(pki: Path, tcp_port: int, tls_port: int,
                  bridge_port: int | None = None) -> zenoh.Config:
    """surface-router.json5: loopback TCP for the station's tools, TLS for everyone else (and,
    with ``bridge_port``, the surface bridge's own loopback TLS listener)."""
    listen = [f"tcp/127.0.0.1:{tcp_port}", f"tls/127.0.0.1:{tls_port}"]
    if bridge_port is not None:
        listen.append(f"tls/127.0.0.1:{bridge_port}")
    config = _on_loopback("surface-router", listen)
    tls_files(config, root_ca_certificate=pki / "ca.pem",
              listen_certificate=pki / "surface-router.pem",
              listen_private_key=pki / "surface-router.key")
    return config


def client_config(pki: Path, tls_port: int, cert: str | None) -> zenoh.Config:
    """surface-client.json5 with the certificate ``cert`` (None: no certificate at all)."""
    config = _on_loopback("surface-client", [], [f"tls/127.0.0.1:{tls_port}"])
    return connect_with(config, pki, cert)


def vehicle_config(pki: Path, listen_port: int, tls_port: int, cert: str | None,
                   bridge_socket: Path | None = None) -> zenoh.Config:
    """vehicle.json5: loopback for the vehicle's apps (and, with ``bridge_socket``, the Unix
    socket of its bridge), TLS to the surface router."""
    listen = [f"tcp/127.0.0.1:{listen_port}"]
    if bridge_socket is not None:
        listen.append(f"unixsock-stream/{bridge_socket}")
    config = _on_loopback("vehicle", listen, [f"tls/127.0.0.1:{tls_port}"])
    return connect_with(config, pki, cert)


def bridge_socket_config(socket: Path) -> zenoh.Config:
    """A vehicle's bridge joining its router over the router's Unix socket."""
    config = local_config(0)
    set_json(config, "connect/endpoints", [f"unixsock-stream/{socket}"])
    return config


def surface_bridge_settings(pki: Path, bridge_port: int) -> ZenohSettings:
    """`nodes.ssv.zenoh` of a deployed mission (docs/deploy.md), with the generated files."""
    return ZenohSettings.model_validate({
        "mode": "client",
        "connect": [f"tls/127.0.0.1:{bridge_port}"],
        "transport/link/tls/root_ca_certificate": str(pki / "ca.pem"),
        "transport/link/tls/connect_certificate": str(pki / "surface-bridge.pem"),
        "transport/link/tls/connect_private_key": str(pki / "surface-bridge.key"),
        "transport/link/tls/enable_mtls": True,
        "transport/link/tls/verify_name_on_connect": True,
    })


def surface_bridge_config(pki: Path, bridge_port: int) -> zenoh.Config:
    """The Zenoh config `zab run --node ssv` opens with those settings."""
    return zenoh_config(surface_bridge_settings(pki, bridge_port))


def local_config(port: int) -> zenoh.Config:
    """A bridge or tool on the same machine as a router: plain TCP on loopback."""
    config = zenoh.Config()
    set_json(config, "mode", "client")
    set_json(config, "connect/endpoints", [f"tcp/127.0.0.1:{port}"])
    set_json(config, "listen/endpoints", [])
    set_json(config, "scouting/multicast/enabled", False)
    return config


def close(session: zenoh.Session) -> None:
    with suppress(zenoh.ZError):  # a close racing a link teardown may time out
        session.close()


def collect(session: zenoh.Session, key: str) -> list[Sample]:
    got: list[Sample] = []
    session.declare_subscriber(key, lambda s: got.append((str(s.key_expr),
                                                          s.payload.to_bytes())))
    return got


def wait(condition: Callable[[], bool], what: str, seconds: float = DEADLINE) -> None:
    end = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < end, f"not within {seconds} s: {what}"
        time.sleep(0.05)


def put_until_received(session: zenoh.Session, key: str, payload: bytes,
                       got: list[Sample]) -> None:
    """Put until the subscriber has it (declarations travel asynchronously)."""
    end = time.monotonic() + DEADLINE
    while (key, payload) not in got:
        assert time.monotonic() < end, f"{key}={payload!r} never arrived; got {got}"
        session.put(key, payload)
        time.sleep(0.1)


def tls_links(session: zenoh.Session) -> dict[str | None, str]:
    """The session's TLS links: the other side's certificate name -> its locator."""
    return {link.auth_identifier: link.dst for link in session.info.links()
            if link.dst.startswith("tls/")}
