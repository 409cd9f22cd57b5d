"""``zab put --mission``: a value checked against the channels that read its key before it
is sent, so an operator's typo is refused in one line rather than dropped by the bridge.

Two checks, against every channel element whose input key (at any of its senders) is the
key: a field name that none of them reads (:mod:`bridge.wire.unused`, named with the names
they read there), and a value that none of them can pack (the first one's reason: a DCCL
message's missing required field, a number where a map is read...). An image channel's
control key is checked as the bridge checks a control (:func:`bridge.core.images.fit_control`);
on a camera's input key, which takes JPEG or PNG bytes, a put (JSON) is refused. Keys no
channel reads, ROS 2 topics (their type is in the key: :func:`bridge.cli.poke.payload_for`)
and key families are not checked.
"""

from __future__ import annotations

from typing import Any

from bridge.core.images import control_keys, fit_control, settings_of
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


def image_problem(loaded: LoadedMission, key: str, value: Any) -> str | None:
    """Why an image channel reading ``key`` (a control key at a receiver, a camera's input)
    cannot take ``value`` (one line), or None (none reads it, or it fits)."""
    for node in loaded.mission.nodes:
        found = control_keys(loaded.table, node).get(key)
        if found is not None:
            channel, camera = found
            assert channel.image is not None
            try:
                fit_control(channel, camera, settings_of({}, channel.image), value)
            except ValueError as exc:
                return str(exc)
            return None
    for channel in loaded.table.channels:
        spec = channel.image
        if spec is not None and not spec.control and spec.ros2 is None \
                and any(spec.input_key(camera) == key for camera in channel.senders):
            return (f"image channel {spec.name!r} takes pictures there: JPEG or PNG bytes "
                    "(image/jpeg, image/png), which zab put does not send (it puts a JSON "
                    "value as msgpack); a camera program puts them")
    return None


def problem_with(loaded: LoadedMission, key: str, value: Any) -> str | None:
    """Why no channel reading ``key`` can take ``value`` (one line), or None."""
    if (problem := image_problem(loaded, key, value)) is not None:
        return problem
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
