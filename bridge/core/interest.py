"""Demand-driven sending (pure): what this node's applications want, and what its peers want.

In a mission with ``demand``, a node sends a channel only while one of the channel's
destinations wants it (``always`` channels: always). A destination *wants* a channel while some
application there subscribes to one of the channel's output keys; the runtime learns that from
Zenoh matching listeners on its output publishers (the virtual-clock fleet from its simulated
subscriptions) and hands the set to :meth:`Interest.set_local`.

Each node tells the others in an ``@want`` entry: at its first transmit opportunity, whenever
its set changes, when a peer's link comes back up (it may have restarted and forgotten), and at
least every ``refresh_s`` (so it survives a lost frame).
Until a peer's first ``@want`` arrives, that peer wants nothing: a node that starts sends no
data nobody asked for. Values keep arriving in the store while nobody wants them, so the latest
one goes out as soon as somebody does.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

from bridge.core.builder import Candidate
from bridge.core.families import Extra
from bridge.mission.model import Mission
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.interest import InterestCodec


def _chunk_matches(a: str, b: str) -> bool:
    """Whether two key-expression chunks (``*``, ``$*`` or verbatim) can name the same chunk."""
    if a == "*" or b == "*":
        return True
    if "$*" not in a and "$*" not in b:
        return a == b
    if "$*" in a and "$*" in b:
        return True  # both sub-chunk wildcards: assume they meet (conservative)
    pattern, text = (a, b) if "$*" in a else (b, a)
    return re.fullmatch(".*".join(map(re.escape, pattern.split("$*"))), text) is not None


def intersects(a: str, b: str) -> bool:
    """Whether Zenoh key expressions ``a`` and ``b`` share a key (``*``, ``**`` and ``$*``)."""
    return _intersects(a.split("/"), b.split("/"))


def _intersects(a: list[str], b: list[str]) -> bool:
    if not a or not b:
        rest = a or b
        return all(c == "**" for c in rest)
    if a[0] == "**":
        return _intersects(a[1:], b) or _intersects(a, b[1:])
    if b[0] == "**":
        return _intersects(a, b[1:]) or _intersects(a[1:], b)
    return _chunk_matches(a[0], b[0]) and _intersects(a[1:], b[1:])


def output_keys(table: ChannelTable, node: str) -> dict[int, set[str]]:
    """Per channel ``node`` receives: the output keys it publishes there (a key family's with
    ``*`` for the member; an image channel's pictures, and none for its control, which the
    camera takes in)."""
    out: dict[int, set[str]] = {}
    for channel in table.channels:
        image = channel.image
        for sender in channel.senders:
            if node in channel.destinations(sender):
                keys = out.setdefault(channel.index, set())
                if image is None:
                    keys.update(e.output_key(sender, node) for e in channel.elements)
                elif not image.control:
                    keys.add(image.output_key(sender, node))
    return out


def wanted_by(table: ChannelTable, node: str, subscriptions: Iterable[str]) -> frozenset[int]:
    """The channels whose output keys at ``node`` meet one of ``subscriptions``."""
    subs = list(subscriptions)
    return frozenset(index for index, keys in output_keys(table, node).items()
                     if any(intersects(k, s) for k in keys for s in subs))


def own_subscriptions(mission: Mission, input_keys: Iterable[str]) -> list[str]:
    """What a bridge itself subscribes to at a node (its channels' inputs, anchors' and CTD
    keys): in Zenoh these meet its output publishers like any application's subscriber."""
    ranging = mission.ranging
    keys = [*input_keys, *ranging.anchor_keys.values()]
    keys += [k for k in (ranging.ctd_key, ranging.peer_ctd_key) if k is not None]
    return [k.replace("{src}", "*").replace("{node}", "*") for k in keys]


@dataclass
class Interest:
    """This node's wanted channels and the last ``@want`` heard from each peer."""

    codec: InterestCodec
    refresh_s: float
    local: frozenset[int] = frozenset()
    sent: frozenset[int] | None = None
    sent_at: float | None = None
    peers: dict[str, frozenset[int]] = field(default_factory=dict)
    heard_at: dict[str, float] = field(default_factory=dict)

    def set_local(self, wanted: Iterable[int]) -> bool:
        """What this node's applications want now; returns whether it changed."""
        wanted = frozenset(wanted)
        changed, self.local = wanted != self.local, wanted
        return changed

    def repeat(self) -> None:
        """Send the interest again at the next opportunity, changed or not."""
        self.sent = None

    def next_due(self) -> float | None:
        """When the next ``@want`` is due: at once if it changed (or was never sent)."""
        if self.sent is None or self.sent != self.local or self.sent_at is None:
            return float("-inf")
        return self.sent_at + self.refresh_s

    def candidate(self, now: float) -> Candidate | None:
        due = self.next_due()
        if due is None or due > now + 1e-9:
            return None
        carried = self.local

        def sent(built: float) -> None:
            self.sent, self.sent_at = carried, built

        return Candidate(self.codec, self.sent_at, Extra(self.codec, self.codec.pack(carried),
                                                         sent))

    def on_heard(self, src: str, wanted: Iterable[int], now: float) -> None:
        self.peers[src] = frozenset(wanted)
        self.heard_at[src] = now

    def wants(self, channel: ChannelCodec, destinations: Iterable[str]) -> bool:
        """Whether ``channel`` is wanted by one of ``destinations``."""
        return channel.always or any(channel.index in self.peers.get(d, ())
                                     for d in destinations)

    def snapshot(self, table: ChannelTable) -> dict[str, object]:
        """Names of the channels wanted here and by each peer (as last heard)."""
        def names(indices: Iterable[int]) -> list[str]:
            return [table.channels[i].name for i in sorted(indices)]
        return {"here": names(self.local),
                "peers": {p: names(w) for p, w in sorted(self.peers.items())}}
