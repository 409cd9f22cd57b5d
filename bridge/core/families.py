"""Key families in the node core (pure): one latest value and age per member of a keyed channel.

A keyed channel reads a wildcard input (``sensors/*/temp``); each concrete key that the mission
allows is a *member* with its own slot in the sender's store, its own age, and its own output
key at receivers (``{src}/sensors/{key}/temp``). Members of a learned family are numbered in
the order the sender first sees them, up to the family's bound; a further key is refused and
counted. Their names cross the water in ``@key`` entries: beside a member's first
:data:`ANNOUNCE_REPEATS` values and again every :data:`REANNOUNCE_S` seconds, so a receiver
that missed them (loss, restart) learns them later; until then its values are dropped, counted.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridge.core.builder import Candidate
from bridge.core.store import ChannelState
from bridge.errors import EncodeError
from bridge.wire.channels import ChannelCodec, ChannelTable, ElementCodec
from bridge.wire.families import NameCodec, member_pattern
from bridge.wire.sample_meta import tombstone

ANNOUNCE_REPEATS = 3  # a learned member's name goes beside its first values this many times
REANNOUNCE_S = 60.0  # and again this often while the member is being sent


@dataclass
class MemberState(ChannelState):
    """A family member's latest value at its sender; its entry starts with the member index."""

    member: int = 0

    def payload(self) -> int:
        assert self.channel.family is not None
        return (self.member << self.channel.bits) | super().payload()


@dataclass
class Extra:
    """A system entry offered to a frame: its codec, its bits, and what to do once it is sent
    (called with the time the frame was built)."""

    channel: Any
    bits: int
    on_sent: Callable[[float], None]
    to: str | None = None  # the one node it is for (a query's server or asker), if any


@dataclass
class FamilySender:
    """The members of one keyed channel at its sender."""

    channel: ChannelCodec
    node: str
    names: list[str] = field(default_factory=list)
    states: dict[int, MemberState] = field(default_factory=dict)
    announced: Counter[int] = field(default_factory=Counter)
    announced_at: dict[int, float] = field(default_factory=dict)
    refused: int = 0

    def __post_init__(self) -> None:
        assert self.channel.family is not None
        self.names = list(self.channel.family.members)
        self.patterns = [member_pattern(e.input_key(self.node, "{key}"))
                         for e in self.channel.elements]

    @property
    def learned(self) -> bool:
        return bool(self.channel.family and self.channel.family.learned)

    def member(self, name: str) -> int | str:
        """The index of member ``name``, learning it if the family may; else why not."""
        if name in self.names:
            return self.names.index(name)
        spec = self.channel.family
        assert spec is not None
        if not spec.learned:
            return f"{name!r} is not a member of channel {self.channel.name!r}"
        if len(name.encode()) > spec.name_bytes:
            return f"member name {name!r} is longer than {spec.name_bytes} bytes"
        if len(self.names) >= spec.bound:
            self.refused += 1
            return f"channel {self.channel.name!r} already learned its {spec.bound} keys"
        self.names.append(name)
        return len(self.names) - 1

    def state(self, member: int) -> MemberState:
        state = self.states.get(member)
        if state is None:
            n = len(self.channel.elements)
            state = self.states[member] = MemberState(self.channel, [None] * n, [None] * n,
                                                      member=member)
        return state

    def name_due(self, member: int, now: float) -> bool:
        if not self.learned:
            return False
        if self.announced[member] < ANNOUNCE_REPEATS:
            return True
        return now - self.announced_at.get(member, float("-inf")) >= REANNOUNCE_S

    def named(self, member: int, built: float) -> None:
        self.announced[member] += 1
        self.announced_at[member] = built


