"""What happened at a node, as typed events (pure data, in the spirit of h11's ``_events``).

:class:`~bridge.core.node.NodeCore` outputs one of these for each runtime event (a frame sent,
heard or dropped, a link change, a range, a fix, a delivery report …); the runtime adds
:class:`ModemDown` and :class:`ModemUp`. In-process observers ``match`` on the classes. Where
an event leaves the process (``@zab/<mission>/<node>/events``, the MCAP logbook, the GUI feed)
it becomes the map :meth:`Event.to_dict` returns, named by the class's :attr:`Event.kind`: the
wire names (``frame_sent``, ``bytes``, ``src`` …) live only there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from bridge.frozen import direct_init

if TYPE_CHECKING:  # not imported at run time: the tracker pulls in numpy
    from bridge.ranging.localise import Fix, NoFix
    from bridge.ranging.tracker import Estimate

__all__ = [
    "Delivery", "Event", "FieldsLeftOut", "FrameDropped", "FrameReceived", "FrameRelayed",
    "FrameSent", "Link", "LinkSwitched", "MissionMismatch", "ModemDown", "ModemUp", "PayloadDrops",
    "PeerLink", "PeerRestarted", "PicturePublished", "Position", "Range", "RangeFailed",
    "RouteSwitched", "SendFailed",
    "StateSaving", "Surfaced", "UnmappedKey", "notable",
]


@dataclass(frozen=True, slots=True)
class Event:
    """Base of every event; ``time`` is the node's clock when it happened."""

    kind: ClassVar[str]
    """The event's name on the wire (a ``kind`` field, an MCAP topic)."""

    time: float

    def to_dict(self) -> dict[str, Any]:
        """The event as plain data, with its wire field names (bytes stay bytes)."""
        raise NotImplementedError


@dataclass(frozen=True, slots=True)
class PayloadDrops(Event):
    """Samples on input keys that could not be used since the last such event (a summary, at
    most one a second however many drops: see :mod:`bridge.core.drops`): per key and cause,
    how many and the first reason given."""

    kind: ClassVar[str] = "payload_drops"
    drops: tuple[tuple[str, str, int, str], ...]
    """``(key, cause, count, reason)`` each."""

    @property
    def total(self) -> int:
        return sum(count for _, _, count, _ in self.drops)

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "total": self.total,
                "drops": [{"key": key, "cause": cause, "count": count, "reason": reason}
                          for key, cause, count, reason in self.drops]}


@dataclass(frozen=True, slots=True)
class FieldsLeftOut(Event):
    """A sample on an input key had fields no channel carries: they do not cross (reported
    once per key and set of fields; counted per sample)."""

    kind: ClassVar[str] = "fields_left_out"
    key: str
    fields: list[str]

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "key": self.key, "fields": self.fields}


@dataclass(frozen=True, slots=True)
class UnmappedKey(Event):
    """An application put a key under this node's ``keyspace`` that no channel reads
    (reported once per key; counted per sample)."""

    kind: ClassVar[str] = "unmapped_key"
    key: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "key": self.key}


@direct_init
@dataclass(frozen=True, slots=True)
class FrameSent(Event):
    """The modem accepted a frame of ``size`` bytes carrying ``channels`` (``dest``: its
    unicast destination, None = broadcast)."""

    kind: ClassVar[str] = "frame_sent"
    size: int
    channels: list[str]
    dest: str | None
    data: bytes
    link: str | None = None  # with several links: the one it went out on

    def to_dict(self) -> dict[str, Any]:
        out = {"time": self.time, "bytes": self.size, "channels": self.channels,
               "dest": self.dest, "data": self.data}
        if self.link is not None:
            out["link"] = self.link
        return out


@dataclass(frozen=True, slots=True)
class FrameRelayed(Event):
    """This node carried on a frame of ``origin`` (``size`` bytes, ``hops`` relays so far)
    over ``link`` (``dest``: its next hop, None = broadcast)."""

    kind: ClassVar[str] = "frame_relayed"
    origin: str
    size: int
    link: str
    dest: str | None
    hops: int

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "origin": self.origin, "bytes": self.size,
                "link": self.link, "dest": self.dest, "hops": self.hops}


@dataclass(frozen=True, slots=True)
class SendFailed(Event):
    """The modem refused a frame (its data stays due)."""

    kind: ClassVar[str] = "send_failed"
    error: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "error": self.error}


