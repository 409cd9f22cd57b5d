"""The receiving side of a node (pure): frames in, values and events out.

:meth:`Inbound.receive` checks where a frame comes from (a peer under the same mission file;
two frames in a row with the same foreign fingerprint say the peer runs another one, or in an
authenticated mission one whose tag a key holder made under it), decodes
it (authentication, replay window, check value), tells the MAC and the link what was heard,
follows the peer's epoch, and hands each entry to what it is for: values to publish (latest,
released by a reliable window, or reassembled from fragments), acknowledgements to the
sending side, family names, demand bitmaps and queries to theirs. DLBL delays go to ranging.

With several links or routes a frame starts with a network header
(:class:`~bridge.core.routing.Routing`): the frame is its *origin*'s, heard from a neighbour
(the origin itself, or a relay), on one of the node's links. What concerns the hop (the MAC,
the link's health, ranging) follows the neighbour; what the frame carries follows the origin
(its epoch, its streams, its authentication), and its channel entries are taken only when
the header says the frame serves this node.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from bridge.core.events import FrameDropped, FrameReceived, MissionMismatch, PeerRestarted
from bridge.core.families import Families
from bridge.core.images import Images
from bridge.core.interest import Interest
from bridge.core.link import Links, LinkState
from bridge.core.linkset import LinkSet, LinkSide
from bridge.core.outbound import Outbound
from bridge.core.outputs import Outbox
from bridge.core.queries import Queries
from bridge.core.ranges import Ranges
from bridge.core.receivers import Receivers
from bridge.core.reception import Reception
from bridge.core.routing import Arrival
from bridge.core.transfer import from_bytes
from bridge.errors import DecodeError, FrameError
from bridge.mission.model import Mission
from bridge.mission.presets import Preset
from bridge.wire.channels import AckCodec, ChannelCodec, ElementCodec, Values
from bridge.wire.families import NameCodec
from bridge.wire.frame import DecodedFrame, Entry, FrameCodec
from bridge.wire.interest import InterestCodec
from bridge.wire.marks import MarkCodec
from bridge.wire.queries import QueryCodec
from bridge.wire.sample_meta import NOTHING, read_meta

if TYPE_CHECKING:
    from bridge.core.network import NodeNetwork

__all__ = ["PEER_STATUS_S", "Inbound", "plain"]

log = logging.getLogger("zab.core")

PEER_STATUS_S = 1.0
"""Least time between two ``peers/<peer>`` status puts of one peer."""
STALE_SLACK_S = 0.25
"""How much older than the newest published a latest value may be taken and still be
published (two estimates of a frame's start differ by less)."""

Anchors = dict[str, tuple[float, float, float]]


class Inbound:
    """Decoding and acceptance of the frames one node hears."""

    def __init__(self, mission: Mission, node: str, codec: FrameCodec, outbox: Outbox,
                 linkset: LinkSet, links: Links, receivers: Receivers, outbound: Outbound,
                 queries: Queries | None, ranges: Ranges | None, sealed: bool,
                 network: NodeNetwork | None = None) -> None:
        """``sealed``: frames are authenticated (each moves a replay window); ``network``:
        frames carry the network header (several links or routes)."""
        self.mission = mission
        self.linkset = linkset
        self.network = network
        self.index = list(mission.nodes).index(node)
        self._takes = True  # the frame being read serves this node
        self.sealed = sealed
        self.node = node
        self.address = mission.address_of(node)
        self.codec = codec
        self.outbox = outbox
        self.stats = outbox.stats
        self.links = links
        self.receivers = receivers
        self.outbound = outbound
        self.families: Families = outbound.families
        self.interest: Interest | None = outbound.interest
        self.queries = queries
        self.ranges = ranges
        self.images: Images | None = None  # image channels (set by the node if it has some)
        self.received_at: dict[str, float] = {}
        self.mismatched: dict[str, str] = {}  # peers known to run another mission file
        self._foreign: dict[str, int] = {}  # a peer's last fingerprint not ours
        self._peer_status: dict[str, float] = {}  # when each peer's status was last put
        self.sent_at = 0.0
        """When the frame being decoded left its sender (:func:`frame_start`): its values'
        timestamps count back from it."""
        self._newest: dict[str, tuple[float, float]] = {}
        """Per output key of a latest-value channel: when the newest value published on it
        was taken, and this node's clock then (an older one that comes later is not
        published, unless this node's clock went back since)."""
        self._with_meta = {c.index for c in codec.table.channels if any(e.meta for e in
                                                                         c.elements)}

    def receive(self, rx: Reception, now: float, modem_now: float | None = None,
                side: LinkSide | None = None) -> None:
        """Decode one received frame (heard on ``side``, default the node's first link) and
        publish what it carries for this node (``modem_now``: the modem clock now, which DLBL
        times are in)."""
        self.linkset.news()  # (what this frame asks, or polls, may be sent at once)
        side = side or self.linkset.primary
        src = self._source(rx, now, side)
        if src is None:
            return
        network = self.network
        origin, arrival, address = src, None, rx.src
        start = frame_start(rx, side.info.preset_of(src))  # (when src sent it)
        if network is not None:  # (a copy sent again: its acknowledgements are owed again)
            arrival = network.routing.arrived(rx.data, src, now,
                                              functools.partial(self.receivers.again,
                                                                sent=start))
            if arrival is None:  # a copy of a frame taken already (or malformed): the hop
                self._hop(rx, src, side, now)
                return
            origin, address = arrival.origin, self.mission.address_of(arrival.origin)
        try:
            frame = self.codec.decode(rx.data, address, now) if arrival is None \
                else self.codec.decode(rx.data, address, now, arrival.start)
        except FrameError as exc:
            self.stats.frames_dropped[exc.reason] += 1
            self.outbox.event(FrameDropped(now, origin, exc.reason, str(exc), rx.data))
            return
        self._hop(rx, src, side, now)
        self._heard(origin, frame, now)
        self.sent_at = start
        if arrival is not None:  # the origin built it the header's age before this frame
            self.sent_at -= arrival.header.age
            network.routing.taken(arrival, rx.data, src, now,  # type: ignore[union-attr]
                                  reliable_entries(frame))
            self._takes = self.index in arrival.header.serves
        values: dict[str, Values] = {}
        anchors: Anchors = {}  # live anchor positions the frame carried
        members: dict[str, dict[str, Values]] = {}  # key families: per member
        carried: dict[str, None] = {}  # every channel it carried for us, values or not
        for entry in frame.entries:
            self._entry(origin, entry, now, values, anchors, members, carried)
        self._takes = True
        if self.ranges is not None and origin == src and side is self.linkset.primary:
            self.ranges.heard(src, rx, frame.delays, modem_now if modem_now is not None
                              else now, now, anchors)
        meta = plain(rx.meta)
        if arrival is not None:
            meta.update(_hop_meta(arrival, src, side))
        src = origin
        peer_status = self._peer_status
        if now - peer_status.get(src, -math.inf) >= PEER_STATUS_S:  # not every frame
            peer_status[src] = now
            self.outbox.status(f"peers/{src}", {"last_heard": now, "meta": dict(meta)})
        self.outbox.event(FrameReceived(now, src, len(rx.data), list(carried), rx.data, meta,
                                        values, members or None))

    def _source(self, rx: Reception, now: float, side: LinkSide) -> str | None:
        """The sender of ``rx`` if it is a peer under this mission file; else the frame is
        counted dropped (or foreign) and None."""
        src = self.mission.name_of(rx.src) if self.network is None else side.name_of(rx.src)
        codec = self.codec
        sender_print = codec.sender_fingerprint(rx.data)
        if sender_print != codec.fingerprint16 and sender_print is not None \
                and src != self.node:
            self._foreign_frame(src or f"address {rx.src}", sender_print, rx, now)
            return None
        if src is None or src == self.node:
            self.stats.frames_dropped["unknown_source"] += 1
            self.outbox.event(FrameDropped(now, src, "unknown_source", data=rx.data))
            return None
        return src

    def _hop(self, rx: Reception, src: str, side: LinkSide, now: float) -> None:
        """A frame heard from neighbour ``src`` on ``side``: its MAC and health record it."""
        address = self.address if self.network is None else side.address_of(self.node)
        side.schedule.on_heard(src, rx.dest == address, now)
        if self.network is not None:
            self.linkset.heard(side, src, now)
            self.links.heard(src, now)
            if self.links.states.get(src) is not LinkState.UP:
                self.links.update(now)

    def _heard(self, src: str, frame: DecodedFrame, now: float) -> None:
        """A valid frame of ``src`` (its origin): the counters, the link and the peer's epoch
        record it."""
        self.stats.frames_received += 1
        if self._foreign:
            self._foreign.pop(src, None)
        if self.mismatched:
            self._matched(src, now)
        links = self.links
        links.heard(src, now)
        if self.sealed:
            self.outbox.unsaved = True  # the replay window moved: saved before publishing
        epoch = frame.epoch
        if epoch is not None and self.receivers.peer_epochs.get(src) != epoch:
            known = self.receivers.epoch(src, epoch)
            if known is not None:  # src started without its saved state
                self.outbound.resync(src)
                self.families.forget(src)
                log.info("%s: %s started afresh (epoch %d -> %d): streams resynchronised",
                         self.node, src, known, epoch)
                self.outbox.event(PeerRestarted(now, src, epoch, known))
        if links.states.get(src) is not LinkState.UP:
            links.update(now)

    def _entry(self, src: str, entry: Entry, now: float, values: dict[str, Values],
               anchors: Anchors, members: dict[str, dict[str, Values]],
               carried: dict[str, None]) -> None:
        """One entry of a frame from ``src``: its values published and gathered, its channel
        in ``carried`` if it was for us (a picture's fragment too, which is no value)."""
        channel = entry.channel
        if not isinstance(channel, ChannelCodec):  # an acknowledgement or a system entry
            if isinstance(channel, AckCodec):
                self.outbound.on_ack(src, entry.header, now)
                if self.network is not None:  # (it may release frames a relay keeps)
                    self.network.acked(src, entry.header)
            else:
                self._system(src, channel, entry, now)
            return
        if src not in channel.senders:
            self.stats.frames_dropped["unexpected_sender"] += 1
            return
        if not self._takes or not channel.reaches(src, self.node):
            return  # overheard: addressed to others
        surfacing = self.outbound.surfacing
        if surfacing is not None and src in surfacing.reachable and not channel.stream:
            surfacing.duplicates += 1  # it reaches us over IP at full fidelity
            return
        if channel.image is not None and self.images is not None:
            taken = self.images.entry(src, channel, entry, now)
            if taken:
                carried[channel.name] = None
                self.stats.received_per_channel[channel.name] += taken
                self.received_at[channel.name] = now
            return
        if channel.fragmented:
            delivered = self._fragment(src, channel, entry, now)
        elif channel.reliable:
            delivered = self.receivers.entry(src, channel, entry.header, entry.values)
        else:
            assert entry.values is not None  # (a latest value always has its values)
            delivered = [entry.values]
        member = "*"
        if channel.family is not None:
            name = self.families.member_name(src, channel, entry.header[0])
            if name is None:  # a learned member whose @key entry has not arrived yet
                self.stats.frames_dropped["unknown_member"] += 1
                return
            member = name
        for elements in delivered:
            carried[channel.name] = None
            self._deliver(src, channel, member, elements, now, values, anchors, members)

    def _deliver(self, src: str, channel: ChannelCodec, member: str, elements: Values,
                 now: float, values: dict[str, Values], anchors: Anchors,
                 members: dict[str, dict[str, Values]]) -> None:
        """One value of ``channel`` from ``src`` (``member`` of its family): published."""
        cname, family, latching = channel.name, channel.family, channel.latching
        seen = None
        if channel.index in self._with_meta:
            elements, seen = read_meta(channel, elements)
        values[cname] = elements
        if family is not None:
            members.setdefault(cname, {})[member] = elements
        self.stats.received_per_channel[cname] += 1
        self.received_at[cname] = now
        for i, (element, value) in enumerate(zip(channel.elements, elements, strict=True)):
            key = element.output_key(src, self.node, member)
            said = seen[i] if seen is not None else NOTHING
            encoding = said.encoding or element.encoding
            taken = self.sent_at - (said.age_s or 0.0)
            if not channel.stream and self._stale(key, taken, element, now):
                continue
            if family is not None:
                self.families.arrived(key, now)
            if latching and self.queries is not None:
                self.queries.remember(key, None if said.deleted else value, encoding, taken)
            if self.ranges is not None and not said.deleted:
                self.ranges.anchor_value(key, value, anchors, now)
            self.outbox.publish(key, None if said.deleted else value, encoding, latching,
                                element.ros2, taken, said.deleted, said.attachment, src)

    def _stale(self, key: str, taken: float, element: ElementCodec, now: float) -> bool:
        """Whether a latest value on output ``key``, taken at ``taken``, is older than one
        published there already (beyond the timing's slack and its age's step, and with this
        node's clock not gone back since: its times count from it): then it is counted, not
        published. A relay that fell behind delivered minutes-old values after newer ones had
        come directly, rolling back what a subscriber holds."""
        newest = self._newest.get(key)
        if newest is not None and now >= newest[1]:
            step = element.meta.age_step_s if element.meta is not None else None
            if taken < newest[0] - STALE_SLACK_S - (step or 0.0):
                self.stats.values_stale += 1
                return True
            if taken <= newest[0]:
                return False
        self._newest[key] = (taken, now)
        return False

    def _fragment(self, src: str, channel: ChannelCodec, entry: Entry,
                  now: float) -> list[Values]:
        """A fragment: the value it completes, if any, with the transfer's progress out."""
        data, progress = self.receivers.fragment(src, channel, entry.header, entry.chunk)
        self.outbox.status(f"transfer/{channel.name}", {**progress, "peer": src, "time": now})
        if data is None:
            return []
        try:
            return [channel.unpack(from_bytes(channel, data))]
        except DecodeError as exc:
            self.stats.frames_dropped["malformed"] += 1
            self.outbox.event(FrameDropped(now, src, "malformed",
                                           f"transfer on {channel.name!r}: {exc}"))
            return []

    def _system(self, src: str, channel: NameCodec | InterestCodec | QueryCodec | MarkCodec,
                entry: Entry, now: float) -> None:
        """An ``@key``, ``@want``, query or ``@mark`` entry from ``src``."""
        if isinstance(channel, NameCodec):
            self.families.on_name(src, entry.header)
        elif isinstance(channel, InterestCodec):
            if self.interest is not None:
                self.interest.on_heard(src, entry.header, now)
        elif isinstance(channel, QueryCodec):
            if self.queries is not None:
                if channel.reply:
                    self.queries.on_reply(src, channel, entry.header, entry.values, now)
                else:  # (the time left a request carries counts from when its frame left)
                    self.queries.on_request(src, channel, entry.header, entry.values, now,
                                            self.sent_at)
        else:  # an @mark: a peer refused our frames as replayed
            peer, mark = entry.header
            auth = self.codec.auth
            if self.codec.table.nodes[peer] == self.node and auth is not None \
                    and auth.resume_past(mark):
                log.info("%s: %s refused its frames as replayed: its counter resumes past %d",
                         self.node, src, mark)

    def _foreign_frame(self, src: str, fingerprint: int, rx: Reception, now: float) -> None:
        """A frame whose check gives another fingerprint: corrupt, or sent with another
        mission file — the same fingerprint twice in a row from one sender says which; in an
        authenticated mission, only a tag a key holder made under that fingerprint does."""
        if self.sealed:
            mismatch = self.codec.vouch(rx.data, rx.src, fingerprint) is not None
        else:
            mismatch = self._foreign.get(src) == fingerprint
            self._foreign[src] = fingerprint
        reason = "mission_mismatch" if mismatch else "check"
        self.stats.frames_dropped[reason] += 1
        self.outbox.event(FrameDropped(now, src, reason,
                                       f"check failed (fingerprint {fingerprint:04x})", rx.data))
        text = f"{fingerprint:04x}"
        if mismatch and self.mismatched.get(src) != text:
            self.mismatched[src] = text
            ours = f"{self.codec.fingerprint16:04x}"
            log.warning("%s: peer %s runs a different mission file (fingerprint %s, ours %s): "
                        "its frames are dropped", self.node, src, text, ours)
            event = MissionMismatch(now, src, text, ours)
            self.outbox.status(f"mismatch/{src}", event.to_dict())
            self.outbox.event(event)

    def _matched(self, src: str, now: float) -> None:
        """A frame of this mission file from ``src``: it no longer runs another one."""
        if self.mismatched.pop(src, None) is not None:
            log.warning("%s: peer %s runs this mission file again", self.node, src)
            self.outbox.status(f"mismatch/{src}", {"time": now, "peer": src, "fingerprint": None,
                                                   "ours": f"{self.codec.fingerprint16:04x}"})


def frame_start(rx: Reception, preset: Preset | None) -> float:
    """When ``rx``'s frame left its sender, as well as the receiver can tell: the end of the
    reception less the frame's airtime and travel time (the modem's figures when it gives
    them, else the sender's preset and none)."""
    meta = rx.meta
    airtime, travel = meta.get("airtime_s"), meta.get("travel_time_s")
    if airtime.__class__ is not float and not isinstance(airtime, int | float):
        airtime = preset.airtime(len(rx.data)) if preset is not None else 0.0
    if travel.__class__ is not float and not isinstance(travel, int | float):
        travel = 0.0
    return rx.time - airtime - travel


def reliable_entries(frame: DecodedFrame) -> frozenset[tuple[int, int]]:
    """The (channel index, seq) of the reliable values ``frame`` carries."""
    return frozenset((e.channel.index, e.header[0]) for e in frame.entries
                     if isinstance(e.channel, ChannelCodec) and e.channel.reliable
                     and not e.channel.fragmented)


def _hop_meta(arrival: Arrival, src: str, side: LinkSide) -> dict[str, Any]:
    """What a frame's network header adds to its reception's metadata."""
    meta: dict[str, Any] = {"link": side.name}
    header = arrival.header
    if header.routed:
        meta.update({"via": src, "hops": header.hops, "age_s": header.age})
    return meta


_SCALARS = (int, float, str, bool, type(None))
_PLAIN_TYPES = frozenset(_SCALARS)  # exactly these (not subclasses): plain already


def plain(meta: Mapping[str, Any]) -> dict[str, Any]:
    """Link metadata reduced to msgpack-able scalars (a copy when it is plain already, as a
    simulator's is: its types are checked first)."""
    for k, v in meta.items():
        if k.__class__ is not str or v.__class__ not in _PLAIN_TYPES:
            return {str(k): v for k, v in meta.items() if isinstance(v, _SCALARS)}
    return dict(meta)