class Families:
    """Every key family of one node: members it sends, and names of members it receives."""

    def __init__(self, table: ChannelTable, node: str) -> None:
        self.node = node
        self.names_codec: NameCodec | None = table.names
        self.senders = {c.index: FamilySender(c, node) for c in table.channels
                        if c.family is not None and c.sent_by(node) and c.destinations(node)}
        self.heard: dict[tuple[str, int], dict[int, str]] = {}  # (src, channel) → names
        self.received_at: dict[str, float] = {}  # output key → last arrival

    # -- sender ------------------------------------------------------------------------------

    def subscriptions(self) -> dict[str, list[tuple[ChannelCodec, int]]]:
        """Wildcard input keys to subscribe, with the (channel, element) each feeds."""
        keys: dict[str, list[tuple[ChannelCodec, int]]] = {}
        for sender in self.senders.values():
            for i, element in enumerate(sender.channel.elements):
                keys.setdefault(element.input_key(self.node), []).append((sender.channel, i))
        return keys

    def feed_keys(self) -> dict[str, Any]:
        """Concrete input keys an application could publish (a learned family's up to its
        bound, named ``k0``, ``k1``, …), with the layout of each: for synthetic feeds."""
        out: dict[str, Any] = {}
        for sender in self.senders.values():
            spec = sender.channel.family
            assert spec is not None
            names = [f"k{i}" for i in range(spec.bound)] if spec.learned else spec.members
            for element in sender.channel.elements:
                for name in names:
                    out[element.input_key(self.node, name)] = element.layout
        return out

    def ingest(self, key: str, value: Any, now: float) -> list[str]:
        """A sample on concrete ``key``: store it in each member it belongs to. Returns why
        it was refused by a family that reads the key (empty: stored, or no family reads it)."""
        return self._store(key, lambda element: element.layout.pack(value), now)

    def delete(self, key: str, now: float) -> list[str]:
        """A delete on concrete ``key``: a tombstone in each member it belongs to whose
        channel has ``deletes``. Returns the problems, as :meth:`ingest`."""
        return self._store(key, lambda element: tombstone(element.layout), now, deletes=True)

    def _store(self, key: str, pack: Callable[[ElementCodec], int], now: float,
               deletes: bool = False) -> list[str]:
        problems: list[str] = []
        for sender in self.senders.values():
            for i, pattern in enumerate(sender.patterns):
                match = pattern.fullmatch(key)
                element = sender.channel.elements[i]
                if match is None or (deletes and not (element.meta and element.meta.deletes)):
                    continue
                member = sender.member(match.group(1))
                if isinstance(member, str):
                    problems.append(member)
                    continue
                try:
                    packed = pack(element)
                except EncodeError as exc:
                    problems.append(f"channel {sender.channel.name!r}: {exc}")
                    continue
                state = sender.state(member)
                state.packed[i], state.updated[i] = packed, now
                state.fresh = True
        return problems

    def outputs_for(self, key: str) -> list[tuple[str, str]]:
        """(destination, output key) of each member concrete ``key`` feeds (for relays)."""
        out: list[tuple[str, str]] = []
        for sender in self.senders.values():
            channel = sender.channel
            for i, pattern in enumerate(sender.patterns):
                match = pattern.fullmatch(key)
                if match is not None and match.group(1) in sender.names:
                    element = channel.elements[i]
                    out += [(d, element.output_key(self.node, d, match.group(1)))
                            for d in channel.destinations(self.node)]
        return out

    def candidates(self, now: float, wanted: Callable[[ChannelCodec], bool]) -> list[Candidate]:
        """Members due at ``now``, and the names receivers still need to hear beside them."""
        out: list[Candidate] = []
        for sender in self.senders.values():
            if not wanted(sender.channel):
                continue
            for member, state in sender.states.items():
                ready = state.ready_at(now)
                if ready is None or ready > now + 1e-9:
                    continue
                out.append(Candidate(sender.channel, state.last_sent, state, member))
                if sender.name_due(member, now):
                    assert self.names_codec is not None  # (a learned family names members)
                    out.append(Candidate(self.names_codec, None, self._name(sender, member),
                                         member))
        return out

    def _name(self, sender: FamilySender, member: int) -> Extra:
        codec = self.names_codec
        assert codec is not None
        bits = codec.pack(sender.channel.index, member, sender.names[member])
        return Extra(codec, bits, lambda built: sender.named(member, built))

    def next_due(self, now: float | None, wanted: Callable[[ChannelCodec], bool]) -> float | None:
        times = [t for sender in self.senders.values() if wanted(sender.channel)
                 for s in sender.states.values() if (t := s.ready_at(now)) is not None]
        return min(times) if times else None

    # -- receiver ----------------------------------------------------------------------------

    def member_name(self, src: str, channel: ChannelCodec, member: int) -> str | None:
        """The name of ``src``'s member ``member`` of ``channel`` (None: not learned yet)."""
        spec = channel.family
        assert spec is not None
        if not spec.learned:
            return spec.members[member] if member < len(spec.members) else None
        return self.heard.get((src, channel.index), {}).get(member)

    def on_name(self, src: str, header: tuple[Any, ...]) -> None:
        """An ``@key`` entry from ``src``: member ``header[1]`` of channel ``header[0]``."""
        channel, member, name = header
        self.heard.setdefault((src, channel), {})[member] = name

    def arrived(self, key: str, now: float) -> None:
        self.received_at[key] = now

    def snapshot(self, now: float) -> dict[str, Any]:
        """Per keyed channel: members and the age of each member's value (sender side), keys
        refused at the bound; per output key received: its age."""
        return {
            "members": {s.channel.name: {s.names[m]: st.age(now) for m, st in s.states.items()}
                        for s in self.senders.values()},
            "keys_refused": {s.channel.name: s.refused for s in self.senders.values()
                             if s.refused},
            "member_age_s": {k: now - t for k, t in self.received_at.items()},
        }
