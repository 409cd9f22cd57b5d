"""Fidelity that follows the link (pure): which peers are reachable over IP right now.

In a mission with ``surfacing``, each bridge holds a Zenoh liveliness token
``@zab/<mission>/<node>/bridge``. A bridge that sees a peer's token (the peer surfaced and its
Zenoh joined this node's over IP) and, with a mission key, a proof from it
(:mod:`bridge.runtime.ip_watch`) calls :meth:`Surfacing.changed`; from then on:

- the node's channels to that peer are not carried acoustically (a channel whose every
  destination is reachable over IP is not sent at all; reliable and fragmented ones still are);
- acoustic values *from* that peer are not published (counted as ``surfaced_duplicates``): a
  sender that has not noticed yet never puts a quantised copy beside the full-fidelity one;
- each input sample feeding a channel to that peer is put, unquantised, on the peer's output
  key (a :class:`Relay`), unless that key is the input key itself.
- a get here on a query that peer serves crosses nothing: the peer's applications answer it
  over IP (:class:`~bridge.core.queries.OverIp`, counted as ``gets_over_ip``).

When the token goes (the vehicle dived, the IP path is lost), the peer is acoustic again: the
store kept the latest value of every channel, so the next opportunity sends those, once each.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any


@dataclass(frozen=True)
class Relay:
    """Put ``data`` (as received, ``encoding``) on ``key`` over IP, marked as bridged, with
    the application's ``attachment`` where the channel carries it (as the acoustic path
    publishes it) and its time ``taken``; ``delete``: a Zenoh delete of ``key`` instead."""

    key: str
    data: bytes
    encoding: str
    attachment: bytes | None = None
    delete: bool = False
    taken: float | None = None


@dataclass
class Surfacing:
    """Peers reachable over IP, with when each came and went."""

    node: str
    republish: bool = True
    reachable: set[str] = field(default_factory=set)
    since: dict[str, float] = field(default_factory=dict)
    duplicates: int = 0
    relayed: int = 0
    gets_over_ip: int = 0
    switches: list[dict[str, Any]] = field(default_factory=list)

    def changed(self, peer: str, up: bool, now: float) -> bool:
        """The peer's bridge token appeared (``up``) or went; returns whether that is news."""
        if peer == self.node or (peer in self.reachable) == up:
            return False
        if up:
            self.reachable.add(peer)
        else:
            self.reachable.discard(peer)
        self.since[peer] = now
        self.switches.append({"peer": peer, "ip": up, "time": now})
        return True

    def acoustic(self, destinations: Iterable[str]) -> tuple[str, ...]:
        """The destinations still reached only acoustically."""
        return tuple(d for d in destinations if d not in self.reachable)

    def republishes(self, input_key: str, output_key: str) -> bool:
        """Whether a sample on ``input_key`` is put over IP on ``output_key`` (for a
        destination reachable over IP): not where that is the input key itself."""
        return self.republish and output_key != input_key

    def relays(self, input_key: str, out_keys: Iterable[tuple[str, str]],
               sample: Relay) -> list[Relay]:
        """Relays of an input ``sample`` (on ``input_key``): ``out_keys`` holds (destination,
        output key)."""
        keys = sorted({key for dest, key in out_keys
                       if dest in self.reachable and self.republishes(input_key, key)})
        self.relayed += len(keys)
        return [replace(sample, key=key) for key in keys]

    def snapshot(self) -> dict[str, Any]:
        return {"ip_reachable": sorted(self.reachable), "since": dict(self.since),
                "surfaced_duplicates": self.duplicates, "relayed": self.relayed,
                "gets_over_ip": self.gets_over_ip}
