"""Channels as the wire sees them: resolved senders/receivers, compiled layouts, fingerprint.

Built once from a validated :class:`~bridge.mission.Mission`. The channel index is its place
in the mission's ``channels`` list; every node derives the same table from the same file.
"""

from __future__ import annotations

import hashlib
import json
import re
import string
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

from bridge.codec import Layout
from bridge.errors import LayoutError
from bridge.mission import Channel, Element, Mission

WIRE_VERSION = 1

SENDER_TEMPLATES = frozenset({"node", "src"})
RECEIVER_TEMPLATES = frozenset({"node", "src", "dst"})


class PatternError(ValueError):
    """A ``from``/``to`` pattern names no node or is not a valid regular expression."""


def match_nodes(pattern: str | Sequence[str], nodes: Sequence[str]) -> tuple[str, ...]:
    """Nodes named by ``pattern``: an exact name, a list of them, or a regex (full match)."""
    items = [pattern] if isinstance(pattern, str) else list(pattern)
    found: list[str] = []
    for item in items:
        if item in nodes:
            hits = [item]
        else:
            try:
                rx = re.compile(item)
            except re.error as exc:
                raise PatternError(
                    f"{item!r} is neither a node name nor a valid regex: {exc}"
                ) from None
            hits = [n for n in nodes if rx.fullmatch(n)]
            if not hits:
                raise PatternError(f"{item!r} matches no node (nodes: {', '.join(nodes)})")
        found.extend(h for h in hits if h not in found)
    return tuple(found)


def template_names(key: str) -> set[str]:
    """The ``{name}`` placeholders used in a key template."""
    return {name for _, name, _, _ in string.Formatter().parse(key) if name}


@dataclass(frozen=True)
class ElementCodec:
    """An element with its compiled layout."""

    in_key: str
    out_key: str
    encoding: str
    layout: Layout

    def input_key(self, node: str) -> str:
        return self.in_key.format(node=node, src=node)

    def output_key(self, src: str, dst: str) -> str:
        return self.out_key.format(node=dst, src=src, dst=dst)


@dataclass(frozen=True)
class ChannelCodec:
    """A channel ready for the wire: index, endpoints, policy and element layouts."""

    index: int
    name: str
    senders: tuple[str, ...]
    receivers: tuple[str, ...]
    interval_s: float
    latching: bool
    priority: int
    elements: tuple[ElementCodec, ...]
    ack: bool = False

    @cached_property
    def bits(self) -> int:
        return sum(e.layout.bits for e in self.elements)

    def sent_by(self, node: str) -> bool:
        return node in self.senders

    def destinations(self, sender: str) -> tuple[str, ...]:
        """Receivers of this channel when ``sender`` sends it (never the sender itself)."""
        return tuple(r for r in self.receivers if r != sender)

    def pack(self, values: Sequence[object]) -> int:
        """All element values as one integer of ``bits`` bits, first element most significant."""
        n = 0
        for element, value in zip(self.elements, values, strict=True):
            n = (n << element.layout.bits) | element.layout.pack(value)
        return n

    def unpack(self, n: int) -> list[dict]:
        out: list[dict] = []
        for element in reversed(self.elements):
            bits = element.layout.bits
            out.append(element.layout.unpack(n & ((1 << bits) - 1)))
            n >>= bits
        out.reverse()
        return out


def compile_element(element: Element, on_out_of_range: str) -> ElementCodec:
    layout = Layout.from_fields(element.fields, on_out_of_range=on_out_of_range)
    return ElementCodec(element.in_, element.out, element.encoding, layout)


class ChannelTableError(ValueError):
    """A channel cannot be compiled; ``loc`` points into the mission document."""

    def __init__(self, message: str, loc: tuple[str | int, ...]) -> None:
        super().__init__(message)
        self.loc = loc


def compile_channel(index: int, channel: Channel, nodes: Sequence[str]) -> ChannelCodec:
    """Resolve patterns and compile layouts, raising :class:`ChannelTableError` with a location."""
    loc: tuple[str | int, ...] = ("channels", index)
    try:
        senders = match_nodes(channel.from_, nodes)
    except PatternError as exc:
        raise ChannelTableError(str(exc), (*loc, "from")) from None
    try:
        receivers = match_nodes(channel.to, nodes)
    except PatternError as exc:
        raise ChannelTableError(str(exc), (*loc, "to")) from None
    if not any(set(receivers) - {sender} for sender in senders):
        raise ChannelTableError("a channel must reach a node other than its sender", (*loc, "to"))
    elements = []
    for i, element in enumerate(channel.elements):
        eloc = (*loc, "elements", i)
        for key, allowed, where in ((element.in_, SENDER_TEMPLATES, "in"),
                                    (element.out, RECEIVER_TEMPLATES, "out")):
            bad = template_names(key) - allowed
            if bad:
                raise ChannelTableError(
                    f"unknown template {{{sorted(bad)[0]}}} in {key!r}; "
                    f"allowed here: {', '.join('{' + a + '}' for a in sorted(allowed))}",
                    (*eloc, where),
                )
        try:
            elements.append(compile_element(element, channel.on_out_of_range))
        except LayoutError as exc:
            raise ChannelTableError(str(exc), (*eloc, "fields", *exc.loc)) from None
    return ChannelCodec(
        index=index,
        name=channel.name,
        senders=senders,
        receivers=receivers,
        interval_s=channel.interval_s,
        latching=channel.latching,
        priority=channel.priority,
        elements=tuple(elements),
        ack=channel.ack,
    )


@dataclass(frozen=True)
class ChannelTable:
    """Every channel of a mission, plus what both ends of a link must agree on."""

    channels: tuple[ChannelCodec, ...]
    nodes: tuple[str, ...]
    dlbl: bool
    auth_tag_bytes: int = 0  # 0: frames are not authenticated

    @classmethod
    def from_mission(cls, mission: Mission) -> ChannelTable:
        nodes = tuple(mission.nodes)
        seen: dict[str, int] = {}
        for i, channel in enumerate(mission.channels):
            if channel.name in seen:
                raise ChannelTableError(
                    f"channel name {channel.name!r} already used by channel {seen[channel.name]}",
                    ("channels", i, "name"),
                )
            seen[channel.name] = i
        compiled = tuple(compile_channel(i, c, nodes) for i, c in enumerate(mission.channels))
        auth = mission.wire.auth
        return cls(channels=compiled, nodes=nodes, dlbl=mission.wire.dlbl,
                   auth_tag_bytes=auth.tag_bytes if auth else 0)

    def __len__(self) -> int:
        return len(self.channels)

    def by_name(self, name: str) -> ChannelCodec:
        return next(c for c in self.channels if c.name == name)

    def foreign_nodes(self, node: str) -> tuple[str, ...]:
        """The nodes whose DLBL delays ``node`` reports, in mission order."""
        return tuple(n for n in self.nodes if n != node)

    @cached_property
    def fingerprint(self) -> bytes:
        """8 bytes that differ when two mission files would disagree about the wire."""
        description = {
            "wire": WIRE_VERSION,
            "dlbl": self.dlbl,
            "auth": self.auth_tag_bytes,
            "nodes": self.nodes,
            "channels": [
                [c.name, [[f"{f.path}:{f.describe()}" for f in e.layout.fields]
                          for e in c.elements]]
                for c in self.channels
            ],
        }
        blob = json.dumps(description, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).digest()[:8]
