"""``zab put --mission``: a value checked against the channels that read its key before it
is sent, so an operator's typo is refused in one line rather than dropped by the bridge.

Two checks, against every channel element whose input key (at any of its senders) is the
key: a field name that none of them reads (:mod:`bridge.wire.unused`, named with the names
they read there), and a value that none of them can pack (the first one's reason: a DCCL
message's missing required field, a number where a map is read...). Keys no channel reads,
ROS 2 topics (their type is in the key: :func:`bridge.cli.poke.payload_for`), key families
and pictures are not checked.
"""

from __future__ import annotations

from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import EncodeError
from bridge.wire.channels import ChannelCodec, ElementCodec
from bridge.wire.unused import schema_tree, union, unread

__all__ = ["problem_with", "readers"]


def readers(loaded: LoadedMission, key: str) -> list[tuple[ChannelCodec, ElementCodec]]:
    """The channel elements that take their values from ``key`` (at some sender)."""
    return [(channel, element) for channel in loaded.table.channels
            if channel.family is None and channel.image is None
            for element in channel.elements if element.ros2 is None
            and any(element.input_key(node) == key for node in channel.senders)]


def problem_with(loaded: LoadedMission, key: str, value: Any) -> str | None:
    """Why no channel reading ``key`` can take ``value`` (one line), or None."""
    found = readers(loaded, key)
    if not found:
        return None
    tree = union(schema_tree(element.layout.json_schema()) for _, element in found)
    if (unknown := next(unread(value, tree), None)) is not None:
        path, names = unknown
        parent, _, name = path.rpartition(".")
        channels = " and ".join(repr(channel.name) for channel, _ in found)
        return f"channel {channels} {'have' if len(found) > 1 else 'has'} no field {name!r}" \
            f"{f' in {parent}' if parent else ''} (its fields{' there' if parent else ''}: " \
            f"{', '.join(names)})"
    reasons = []
    for channel, element in found:
        try:
            element.layout.pack(value)
        except EncodeError as exc:
            reasons.append(f"channel {channel.name!r}: {exc}")
            continue
        return None
    return reasons[0]
