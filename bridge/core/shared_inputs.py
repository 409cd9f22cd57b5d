"""Input keys that two nodes read alike: a warning where vehicles surface.

Under water each node's Zenoh is its own, so ``in: status`` on auv1 and on auv2 are two keys.
With ``surfacing``, a surfaced vehicle's Zenoh joins the surface's, and with two vehicles up at
once every node's keys are one space: auv1's bridge would take auv2's ``status`` as its own,
send it as auv1's and keep it latched after the dive, and Zenoh gives no way to tell whose
application put a sample. So a mission with ``surfacing`` must give each node's inputs keys of
its own, the sender named in them (``in: "{node}/status"``, as the deploy kit's access control
also requires: a vehicle may publish only under its own name). ``zab check`` warns rather than
refuses: a mission whose vehicles surface one at a time (``zab demo``'s tour) is not wrong.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from bridge.core.interest import intersects
from bridge.mission.loader import Loc, format_loc
from bridge.mission.model import Mission
from bridge.wire.channels import ChannelTable

__all__ = ["keys_read_alike", "shared_input_warnings", "shared_inputs"]


@dataclass(frozen=True)
class _Read:
    """One input key a node reads, and where the mission sets it."""

    node: str
    key: str
    loc: Loc
    channel: str


def _reads(mission: Mission, table: ChannelTable) -> Iterator[_Read]:
    images = {image.name: i for i, image in enumerate(mission.images)}
    for channel in table.channels:
        image = channel.image
        if image is not None:
            if not image.control:
                for node in channel.senders:
                    yield _Read(node, image.input_key(node), ("images", images[image.name],
                                                               "in"), image.name)
            continue
        for i, element in enumerate(channel.elements):
            loc: Loc = ("channels", channel.index, "elements", i,
                        "in" if element.ros2 is None else "ros2")
            for node in channel.senders:
                yield _Read(node, element.input_key(node), loc, channel.name)


def shared_inputs(mission: Mission, table: ChannelTable) -> Iterator[tuple[_Read, _Read]]:
    """Each pair of input keys two nodes read alike (the earlier in the mission first), once
    per pair of places in the mission."""
    reads = list(_reads(mission, table))
    told: set[tuple[Loc, Loc]] = set()
    for j, later in enumerate(reads):
        for earlier in reads[:j]:
            if earlier.node == later.node or (earlier.loc, later.loc) in told \
                    or not intersects(earlier.key, later.key):
                continue
            told.add((earlier.loc, later.loc))
            yield earlier, later


def shared_input_warnings(mission: Mission, table: ChannelTable) -> Iterator[str]:
    """``zab check``'s warning, with its place, for each input key two nodes read alike, in a
    mission with ``surfacing`` (none without)."""
    if mission.surfacing is None:
        return
    for earlier, later in shared_inputs(mission, table):
        same = "" if earlier.loc == later.loc else f" (channel {earlier.channel!r})"
        yield (f"{format_loc(later.loc)}: {earlier.node} and {later.node} both read "
               f"{later.key!r}{same}: with surfacing, two vehicles up at once share one "
               f"Zenoh, and each bridge would take the other's samples as its own; name "
               f"the sender in the key, e.g. '{{node}}/{later.key}'")


def keys_read_alike(mission: Mission, table: ChannelTable, node: str, peer: str) -> list[str]:
    """The input keys of ``node`` that ``peer`` reads alike (sorted, each once)."""
    return sorted({(a if a.node == node else b).key for a, b in shared_inputs(mission, table)
                   if {a.node, b.node} == {node, peer}})
