"""A node's keyspace (pure): where its applications put what they mean to cross the water, and
the puts there that nothing reads.

Each node has a ``keyspace`` in the mission (default ``{node}/**``). The runtime watches it;
a put there on a key no channel reads (nor the bridge itself: the node's nav key, the CTD and
anchor keys) is *unmapped*: counted per key (``unmapped_keys`` in the node's stats, at most
:data:`MAX_KEYS` keys, the rest under ``(other keys)``), logged and reported
(:class:`~bridge.core.events.UnmappedKey`) once per key, so a typo in a key shows at once.

At the other end, a get on a peer's keyspace that asks no query and no latched value of this
node maps to nothing: :meth:`Keyspace.unanswered` says why, for the runtime's reply error;
not while a peer is reachable over IP (surfaced): then the get may be answered there, by
another bridge or application, and an error from here would only contradict it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from functools import cached_property

from bridge.core.events import UnmappedKey
from bridge.core.interest import intersects, output_keys
from bridge.core.outputs import Outbox
from bridge.core.surfacing import Surfacing
from bridge.mission.model import Mission
from bridge.wire.channels import ChannelTable

log = logging.getLogger("zab.core")

MAX_KEYS = 256
"""Distinct unmapped keys counted one by one; more are counted together, so an application
publishing ever new keys cannot grow the counters (or the log) without bound."""
OTHER = "(other keys)"
_CACHED = 4096  # keys whose answer :meth:`Keyspace.maps` keeps


def keyspace_of(mission: Mission, node: str) -> list[str]:
    """The key expressions of ``node``'s keyspace."""
    return [k.format(node=node) for k in mission.nodes[node].keyspace]


class Keyspace:
    """What one node reads of its keyspace, and the puts there nothing reads."""

    def __init__(self, mission: Mission, table: ChannelTable, node: str, inputs: Iterable[str],
                 outbox: Outbox, surfacing: Surfacing | None = None,
                 steered: Iterable[str] = ()) -> None:
        """``inputs``: the keys the node's channels read (wildcards allowed); ``surfacing``:
        the peers reachable over IP, when the mission surfaces; ``steered``: the image
        control keys here (read, and a get on them answered)."""
        self.node = node
        self.steered = set(steered)
        self.surfacing = surfacing
        self.outbox = outbox
        self.expressions = keyspace_of(mission, node)
        ranging = mission.ranging
        read = [*inputs, *self.steered, *ranging.anchor_keys.values()]
        read += [k for k in (mission.nodes[node].nav_key, ranging.ctd_key, ranging.peer_ctd_key)
                 if k is not None]
        self._read = [k.replace("{src}", "*").replace("{node}", "*") for k in read]
        self._maps: dict[str, bool] = {}
        self.mission = mission
        self.table = table

    @cached_property
    def _answered(self) -> tuple[list[str], dict[str, str]]:
        """The keys a get is answered on here (queries asked, latched outputs and pictures,
        image controls), and each output key's channel; worked out at the first get."""
        node, table = self.node, self.table
        outputs = output_keys(table, node)
        latched = {k for c in table.channels if c.latching or c.image is not None  # (pictures)
                   for k in outputs.get(c.index, ())}
        asked = {spec.asked_key(s) for spec in table.queries if node in spec.askers
                 for s in spec.servers if s != node}
        return (sorted(asked | latched | self.steered),
                {k: table.channels[i].name for i, keys in outputs.items() for k in keys})

    def maps(self, key: str) -> bool:
        """Whether a put on concrete ``key`` is read here (answers kept, bounded)."""
        found = self._maps.get(key)
        if found is None:
            if len(self._maps) >= _CACHED:
                self._maps.clear()
            found = self._maps[key] = any(intersects(k, key) for k in self._read)
        return found

    def unmapped(self, key: str, now: float) -> None:
        """An application put ``key``, under this node's keyspace, and nothing reads it."""
        counted = self.outbox.stats.unmapped_keys
        if key not in counted and len(counted) >= MAX_KEYS:
            counted[OTHER] += 1
            return
        counted[key] += 1
        if counted[key] == 1:
            log.warning("%s: a put on %r, under this node's keyspace, is read by no channel "
                        "of the mission: it does not cross (counted; said once)", self.node, key)
            self.outbox.event(UnmappedKey(now, key))

    def peer_keyspaces(self) -> list[str]:
        """The key expressions of the other nodes' keyspaces, where gets may be asked here."""
        return sorted({k for peer in self.mission.nodes if peer != self.node
                       for k in keyspace_of(self.mission, peer)})

    def unanswered(self, selector: str) -> str | None:
        """Why a get on ``selector`` (under a peer's keyspace) gets nothing from the bridge
        here, or None when it asks a query or a latched value of this node, or while a peer is
        reachable over IP (the get may be answered there)."""
        if self.surfacing is not None and self.surfacing.reachable:
            return None
        answered, channels = self._answered
        if any(intersects(selector, k) for k in answered):
            return None
        outputs = [f"{k} (channel {c})" for k, c in channels.items()
                   if intersects(selector, k)]
        if outputs:
            return (f"{selector}: {', '.join(outputs)} at {self.node} not latched: no value is "
                    "kept to answer a get (subscribe to it)")
        return (f"{selector}: no query and no channel of the mission maps this key at "
                f"{self.node}: nothing crosses the water for it")
