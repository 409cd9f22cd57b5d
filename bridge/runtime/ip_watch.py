"""Surfacing, proven: which peer bridges are reachable over IP, as far as the mission key says.

Each bridge of a mission with ``surfacing`` declares its liveliness token
``@zab/<mission>/<node>/bridge`` and, before it, a queryable ``@zab/<mission>/<node>/prove``.
A token only says that *something* on this Zenoh network declared it: a local application can
(Zenoh also merges tokens of one key, so a forged one would hide a real one's arrival and
departure). So while a peer's token is alive, :class:`IpWatch` asks that peer's queryable for
a proof every :data:`PROVE_EVERY_S` (a fresh nonce each time, :func:`~bridge.wire.proofs.
surfacing_proof`): the peer counts as reachable over IP from the first valid answer, and no
longer from the first time none comes within :data:`PROVE_TIMEOUT_S`, or when the token goes.

Without a mission key (``wire.auth: off``) there is nothing to prove with: the token alone is
believed, as the access control of the vehicle's Zenoh router must then guard it
(docs/deploy.md).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from collections.abc import Callable
from typing import Any

import msgpack
import zenoh

from bridge.wire.proofs import proven, surfacing_proof

log = logging.getLogger("zab.node")

PROVE_EVERY_S = 2.0
PROVE_TIMEOUT_S = 1.5
WARN_AFTER = (3, 30, 300, 3000)
"""Challenges of one peer failed in a row at which a warning is logged."""


class IpWatch:
    """The IP reachability of one node's peers, for its core (``changed(peer, up)`` on the
    event loop)."""

    def __init__(self, session: zenoh.Session, mission: str, node: str, peers: set[str],
                 key: bytes | None, changed: Callable[[str, bool], None]) -> None:
        self.session = session
        self.mission = mission
        self.node = node
        self.peers = peers - {node}
        self.key = key
        self.changed = changed
        self.tokens: set[str] = set()  # peers whose token is alive (kept by the Zenoh thread)
        self.reachable: set[str] = set()  # peers proven reachable
        self.unproven = 0  # challenges a live token's peer did not answer with a proof
        self._failing: dict[str, int] = {}  # each peer's challenges failed in a row
        self.entities: list[Any] = []
        self._wake = asyncio.Event()

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Answer challenges, then declare this bridge's token and watch the peers'."""
        prefix = f"@zab/{self.mission}"
        self.entities.append(self.session.declare_queryable(f"{prefix}/{self.node}/prove",
                                                            self._answer))
        liveliness = self.session.liveliness()
        self.entities.append(liveliness.declare_token(f"{prefix}/{self.node}/bridge"))

        def on_token(sample: zenoh.Sample) -> None:  # Zenoh thread
            parts = str(sample.key_expr).split("/")
            if len(parts) == 4 and parts[2] in self.peers:
                up = sample.kind == zenoh.SampleKind.PUT
                # (at once, not on the loop: a get that came over the same join may be next)
                (self.tokens.add if up else self.tokens.discard)(parts[2])
                with contextlib.suppress(RuntimeError):  # the loop closed: the node is gone
                    loop.call_soon_threadsafe(self._token, parts[2], up)

        self.entities.append(liveliness.declare_subscriber(f"{prefix}/*/bridge", on_token,
                                                           history=True))

    def _answer(self, query: zenoh.Query) -> None:
        """Zenoh thread: a peer's challenge; the proof, if this node holds the key."""
        try:
            params = query.parameters
            nonce, asker = params.get("nonce") or "", params.get("from") or ""
            if self.key is not None and nonce and asker:
                proof = surfacing_proof(self.key, self.mission, self.node, asker, nonce)
                query.reply(query.key_expr, msgpack.packb({"node": self.node, "proof": proof}))
            elif self.key is None:
                query.reply(query.key_expr, msgpack.packb({"node": self.node}))
        finally:
            query.drop()

    def _token(self, peer: str, up: bool) -> None:
        """On the loop: a peer's token appeared or went."""
        if up:
            self._wake.set()  # prove it now
        else:
            self._set(peer, False)

    def _set(self, peer: str, up: bool) -> None:
        if (peer in self.reachable) != up:
            (self.reachable.add if up else self.reachable.discard)(peer)
            self.changed(peer, up)

    async def run(self) -> None:
        """Prove every peer whose token is alive, again and again."""
        while True:
            for peer in sorted(self.tokens):
                up = await self._prove(peer)
                if peer in self.tokens:  # (it may have gone meanwhile)
                    self._set(peer, up)
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(PROVE_EVERY_S):
                    await self._wake.wait()

    async def _prove(self, peer: str) -> bool:
        """Whether ``peer`` answers a fresh challenge with a valid proof now. The first valid
        answer settles it, as it comes (no consolidation, which holds replies to the end): the
        get itself ends only once every queryable on the key has (or at its timeout), and gets
        meanwhile would be answered both over IP and acoustically."""
        key = self.key
        if key is None:
            return True  # nothing to prove with: the token is believed
        nonce = secrets.token_hex(16)
        selector = f"@zab/{self.mission}/{peer}/prove?nonce={nonce};from={self.node}"

        def ask() -> bool:
            for reply in self.session.get(selector, timeout=PROVE_TIMEOUT_S,
                                          consolidation=zenoh.ConsolidationMode.NONE):
                answer = None
                if reply.ok is not None:
                    with contextlib.suppress(Exception):  # anything but a map: no proof
                        answer = msgpack.unpackb(reply.ok.payload.to_bytes()).get("proof")
                if proven(key, self.mission, peer, self.node, nonce, answer):
                    return True  # (the replies still to come are dropped)
            return False

        if await asyncio.to_thread(ask):
            self._failing.pop(peer, None)
            return True
        self.unproven += 1
        failing = self._failing[peer] = self._failing.get(peer, 0) + 1
        # (a peer's token can come before its answer does: the first miss is no alarm)
        if peer not in self.reachable and failing in WARN_AFTER:
            log.warning("%s: %s's bridge token is alive but no proof came with the mission key "
                        "(%d times in a row): not treated as surfaced", self.node, peer, failing)
        return False

    def close(self) -> None:
        for entity in self.entities:
            with contextlib.suppress(Exception):
                entity.undeclare()