@direct_init
@dataclass(frozen=True, slots=True)
class FrameReceived(Event):
    """A frame from ``src`` decoded: the channels it carried for this node, the element
    values it completed (``members``: per member of a key family; a picture's fragment
    completes none), with the link metadata."""

    kind: ClassVar[str] = "frame_received"
    src: str
    size: int
    channels: list[str]
    data: bytes
    meta: dict[str, Any]
    values: dict[str, list[dict[str, Any]]]
    members: dict[str, dict[str, list[dict[str, Any]]]] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {"time": self.time, "src": self.src, "bytes": self.size, "channels": self.channels,
               "data": self.data, "meta": self.meta, "values": self.values}
        if self.members:
            out["members"] = self.members
        return out


@direct_init
@dataclass(frozen=True, slots=True)
class PicturePublished(Event):
    """A receiving bridge published a picture of an image channel from ``src`` on ``key``,
    decoded from the stream so far, with ``meta`` in it: the stream's bytes from ``start``
    that the events before had not carried (for the mission log: ``zab log replay`` decodes
    and publishes each picture again, a few dozen bytes logged a refinement, not the file)."""

    kind: ClassVar[str] = "picture_published"
    channel: str
    src: str
    key: str
    start: int
    data: bytes
    meta: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "channel": self.channel, "src": self.src, "key": self.key,
                "start": self.start, "data": self.data, "meta": self.meta}


@dataclass(frozen=True, slots=True)
class FrameDropped(Event):
    """A frame (or a transfer it completed) could not be used: ``reason`` is the counter it
    went to (``check``, ``mission_mismatch``, ``unknown_source``, ``malformed`` …)."""

    kind: ClassVar[str] = "frame_dropped"
    src: str | None
    reason: str
    error: str | None = None
    data: bytes | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"time": self.time, "src": self.src, "reason": self.reason}
        if self.error is not None:
            out["error"] = self.error
        if self.data is not None:
            out["data"] = self.data
        return out


@dataclass(frozen=True, slots=True)
class PeerRestarted(Event):
    """``peer``'s frames carry a new epoch (``was`` before): it started without its state."""

    kind: ClassVar[str] = "peer_restarted"
    peer: str
    epoch: int
    was: int

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "epoch": self.epoch, "was": self.was}


@dataclass(frozen=True, slots=True)
class MissionMismatch(Event):
    """``peer`` runs another mission file: its frame fingerprint is not ``ours`` (hex)."""

    kind: ClassVar[str] = "mission_mismatch"
    peer: str
    fingerprint: str
    ours: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "fingerprint": self.fingerprint,
                "ours": self.ours}


@dataclass(frozen=True, slots=True)
class Delivery(Event):
    """A reliable value's state changed (``queued``, ``sent``, ``delivered``, ``failed``)."""

    kind: ClassVar[str] = "delivery"
    channel: str
    id: int
    dst: str | None
    state: str
    reason: str | None = None
    attempts: int = 0
    key: str | None = None
    ref: str | None = None
    sequence: int | None = None
    """An image channel's picture sequence number (the ``zab:sequence`` its pictures carry)."""

    def to_dict(self) -> dict[str, Any]:
        out = {"channel": self.channel, "id": self.id, "dst": self.dst, "state": self.state,
               "reason": self.reason, "attempts": self.attempts, "time": self.time,
               "key": self.key, "ref": self.ref}
        if self.sequence is not None:
            out["sequence"] = self.sequence
        return out


@dataclass(frozen=True, slots=True)
class RangeFailed(Event):
    """A range asked of the modem failed."""

    kind: ClassVar[str] = "range_failed"
    peer: str
    error: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "error": self.error}


@dataclass(frozen=True, slots=True)
class Range(Event):
    """A range to ``peer`` (``method``: how it was measured)."""

    kind: ClassVar[str] = "range"
    peer: str
    range_m: float
    travel_time_s: float
    sound_speed_mps: float
    method: str
    sound_speed_source: str

    def to_dict(self) -> dict[str, Any]:  # the published ``time`` is when it was reported
        return {"peer": self.peer, "range_m": self.range_m, "time": self.time,
                "travel_time_s": self.travel_time_s, "sound_speed_mps": self.sound_speed_mps,
                "method": self.method, "sound_speed_source": self.sound_speed_source}


