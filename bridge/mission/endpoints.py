"""Zenoh endpoints (``<protocol>/<address>[?<metadata>][#<config>]``) checked as Zenoh reads
them: the mission's ``zenoh.listen`` and ``zenoh.connect``, and the endpoint ``zab listen``
and ``zab put`` join. Zenoh itself says only "invalid port value", without the endpoint."""

from __future__ import annotations

__all__ = ["endpoint_problem", "same_socket", "shared_listens"]

ENDPOINT_EXAMPLE = "tcp/127.0.0.1:7447"
HOST_PORT = ("tcp", "udp", "tls", "quic", "ws")
"""Zenoh's protocols whose address is ``<host>:<port>``."""
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
"""Zenoh's protocols whose address is something else (a path, a device): left to Zenoh."""
TRANSPORT = {"tcp": "tcp", "tls": "tcp", "ws": "tcp", "udp": "udp", "quic": "udp"}
"""The socket each host:port protocol listens with (tls and ws over TCP, quic over UDP)."""
ANY_HOST = ("0.0.0.0", "[::]")
"""Hosts that mean every address of the machine."""


def _parts(endpoint: str) -> tuple[str, str]:
    """The protocol and the address (without metadata and configuration) of ``endpoint``."""
    protocol, _, address = endpoint.partition("/")
    return protocol, address.split("?", 1)[0].split("#", 1)[0]


def _host_port(address: str) -> tuple[str, str | None]:
    """A ``<host>:<port>`` address split (an IPv6 host in brackets); port None if none."""
    if address.startswith("["):  # an IPv6 address: [::1]:7447
        inside, _, rest = address.partition("]")
        return inside + "]", rest[1:] if rest.startswith(":") else None
    host, separator, port = address.rpartition(":")
    return (host, port) if separator else (address, None)


def endpoint_problem(endpoint: str, *, listen: bool = False) -> str | None:
    """What is wrong with a Zenoh ``endpoint``, in one line naming it and the form expected;
    None if nothing is. A ``listen`` endpoint may give port 0 (any free port)."""
    protocol, address = _parts(endpoint)
    why = None
    if "/" not in endpoint or not protocol or not address:
        why = "not <protocol>/<address>"
    elif protocol in OTHER_PROTOCOLS:
        return None
    elif protocol not in HOST_PORT:
        why = f"unknown protocol '{protocol}' (Zenoh's are {', '.join(HOST_PORT)}, " \
            f"{', '.join(OTHER_PROTOCOLS)})"
    else:
        host, port = _host_port(address)
        least = 0 if listen else 1
        if port is None:
            why = f"no port after the host '{address}' (<host>:<port>)"
        elif host in ("", "[]"):
            why = "no host before the port (<host>:<port>)"
        elif not (port.isascii() and port.isdigit()) or not least <= int(port) <= 65535:
            why = f"'{port}' is not a port ({least} to 65535)"
    if why is None:
        return None
    return f"invalid endpoint '{endpoint}': {why}; expected a Zenoh endpoint such as " \
        f"{ENDPOINT_EXAMPLE}"


def same_socket(a: str, b: str) -> bool:
    """Whether listening on endpoints ``a`` and ``b`` (valid) takes one socket of a machine:
    one transport (TCP for tcp, tls and ws; UDP for udp and quic), one port (not 0: any free
    one) and one host, or every host (0.0.0.0) beside any; one path for a Unix socket."""
    (pa, aa), (pb, ab) = _parts(a), _parts(b)
    if pa not in TRANSPORT or pb not in TRANSPORT:
        return pa == pb and aa == ab
    (ha, porta), (hb, portb) = _host_port(aa), _host_port(ab)
    return (TRANSPORT[pa] == TRANSPORT[pb] and porta is not None and portb is not None
            and int(porta) == int(portb) != 0
            and (ha.lower() == hb.lower() or ha in ANY_HOST or hb in ANY_HOST))


def shared_listens(listens: dict[str, list[str]]) -> list[str]:
    """Each node (of ``listens``: node → its listen endpoints) listening where an earlier one
    does, said: fine on machines of their own, but on one machine (``zab sim``, ``zab demo``)
    only the first could listen there."""
    out: list[str] = []
    earlier: list[tuple[str, str]] = []
    for name, endpoints in listens.items():
        for endpoint in endpoints:
            owner = next((n for n, e in earlier if same_socket(e, endpoint)), None)
            if owner is not None:
                out.append(f"node {name!r} listens on {endpoint}, where node {owner!r} does: "
                           "fine on machines of their own, but zab sim and zab demo run every "
                           "node on one machine, where only one can listen there")
        earlier += [(name, e) for e in endpoints]
    return out
