"""Key families on the wire: a channel whose input is a wildcard, one member per concrete key.

A keyed channel's entry carries the member's index in ``index_bits`` = ⌈log2 n⌉ bits (n: the
members listed, the nodes matched, or the learned bound) before the value. Members of a learned
family are named once over the water by the ``@key`` system entry (:class:`NameCodec`): the
family (its place among the mission's learned families), the member index, and the name in
``name_bytes`` bytes, zero padded. Pure: no clock, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

KEY = "key"  # the template placeholder naming a family member
NAME_PRIORITY = 1 << 20  # a member's name goes before any value that needs it


def index_bits(n: int) -> int:
    """⌈log2 n⌉ bits: what an index among ``n`` members takes (0 for a single member)."""
    return (n - 1).bit_length() if n > 1 else 0


@dataclass(frozen=True)
class FamilySpec:
    """The members of a keyed channel: fixed ``members`` or up to ``bound`` learned ones."""

    members: tuple[str, ...]
    bound: int
    learned: bool = False
    name_bytes: int = 0

    @property
    def index_bits(self) -> int:
        return index_bits(self.bound)

    def describe(self) -> list[object]:
        """What both ends must agree on (part of the mission fingerprint)."""
        return (["learn", self.bound, self.name_bytes] if self.learned
                else ["members", list(self.members)])


def family_template(key: str) -> str:
    """``key`` with its family placeholder: ``{key}`` as given, or the single ``*`` chunk
    replaced by ``{key}``; raises ValueError when it has neither (or several ``*``)."""
    if "{" + KEY + "}" in key:
        return key
    chunks = key.split("/")
    stars = [i for i, c in enumerate(chunks) if c == "*"]
    if len(stars) != 1:
        raise ValueError(f"a keyed channel's input {key!r} needs {{key}} or exactly one '*' "
                         "chunk (the member)")
    chunks[stars[0]] = "{" + KEY + "}"
    return "/".join(chunks)


def has_wildcard(key: str) -> bool:
    """True when a Zenoh key expression matches more than one key."""
    return any(c in ("*", "**") or "$*" in c for c in key.split("/"))


def member_pattern(concrete_template: str) -> re.Pattern[str]:
    """A regex matching the concrete keys of a template whose only placeholder left is
    ``{key}``; group 1 is the member."""
    head, _, tail = concrete_template.partition("{" + KEY + "}")
    return re.compile(re.escape(head) + r"([^/*$#?]+)" + re.escape(tail))


@dataclass(frozen=True)
class NameCodec:
    """The ``@key`` system entry: names member ``member`` of learned family ``family``.

    Fields, most significant first: family (``family_bits``), member (``member_bits``), name
    (``8 * name_bytes`` bits, UTF-8, zero padded).
    """

    index: int
    families: tuple[int, ...]  # channel index of each learned family, in mission order
    member_bits: int
    name_bytes: int
    name: str = "@key"
    repeatable: bool = True
    priority: int = NAME_PRIORITY

    @cached_property
    def family_bits(self) -> int:
        return index_bits(len(self.families))

    @property
    def wire_bits(self) -> int:
        return self.family_bits + self.member_bits + 8 * self.name_bytes

    def pack(self, channel: int, member: int, name: str) -> int:
        raw = name.encode()
        if len(raw) > self.name_bytes:
            raise ValueError(f"member name {name!r} is longer than {self.name_bytes} bytes")
        n = (self.families.index(channel) << self.member_bits) | member
        return (n << 8 * self.name_bytes) | int.from_bytes(raw.ljust(self.name_bytes, b"\0"),
                                                           "big")

    def unpack(self, n: int) -> tuple[int, int, str]:
        """``(channel index, member, name)``; raises ValueError when malformed."""
        name_bits = 8 * self.name_bytes
        raw = (n & ((1 << name_bits) - 1)).to_bytes(self.name_bytes, "big").rstrip(b"\0")
        n >>= name_bits
        member = n & ((1 << self.member_bits) - 1)
        family = n >> self.member_bits
        if family >= len(self.families):
            raise ValueError(f"names a member of unknown family {family}")
        try:
            name = raw.decode()
        except UnicodeDecodeError:
            raise ValueError("member name is not UTF-8") from None
        if not name or member_pattern("{key}").fullmatch(name) is None:
            raise ValueError(f"bad member name {name!r}")
        return self.families[family], member, name


def name_codec(index: int, learned: Sequence[tuple[int, FamilySpec]]) -> NameCodec | None:
    """The ``@key`` entry for the learned families ``(channel index, spec)``, if any."""
    if not learned:
        return None
    return NameCodec(index=index, families=tuple(i for i, _ in learned),
                     member_bits=max(s.index_bits for _, s in learned),
                     name_bytes=max(s.name_bytes for _, s in learned))
