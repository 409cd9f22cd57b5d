"""What travels beside a value (pure): a tombstone, the encoding the application used, its
attachment and the value's age, as fields the bridge appends to an element's layout.

A channel opts in (``deletes``, ``attachment_bytes``, ``age``; an element's ``encoding:
as_sent``); then each of its elements' layouts ends with these fields, in this order, so the
frame codec carries them like any field and nothing else changes on the wire:

==========  ===============================  ==================================================
field       bits                             meaning
==========  ===============================  ==================================================
_zab_del    1                                the key was deleted (the element's fields then
                                             hold their lowest values, and mean nothing)
_zab_enc    2                                the application's encoding: 0 msgpack, 1 JSON,
                                             2 JSON as text/plain, 3 JSON untagged
_zab_att    ⌈log2(n + 1)⌉ + 8·n              the application's attachment (its length, then n
                                             bytes), n = ``attachment_bytes``
_zab_age    ⌈log2(s + 1)⌉                    whole steps of ``age.step_s`` since the value was
                                             taken (rounded; s = the most, meaning at least)
==========  ===============================  ==================================================

The age is last, so it is the element's lowest bits: the sender packs 0 when the value arrives
and writes the age when it builds each frame (:meth:`SampleMeta.aged`). The receiver strips
these fields (:meth:`SampleMeta.read`) before it publishes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

from bridge.codec import Layout
from bridge.errors import DecodeError
from bridge.wire.payloads import encode_payload

DELETED = "_zab_del"
ENCODING = "_zab_enc"
ATTACHMENT = "_zab_att"
AGE = "_zab_age"
HIDDEN = frozenset({DELETED, ENCODING, ATTACHMENT, AGE})

APPLICATION_SEPARATOR = b"\x00"
"""In a bridge's attachment, before the sending application's (where a channel carries it)."""

ENCODINGS = ("msgpack", "json", "text", "bytes")
"""The encodings ``as_sent`` tells apart, by id; ``text`` and ``bytes`` are JSON text published
as ``text/plain`` and untagged (``zenoh/bytes``)."""
_ZENOH = {"text": "text/plain", "bytes": "zenoh/bytes"}


def encoding_id(encoding: str, data: bytes) -> int:
    """The id of the encoding a sample came with: msgpack, JSON, JSON as text/plain, or
    untagged (an untagged payload is JSON text when its first byte is ASCII, as JSON text
    starts; else it was msgpack, published back as application/msgpack)."""
    kind = encoding.partition(";")[0]
    if kind in ("application/msgpack", "application/x-msgpack"):
        return 0
    if kind in ("application/json", "text/json"):
        return 1
    if kind == "text/plain":
        return 2
    return 3 if data[:1] < b"\x80" else 0


def encode_as(value: Any, encoding: str) -> tuple[bytes, str]:
    """Bytes and Zenoh encoding to publish ``value`` with, for any of :data:`ENCODINGS`."""
    if encoding in _ZENOH:
        return encode_payload(value, "json")[0], _ZENOH[encoding]
    return encode_payload(value, encoding)


@dataclass(frozen=True)
class Seen:
    """What the fields beside a received value said."""

    deleted: bool = False
    encoding: str | None = None
    attachment: bytes | None = None
    age_s: float | None = None


NOTHING = Seen()


def read_meta(channel: Any, elements: list[Any]) -> tuple[list[Any], list[Seen]]:
    """A received value's elements without the fields beside them, and what each said
    (``channel``: a :class:`~bridge.wire.channels.ChannelCodec`)."""
    metas = [e.meta for e in channel.elements]
    out: list[Any] = []
    seen: list[Seen] = []
    for meta, value in zip(metas, elements, strict=True):
        if meta is None:
            out.append(value)
            seen.append(NOTHING)
        else:
            plain, said = meta.read(value)
            out.append(plain)
            seen.append(said)
    return out, seen


@dataclass(frozen=True)
class SampleMeta:
    """The fields one element carries beside its value."""

    deletes: bool = False
    as_sent: bool = False
    attachment_bytes: int = 0
    age_step_s: float | None = None
    age_max_s: float = 0.0

    @property
    def age_steps(self) -> int:
        """The most steps the age field holds."""
        if self.age_step_s is None:
            return 0
        return max(1, math.ceil(self.age_max_s / self.age_step_s - 1e-9))

    @property
    def age_bits(self) -> int:
        return self.age_steps.bit_length()

    def fields(self) -> list[dict[str, Any]]:
        """The fields appended to the element's layout (as mission field specs)."""
        out: list[dict[str, Any]] = []
        if self.deletes:
            out.append({"field": DELETED, "type": "bool"})
        if self.as_sent:
            out.append({"field": ENCODING, "type": "enum", "values": list(ENCODINGS)})
        if self.attachment_bytes:
            out.append({"field": ATTACHMENT, "type": "bytes",
                        "max_length": self.attachment_bytes})
        if self.age_step_s is not None:
            out.append({"field": AGE, "type": "int", "min": 0, "max": self.age_steps})
        return out

    def aged(self, packed: int, age_s: float) -> int:
        """The element's packed value with its age field set to ``age_s``."""
        steps = min(max(round(age_s / self.age_step_s), 0), self.age_steps) \
            if self.age_step_s else 0
        return (packed >> self.age_bits << self.age_bits) | steps

    def read(self, value: dict[str, Any]) -> tuple[dict[str, Any], Seen]:
        """``value`` without the fields beside it, and what they said."""
        plain = {k: v for k, v in value.items() if k not in HIDDEN}
        attachment = value.get(ATTACHMENT)
        age = value.get(AGE)
        return plain, Seen(
            deleted=bool(value.get(DELETED, False)),
            encoding=value.get(ENCODING) if self.as_sent else None,
            attachment=bytes(attachment) if attachment else None,
            age_s=age * self.age_step_s if age is not None and self.age_step_s else None)


def stamped(value: Any, encoding: int, attachment: bytes | None) -> Any:
    """A sample's value with the fields the bridge carries beside it (a copy; the layouts of
    its channels take those they have). A value that is not a map cannot carry them."""
    if not isinstance(value, dict):
        raise DecodeError("a channel that carries deletes, encodings, attachments or ages "
                          "needs a map payload")
    return {**value, DELETED: False, ENCODING: ENCODINGS[encoding],
            ATTACHMENT: attachment or b"", AGE: 0}


@cache
def tombstone(layout: Layout) -> int:
    """An element of ``layout`` (one with ``deletes``) packed as deleted."""
    return layout.pack({**layout.unpack(0), DELETED: True})


def aged_payload(elements: Sequence[Any], packed: Sequence[int | None],
                 updated: Sequence[float | None], now: float) -> int:
    """A channel's bits, as a store holds them (each element's packed value and when it
    arrived), with each element's age field set to its age at ``now``; ``elements``: the
    channel's :class:`~bridge.wire.channels.ElementCodec`."""
    n = 0
    for element, value, since in zip(elements, packed, updated, strict=True):
        meta, value = element.meta, value or 0
        if meta is not None and meta.age_step_s is not None and since is not None:
            value = meta.aged(value, now - since)
        n = (n << element.layout.bits) | value
    return n
