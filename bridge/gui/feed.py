"""The GUI's Zenoh session (asyncio adapter): samples to the event loop, commands out.

An ordinary Zenoh client of one node (the surface vehicle on its WiFi): explicit endpoints,
no listening, multicast scouting off. Zenoh callbacks run on Zenoh's threads; they copy the
sample and hand it to the loop with ``call_soon_threadsafe``, so nothing here blocks Zenoh.
Until the node answers, the session is retried every :data:`RETRY_S`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from bridge.runtime.session import close_quietly
from bridge.wire.payloads import encode_payload

log = logging.getLogger("zab.gui")

RETRY_S = 1.0
#: How often the session is asked whether the node is still connected.
CONNECTION_CHECK_S = 1.0

SampleHandler = Callable[[str, bytes, str, bytes | None], None]
"""(key, payload, encoding, attachment): the attachment tells which bridge published it."""
LivelinessHandler = Callable[[str, bool], None]


def client_config(endpoints: Sequence[str]) -> zenoh.Config:
    """Zenoh client config that connects only to ``endpoints`` and listens nowhere."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


class ZenohFeed:
    """Subscribes to ``keys`` (and link liveliness ``tokens``) at ``endpoints``."""

    def __init__(
        self,
        endpoints: Sequence[str],
        keys: Sequence[str],
        tokens: str,
        on_sample: SampleHandler,
        on_liveliness: LivelinessHandler,
        on_connection: Callable[[bool, str | None], None],
    ) -> None:
        if not endpoints:
            raise ValueError("the GUI needs at least one Zenoh endpoint to connect to")
        self.endpoints = list(endpoints)
        self.keys = list(keys)
        self.tokens = tokens
        self.on_sample = on_sample
        self.on_liveliness = on_liveliness
        self.on_connection = on_connection
        self.session: zenoh.Session | None = None
        self.connected = False
        self.error: str | None = None
        self.samples = 0

    async def run(self, stop: asyncio.Event) -> None:
        """Open (retrying), subscribe, watch the connection until ``stop``; then close."""
        loop = asyncio.get_running_loop()
        try:
            while not stop.is_set():
                if self.session is None:
                    try:
                        self.session = await loop.run_in_executor(
                            None, zenoh.open, client_config(self.endpoints))
                    except zenoh.ZError as exc:
                        self._connection(False, str(exc))
                    else:
                        self._subscribe(loop, self.session)
                if self.session is not None:
                    alive = await loop.run_in_executor(None, _has_peer, self.session)
                    self._connection(alive, None if alive else "no route to the node")
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(CONNECTION_CHECK_S if self.session else RETRY_S):
                        await stop.wait()
        finally:
            if self.session is not None:
                close_quietly(self.session)
                self.session = None

    def _connection(self, connected: bool, error: str | None) -> None:
        """Report a change of connection (or of the reason it is missing)."""
        if (connected, error) == (self.connected, self.error):
            return
        if connected != self.connected:
            log.info("GUI session %s %s", "connected to" if connected else "not connected to",
                     " ".join(self.endpoints))
        self.connected, self.error = connected, error
        self.on_connection(connected, error)

    def _subscribe(self, loop: asyncio.AbstractEventLoop, session: zenoh.Session) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:
                return
            key, data = str(sample.key_expr), sample.payload.to_bytes()
            encoding = str(sample.encoding)
            origin = None if sample.attachment is None else sample.attachment.to_bytes()
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._deliver, key, data, encoding, origin)

        def on_token(sample: zenoh.Sample) -> None:
            alive = sample.kind == zenoh.SampleKind.PUT
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self.on_liveliness, str(sample.key_expr), alive)

        for key in self.keys:
            session.declare_subscriber(key, on_sample)
        session.liveliness().declare_subscriber(self.tokens, on_token, history=True)

    def _deliver(self, key: str, data: bytes, encoding: str, origin: bytes | None) -> None:
        self.samples += 1
        self.on_sample(key, data, encoding, origin)

    def put(self, key: str, value: Any, ref: str, encoding: str | None = None) -> None:
        """Publish a command value (msgpack; with an ``encoding``, bytes encoded already) with
        attachment ``ref:<ref>``; raises ``ConnectionError`` without a session."""
        if self.session is None:
            raise ConnectionError("not connected to the node: " + " ".join(self.endpoints))
        payload, encoding = encode_payload(value) if encoding is None else (value, encoding)
        self.session.put(key, payload, encoding=zenoh.Encoding(encoding) if encoding else None,
                         attachment=f"ref:{ref}".encode())


def _has_peer(session: zenoh.Session) -> bool:
    """Whether the session is connected to anything (it connects only to the node)."""
    info = session.info
    return bool(list(info.routers_zid()) or list(info.peers_zid()))
