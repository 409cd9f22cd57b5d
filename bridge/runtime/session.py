"""Open a node's Zenoh session from the mission, safely (explicit endpoints, no multicast)."""

from __future__ import annotations

import contextlib
import json
import re
from typing import Any

import zenoh

from bridge.errors import SessionError
from bridge.mission.model import ZenohSettings
from bridge.ros2.attachment import from_bridge
from bridge.wire.proofs import SIGNATURE
from bridge.wire.sample_meta import APPLICATION_SEPARATOR

# Every sample a bridge publishes carries this attachment prefix; bridges never re-bridge it.
ORIGIN_PREFIX = b"zab/1 "


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """A Zenoh config listening and connecting only where the mission says.

    The default listen endpoint would be every interface; here it is none unless given.
    Multicast scouting is off unless the node's ``zenoh`` section turns it on. So is shared
    memory: Zenoh 1.x maps each local publisher's shared-memory pool (16 MB) into a subscriber
    it sends large samples to, and six applications flooding 1 MB puts on the bridge's inputs
    held ~100 MB in it that way, never given back (40 MB with it off); the samples a bridge
    takes are small. ``transport/link/rx/max_message_size`` stays Zenoh's (1 GiB): a limit
    keeps a huge put out (Zenoh reassembles a message whole before the bridge can refuse it),
    but Zenoh keeps the part of a refused message it reassembled, up to the limit, until the
    next long message on that link (a limit of 65 MB held 58 MB after a put of 100 MB), and no
    lower limit fits every bridge (pictures take up to 64 MB). A node's ``zenoh`` section can
    set one: 2 MB kept puts of 20-100 MB out, 3 MB over idle at most (see also
    :mod:`bridge.runtime.heap`).
    """
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    config.insert_json5("listen/endpoints", json.dumps(settings.listen))
    config.insert_json5("connect/endpoints", json.dumps(settings.connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/shared_memory/enabled", "false")
    for key, value in settings.passthrough().items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(settings: ZenohSettings, who: str = "zenoh") -> zenoh.Session:
    """A session with ``settings``; :class:`SessionError` (one line, ``who`` first) when Zenoh
    cannot open it: a listen port taken, a client's router unreachable, a bad endpoint."""
    try:
        return zenoh.open(zenoh_config(settings))
    except zenoh.ZError as exc:
        raise SessionError(f"{who}: {session_problem(str(exc), settings)}") from None


_SOURCE = re.compile(r"\s+at \S+\.rs:\d+\.?")  # "at /root/.cargo/.../tcp.rs:61." in ZError text
_BOUND = re.compile(r"bound to (\S+?): \[")
_CONNECT = re.compile(r"Unable to connect to any of")
_NOT_ENDPOINT = re.compile(r"Endpoints must be of the form [^:]*: ([^\"]*)")


def session_problem(text: str, settings: ZenohSettings) -> str:
    """What a ``zenoh.ZError`` from opening a session means, and what to do, in one line."""
    text = " ".join(_SOURCE.sub("", text).split())
    if not_endpoint := _NOT_ENDPOINT.search(text):  # (Zenoh's Json5Err, as it reads config)
        return (f"invalid endpoint '{not_endpoint.group(1)}': expected a Zenoh endpoint "
                "<protocol>/<host>:<port>, such as tcp/127.0.0.1:7447")
    bound = _BOUND.search(text)
    if bound and "in use" in text.lower():
        return (f"{bound.group(1)} is already in use (is another `zab run`, `zab sim`, "
                "`zab demo` or zenohd listening there?)")
    if bound:
        reason = text[bound.end():].strip(" []")
        return f"cannot listen on {bound.group(1)}: {reason}"
    if _CONNECT.search(text):
        where = " ".join(settings.connect) or "(no connect endpoint)"
        return (f"no Zenoh router answers at {where} (start the router, e.g. zenohd -c "
                "deploy/zenoh/..., or fix zenoh.connect)")
    where = "; ".join(f"{side} {' '.join(endpoints)}" for side, endpoints in
                      (("listen", settings.listen), ("connect", settings.connect)) if endpoints)
    return f"cannot open the Zenoh session{f' ({where})' if where else ''}: {text}"


def close_quietly(session: Any) -> None:
    """Close a session; Zenoh may raise if a link is being torn down at the same moment."""
    with contextlib.suppress(Exception):
        session.close()


def origin_tag(mission: str, node: str) -> bytes:
    return ORIGIN_PREFIX + f"{mission}/{node}".encode()


def marked(origin: bytes, application: bytes | None) -> bytes:
    """The bridge's attachment (``origin``) with the sending application's after it, where a
    channel carries it: ``zab/1 <mission>/<node>`` NUL ``<the application's bytes>``."""
    return origin + APPLICATION_SEPARATOR + application if application else origin


def origin_of(attachment: bytes) -> bytes:
    """A bridge's attachment without its signature (:mod:`bridge.wire.proofs`) and the
    application's attachment it carries, if any."""
    return attachment.partition(SIGNATURE)[0].partition(APPLICATION_SEPARATOR)[0]


def application_of(attachment: bytes) -> bytes | None:
    """The sending application's attachment: inside a bridge's (:func:`marked`), or all of
    an application's own; None if there is none."""
    if not attachment.startswith(ORIGIN_PREFIX):
        return attachment or None
    return attachment.partition(SIGNATURE)[0].partition(APPLICATION_SEPARATOR)[2] or None


def is_bridged(sample: zenoh.Sample) -> bool:
    """True when a bridge published this sample (loop safety): its origin tag, or a ROS 2
    attachment naming a bridge publisher (see :mod:`bridge.ros2.attachment`)."""
    attachment = sample.attachment
    return attachment is not None and bridged_attachment(attachment.to_bytes())


def bridged_attachment(data: bytes) -> bool:
    """:func:`is_bridged`, given the sample's attachment bytes."""
    return data.startswith(ORIGIN_PREFIX) or from_bridge(data)
