"""The latest value of each latching channel, kept across restarts (pure).

A latching channel's value is sent again and again (at its rate) until a newer one replaces it,
so an application often puts it once: a vehicle's mission status, an operator's standing
command. A restart must not silence it. The node's saved state
(:meth:`~bridge.core.node.NodeCore.state`, ``latched``) holds, per latching channel, what the
outbound store holds: each element's packed value, when it arrived and when it was taken. A
node resumed from that state sends it again as before, without a new put, its ``age`` counted
from when it was really taken and its ``ttl_s`` from when it really arrived (a value past its
``ttl_s`` stays unsent, as in the run that took it).

Each value is checked against its channel in the mission the node runs now, also after the
mission file changed (the rest of the state is then not resumed:
:mod:`bridge.core.restarts`). One that no longer fits (its channel gone, no longer latching
or no longer sent by this node, its fields changed) or that cannot be read is not resumed: it
is a dropped payload keyed by the channel, cause ``unresumable``, with a log line (counted at
the node's first tick, when it knows the time). A state saved before this part existed has no
``latched``: it resumes as it did.

Saves: a latched value asks for one at once, then at most every :data:`KEEP_LATCHED_S` (a
status put at 10 Hz does not cost 10 saves a second); one that comes in between asks at the
next tick once that much time has passed, and one that comes while a save is asked for already
goes with it. A ``kill -9`` loses at most the values of the last second or two: the one before
them resumes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Iterable, Mapping
from typing import Any

from bridge.core.outputs import Outbox
from bridge.core.persist import int_from_state, int_to_state
from bridge.core.store import ChannelState, OutboundStore
from bridge.wire.channels import ChannelCodec

__all__ = ["KEEP_LATCHED_S", "Latched", "read_entry", "saved_entry", "shape"]

log = logging.getLogger("zab.core")

KEEP_LATCHED_S = 1.0
"""Least time between two saves a latched value asks for."""

Saved = tuple[list[int | None], list[float | None], list[float | None]]
"""A channel's value as the store holds it: each element's packed value, when it arrived, when
it was taken."""


def shape(channel: ChannelCodec) -> str:
    """What a channel's packed value means, as a short digest: its elements' fields as the
    mission fingerprint describes them, and their bits. A saved value whose channel's shape
    changed is not resumed."""
    description = [[e.layout.bits, fields] for e, fields in zip(
        channel.elements, channel.fields_described(), strict=True)]
    blob = json.dumps(description, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def saved_entry(state: ChannelState, digest: str) -> dict[str, Any] | None:
    """``state``'s value as a saved entry (``digest``: its channel's :func:`shape`), or None
    while it holds none."""
    if all(p is None for p in state.packed):
        return None
    n = len(state.packed)
    return {
        "shape": digest,
        "packed": [None if p is None else int_to_state(p) for p in state.packed],
        "updated": list(state.updated),
        "taken": list(state.taken) if state.taken else [None] * n,
    }


def read_entry(entry: Any, channel: ChannelCodec, digest: str) -> Saved | None:
    """A saved entry's packed values and times, checked against ``channel`` (``digest``: its
    :func:`shape` now); None if its shape changed. ValueError (and the like) if it is
    unreadable."""
    if entry["shape"] != digest:
        return None
    elements = channel.elements
    packed = [None if p is None else int_from_state(p) for p in entry["packed"]]
    updated = [_time(t) for t in entry["updated"]]
    taken = [_time(t) for t in entry["taken"]]
    if not len(packed) == len(updated) == len(taken) == len(elements):
        raise ValueError(f"{len(packed)} values for {len(elements)} elements")
    for element, value, arrived, when in zip(elements, packed, updated, taken, strict=True):
        if value is None:
            if arrived is not None or when is not None:
                raise ValueError("a time without a value")
            continue
        if not isinstance(value, int) or value < 0 or value >> element.layout.bits:
            raise ValueError(f"a value that does not fit its {element.layout.bits} bits")
        if arrived is None:
            raise ValueError("a value without the time it arrived")
    return packed, updated, [t if t is not None or v is None else u
                             for v, u, t in zip(packed, updated, taken, strict=True)]


def _kept(channel: ChannelCodec) -> bool:
    """Whether a channel's latest value is kept across restarts: a latching one, sent from
    the store (not a stream, a key family or pictures)."""
    return channel.latching and not channel.stream and channel.family is None \
        and channel.image is None


def _time(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{value!r} is not a time")
    return float(value)


class Latched:
    """The latching channels' values of one node's store: saved, resumed, and when to save."""

    def __init__(self, store: OutboundStore, outbox: Outbox, node: str) -> None:
        self.store = store
        self.outbox = outbox
        self.node = node
        self.shapes = {i: shape(s.channel) for i, s in store.states.items() if _kept(s.channel)}
        """Each kept channel's shape, by index."""
        self.unsaved = False
        """A latched value changed since the last save asked for."""
        self.asked = -math.inf
        """When a latched value last asked for a save."""
        self.resumed: dict[int, Saved] = {}
        """The values this run resumed from the saved state, by channel index."""
        self.unresumed: list[tuple[str, str]] = []
        """Saved values not resumed, (channel, why), not counted as drops yet."""
        self._told = False  # whether the values resumed were told (at the first tick)

    # -- saves -------------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """Each kept channel's value as the store holds it, by channel name (those without any
        value left out)."""
        out: dict[str, Any] = {}
        for index, digest in self.shapes.items():
            state = self.store.states[index]
            if (entry := saved_entry(state, digest)) is not None:
                out[state.channel.name] = entry
        return out

    def put(self, now: float) -> None:
        """A latched value changed at ``now``: save it, if it is time (a save asked for
        already, not carried out yet, will hold it)."""
        if not self.outbox.unsaved:
            self.unsaved = True
            self.tick(now)

    def tick(self, now: float) -> None:
        """Ask for a save of the latched values changed since the last ask, if it is time (a
        clock gone back asks at once)."""
        if self.unsaved and not 0.0 <= now - self.asked < KEEP_LATCHED_S:
            self.asked = now
            self.unsaved = False
            self.outbox.unsaved = True

    # -- restarts ----------------------------------------------------------------------------

    def resume(self, saved: Any, channels: Iterable[ChannelCodec]) -> None:
        """Put back in the store the values ``saved`` by :meth:`state` in an earlier run; those
        that no longer fit the mission's ``channels``, or cannot be read, go to
        :attr:`unresumed`."""
        if saved is None:
            return
        if not isinstance(saved, Mapping):
            self.unresumed.append(("(latched)", "the saved latched values are unreadable "
                                   f"({type(saved).__name__}, not a map)"))
            return
        names = {c.name: c for c in channels}
        by_name = {self.store.states[i].channel.name: i for i in self.shapes}
        for name, entry in saved.items():
            why = self._misfit(name, names, by_name)
            if why is None:
                try:
                    values = self._read(entry, by_name[name])
                except (ValueError, TypeError, KeyError, AttributeError) as exc:
                    why = f"its saved value is unreadable ({exc})"
                else:
                    if values is not None:
                        self.store.restore(by_name[name], *values)
                        self.resumed[by_name[name]] = values
                        continue
                    why = "its fields changed since it was saved"
            self.unresumed.append((name if isinstance(name, str) else "(latched)",
                                   f"a latched value saved by an earlier run is not resumed: "
                                   f"{why}"))

    def onto(self, stores: Iterable[OutboundStore]) -> None:
        """The values resumed, in ``stores`` too (the node's other links')."""
        for store in stores:
            for index, (packed, updated, taken) in self.resumed.items():
                store.restore(index, list(packed), list(updated), list(taken))

    def _misfit(self, name: Any, names: Mapping[str, ChannelCodec],
                by_name: Mapping[str, int]) -> str | None:
        """Why channel ``name``'s saved value no longer fits the mission, or None."""
        if not isinstance(name, str):
            return f"{name!r} is not a channel name"
        if name in by_name:
            return None
        channel = names.get(name)
        if channel is None:
            return "the mission has no such channel any more"
        if not channel.latching:
            return "the channel is no longer latching"
        return "this node no longer sends the channel's latest value"

    def _read(self, entry: Any, index: int) -> Saved | None:
        return read_entry(entry, self.store.states[index].channel, self.shapes[index])

    def take_unresumed(self, now: float) -> list[tuple[str, str]]:
        """The saved values not resumed, (channel, why), once; the first call at ``now`` also
        logs how many were resumed, and how many of those are past their ``ttl_s`` (kept, but
        not sent: as in the run that saved them)."""
        if self.resumed and not self._told:
            self._told = True
            stale = sum(1 for i in self.resumed
                        if self.store.states[i].ready_at(now) is None
                        and self.store.states[i].ready_at() is not None)
            log.info("%s: resumed the latched values of %d channel(s) from its saved state%s",
                     self.node, len(self.resumed),
                     f" ({stale} past their ttl_s, kept unsent)" if stale else "")
        out, self.unresumed = self.unresumed, []
        return out