@dataclass(frozen=True, slots=True)
class Position(Event):
    """Where this node is: the tracker's ``estimate``, a snapshot :class:`Fix`, or a
    :class:`NoFix` saying why there is none."""

    kind: ClassVar[str] = "position"
    estimate: Estimate | Fix | NoFix

    @property
    def xy(self) -> tuple[float, float, float | None] | None:
        """``(x, y, sigma_m)`` when there is a position, else None."""
        from bridge.ranging.localise import Fix
        from bridge.ranging.tracker import Estimate

        found = self.estimate
        if isinstance(found, Fix) or (isinstance(found, Estimate) and found.has_position):
            return found.x, found.y, found.sigma_m
        return None

    def to_dict(self) -> dict[str, Any]:
        return self.estimate.payload(self.time)


@direct_init  # (built at every change of a link: often, in a big fleet)
@dataclass(frozen=True, slots=True)
class Link(Event):
    """The link to ``peer`` changed state (``up``, ``degraded``, ``down``)."""

    kind: ClassVar[str] = "link"
    peer: str
    state: str
    last_heard: float | None
    silent_s: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "state": self.state,
                "last_heard": self.last_heard, "silent_s": self.silent_s}


@direct_init
@dataclass(frozen=True, slots=True)
class PeerLink(Event):
    """With several links: ``peer``'s state on ``link`` changed (:class:`Link` is its state
    over any link, or through relays)."""

    kind: ClassVar[str] = "peer_link"
    peer: str
    link: str
    state: str
    last_heard: float | None
    silent_s: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "link": self.link, "state": self.state,
                "last_heard": self.last_heard, "silent_s": self.silent_s}


@dataclass(frozen=True, slots=True)
class LinkSwitched(Event):
    """Traffic to ``peer`` moved from link ``was`` (None: none yet) to ``link`` (None: no
    link reaches it now), because ``reason`` (``failover``, ``failback``)."""

    kind: ClassVar[str] = "link_switched"
    peer: str
    link: str | None
    was: str | None
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "link": self.link, "was": self.was,
                "reason": self.reason}


@dataclass(frozen=True, slots=True)
class RouteSwitched(Event):
    """Traffic to ``peer`` moved from next hop ``was`` to ``via`` among the hops its route
    lists, because ``reason`` (``failover``, ``failback``)."""

    kind: ClassVar[str] = "route_switched"
    peer: str
    via: str
    was: str
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "peer": self.peer, "via": self.via, "was": self.was,
                "reason": self.reason}


@dataclass(frozen=True, slots=True)
class Surfaced(Event):
    """``peer``'s bridge became reachable over IP (``ip``) or stopped being so."""

    kind: ClassVar[str] = "surfaced"
    peer: str
    ip: bool

    def to_dict(self) -> dict[str, Any]:
        return {"peer": self.peer, "ip": self.ip, "time": self.time}


@dataclass(frozen=True, slots=True)
class ModemDown(Event):
    """The modem failed or could not be opened: an outage begins (the runtime retries, with
    no event until :class:`ModemUp`)."""

    kind: ClassVar[str] = "modem_down"
    error: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "error": self.error}


@dataclass(frozen=True, slots=True)
class ModemUp(Event):
    """The modem is ready again after :class:`ModemDown`: down ``down_s`` seconds, in which
    ``retries`` more tries to open it failed."""

    kind: ClassVar[str] = "modem_up"
    down_s: float
    retries: int

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "down_s": round(self.down_s, 3), "retries": self.retries}


@dataclass(frozen=True, slots=True)
class StateSaving(Event):
    """The runtime's saves of the node's state started failing (``error``: why) or work again
    (``error`` None); ``since``: when they started failing."""

    kind: ClassVar[str] = "state_saving"
    error: str | None
    since: float

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "saved": self.error is None, "error": self.error,
                "since": self.since}


NOTABLE = (Link, FrameDropped, SendFailed, ModemDown, ModemUp, PayloadDrops, MissionMismatch,
           PeerRestarted, Surfaced, StateSaving, FieldsLeftOut, UnmappedKey, PeerLink,
           LinkSwitched, RouteSwitched)
"""Events also published on ``@zab/<mission>/<node>/events`` (with failed deliveries)."""


def notable(event: Event) -> bool:
    """Whether ``event`` belongs on ``…/events``."""
    return isinstance(event, NOTABLE) or (isinstance(event, Delivery) and event.state == "failed")
