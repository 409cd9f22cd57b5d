"""Key families in the node core (pure): one latest value and age per member of a keyed channel.

A keyed channel reads a wildcard input (``sensors/*/temp``); each concrete key that the mission
allows is a *member* with its own slot in the sender's store, its own age, and its own output
key at receivers (``{src}/sensors/{key}/temp``). Members of a learned family are numbered in
the order the sender first sees them, up to the family's bound; a further key is refused and
counted. Their names cross the water in ``@key`` entries: beside a member's first
:data:`ANNOUNCE_REPEATS` values and again every :data:`REANNOUNCE_S` seconds, so a receiver
that missed them (loss, restart) learns them later; until then its values are dropped, counted.

A sender's restart keeps what the node's saved state holds of its families (:meth:`Families.state`):
the names it learned, in their order, so each keeps its number (a receiver that knew the
numbers before the restart and missed the names again would otherwise publish one member's
value on another's key), and a latching family's member values, as :mod:`bridge.core.latched`
keeps a latching channel's. A saved name or value that no longer fits the mission is not
resumed: a counted drop, as there.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.core.builder import Candidate
from bridge.core.latched import read_entry, saved_entry, shape
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

    def state_of(self, member: int) -> MemberState:
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

    def state(self) -> dict[str, Any]:
        """The names learned, in order, and a latching family's member values by name."""
        out: dict[str, Any] = {"names": list(self.names)} if self.learned else {}
        if self.channel.latching:
            digest = shape(self.channel)
            values = {self.names[m]: entry for m, st in self.states.items()
                      if (entry := saved_entry(st, digest)) is not None}
            if values:
                out["latched"] = values
        return out

    def resume(self, saved: Mapping[str, Any]) -> list[str]:
        """Put back what :meth:`state` saved; returns why each part that no longer fits was
        not resumed."""
        problems: list[str] = []
        names = saved.get("names")
        if names is not None:
            if not self.learned:
                problems.append("its keys are no longer learned")
            elif not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                problems.append("its saved key names are unreadable")
            elif (why := self._misfit(names)) is not None:
                problems.append(why)
            else:
                self.names = list(names)
        values = saved.get("latched") or {}
        if values and not self.channel.latching:
            return [*problems, "the channel is no longer latching"]
        digest = shape(self.channel)
        for name, entry in values.items() if isinstance(values, Mapping) else ():
            member = self.names.index(name) if name in self.names else None
            if member is None:
                problems.append(f"key {name!r} is not a member now")
                continue
            try:
                got = read_entry(entry, self.channel, digest)
            except (ValueError, TypeError, KeyError, AttributeError) as exc:
                problems.append(f"key {name!r}: its saved value is unreadable ({exc})")
                continue
            if got is None:
                problems.append(f"key {name!r}: its fields changed since it was saved")
                continue
            state = self.state_of(member)
            state.packed[:], state.updated[:] = got[0], got[1]
            state.taken = list(got[2])
        return problems

    def _misfit(self, names: list[str]) -> str | None:
        spec = self.channel.family
        assert spec is not None
        if len(names) > spec.bound or len(set(names)) != len(names):
            return f"its {len(names)} saved key names do not fit its bound of {spec.bound}"
        if any(len(n.encode()) > spec.name_bytes for n in names):
            return f"a saved key name is longer than {spec.name_bytes} bytes"
        return None


class Families:
    """Every key family of one node: members it sends, and names of members it receives."""

    def __init__(self, table: ChannelTable, node: str,
                 changed: Callable[[float], None]) -> None:
        """``changed(now)``: a name was learned or a latching member's value stored (what
        the node's saved state holds changed)."""
        self.node = node
        self.names_codec: NameCodec | None = table.names
        self.senders = {c.index: FamilySender(c, node) for c in table.channels
                        if c.family is not None and c.sent_by(node) and c.destinations(node)}
        self.heard: dict[tuple[str, int], dict[int, str]] = {}  # (src, channel) → names
        self.received_at: dict[str, float] = {}  # output key → last arrival
        self.changed = changed

    # -- restarts ----------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """What a restart resumes, by channel name (:meth:`FamilySender.state`)."""
        return {s.channel.name: st for s in self.senders.values() if (st := s.state())}

    def resume(self, saved: Any) -> list[tuple[str, str]]:
        """Put back what :meth:`state` saved in an earlier run; returns (channel, why) of each
        part not resumed."""
        if saved is None:
            return []
        if not isinstance(saved, Mapping):
            return [("(families)", "the saved key families are unreadable")]
        by_name = {s.channel.name: s for s in self.senders.values()}
        out: list[tuple[str, str]] = []
        for name, entry in saved.items():
            sender = by_name.get(name) if isinstance(name, str) else None
            if sender is None or not isinstance(entry, Mapping):
                out.append((str(name), "a key family saved by an earlier run is not resumed: "
                            "this node no longer sends it as a key family"))
                continue
            out += [(name, f"a key family saved by an earlier run is not resumed: {why}")
                    for why in sender.resume(entry)]
        return out

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
                known = len(sender.names)
                member = sender.member(match.group(1))
                if isinstance(member, str):
                    problems.append(member)
                    continue
                try:
                    packed = pack(element)
                except EncodeError as exc:
                    problems.append(f"channel {sender.channel.name!r}: {exc}")
                    continue
                state = sender.state_of(member)
                state.packed[i], state.updated[i] = packed, now
                state.fresh = True
                if sender.channel.latching or len(sender.names) > known:
                    self.changed(now)
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

    def forget(self, src: str) -> None:
        """``src`` started afresh: the member numbers it used mean nothing now."""
        for known in [k for k in self.heard if k[0] == src]:
            del self.heard[known]

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
