"""The mission file: one YAML document that every node of a deployment loads.

These pydantic models ARE the file format (``zab schema`` turns them into JSON Schema).
Times are seconds and say so in their names (``interval_s``, ``slot_s``). Unknown keys are
errors everywhere except in a node's ``zenoh`` section, whose extra keys pass through to the
Zenoh JSON5 configuration (``"transport/link/tx/lease": 2000``).
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    AwareDatetime,
    ConfigDict,
    Discriminator,
    Field,
    ModelWrapValidatorHandler,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    Tag,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from bridge.mission.base import MissionModel
from bridge.mission.endpoints import endpoint_problem
from bridge.mission.fields import FieldSpec
from bridge.mission.images import ImageChannel
from bridge.mission.keyexpr import AnyTemplateKey, FixedKey, NodeTemplateKey, PeerTemplateKey
from bridge.mission.ros2 import Ros2Topic

NodeName = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_-]*$", max_length=32)]


def route_hops(route: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """The next hops of one route of ``routes`` (a name, or names best first)."""
    return (route,) if isinstance(route, str) else tuple(route)


def route_text(route: str | list[str]) -> str:
    """One route as every node must agree on it: a name, or names best first joined by
    ``|`` (part of the mission fingerprint)."""
    return "|".join(route_hops(route))


def listed_routes(mission: Mission) -> bool:
    """Whether some node's route lists several hops."""
    return any(len(route_hops(hop)) > 1 for node in mission.nodes.values()
               for hop in node.routes.values())


NodePattern = Annotated[
    str | list[str],
    Field(description="A node name, a list of names, or a regular expression matching names."),
]


class Strict(MissionModel):
    """Base of every mission model: unknown keys are errors (and numbers finite)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


def _checked(listen: bool) -> AfterValidator:
    """A validator of one endpoint (Zenoh's own refusal does not name it)."""
    def check(endpoint: str) -> str:
        if (why := endpoint_problem(endpoint, listen=listen)) is not None:
            raise ValueError(why)
        return endpoint
    return AfterValidator(check)


ListenEndpoint = Annotated[str, _checked(listen=True)]
ConnectEndpoint = Annotated[str, _checked(listen=False)]


class ZenohSettings(MissionModel):
    """How a node opens its Zenoh session. Extra keys are Zenoh config paths, passed through."""

    model_config = ConfigDict(extra="allow")

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[ListenEndpoint] = Field(
        default_factory=list, description="Endpoints, e.g. tcp/127.0.0.1:7501"
    )
    connect: list[ConnectEndpoint] = Field(default_factory=list)

    def passthrough(self) -> dict[str, Any]:
        """Extra keys, inserted verbatim into the Zenoh configuration."""
        return dict(self.model_extra or {})


class Position(Strict):
    """A static position in metres: x east, y north, depth down (used by the simulator)."""

    x: float = 0.0
    y: float = 0.0
    depth: float = Field(0.0, ge=0.0)


class NodePath(Strict):
    """A scripted route for the simulated ocean: waypoints sailed in order at ``speed_mps``."""

    waypoints: list[Position] = Field(min_length=1, description="Points (x, y, depth) in metres.")
    speed_mps: float = Field(gt=0, le=100, description="Speed along the route, m/s.")
    loop: bool = Field(False, description="Sail back to the first waypoint and go round again; "
                       "otherwise stop at the last.")


BROADCAST_DESCRIPTION = (
    "The address that means every node, on the modem and in what it hears; default: the "
    "backend's convention (micromodem 0, Goby's BROADCAST_ID; evologics 255; sim none). "
    "Every node must agree on it, and no node may have it as its address (zab check).")


OPTIONS_DESCRIPTION = (
    "The backend's options (docs/backends.md has each backend's table); a node's are the "
    "mission's merged with its own, checked against its backend's (zab check).")


class ModemOverride(Strict):
    """Per-node modem settings; unset values come from the mission's ``modem`` defaults."""

    backend: str | None = None
    frame_bytes: int | None = Field(None, ge=4, le=4096)
    broadcast: int | None = Field(None, ge=0, le=65535, description=BROADCAST_DESCRIPTION)
    options: dict[str, Any] = Field(default_factory=dict, description=OPTIONS_DESCRIPTION)


class Node(Strict):
    """One vehicle or station."""

    address: int = Field(ge=0, le=254, description="Acoustic modem address.")
    role: Literal["surface", "submerged"] = "submerged"
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    position: Position | None = None
    nav_key: FixedKey | None = Field(
        None,
        description="Zenoh key of this node's live position ({x, y, depth} in metres, with "
        "heading and speed if it has them: they steer its position tracker); the simulated "
        "ocean moves the node with it, unless a scripted path does.",
    )
    path: NodePath | None = Field(
        None,
        description="Scripted route in the simulated ocean, from the moment the water starts "
        "(replaces position there); the node's own fixes start from its first waypoint.",
    )
    modem: ModemOverride = Field(default_factory=ModemOverride)
    routes: dict[NodeName, NodeName | list[NodeName]] = Field(
        default_factory=dict, description="Static routes of this node: destination -> the "
        "neighbour that carries its traffic on (``{rov2: rov1}``), or several in order of "
        "preference (``{rov2: [rov1, rov3]}``: the first whose link is up); ``default`` as "
        "the destination routes every node not named, but that neighbour itself (see "
        "docs/concepts.md).")

    def hops_to(self, dest: str) -> tuple[str, ...]:
        """The next hops this node's ``routes`` name for ``dest`` (its ``default``'s, but not
        ``dest`` itself), best first; () when they name none."""
        if not self.routes:
            return ()
        if dest in self.routes:
            return route_hops(self.routes[dest])
        hops = route_hops(self.routes.get("default", ()))
        return () if dest in hops else hops
    prefer: list[NodeName] | None = Field(
        None, min_length=1, description="Links (by name) that traffic TO this node takes, "
        "best first (``[rf, acoustic]``); a channel's own ``prefer`` comes first.")
    keyspace: list[NodeTemplateKey] = Field(
        default_factory=lambda: ["{node}/**"], description="Key expressions where this node's "
        "applications put what is meant to cross ({node} = this node): a put there that no "
        "channel reads is counted and logged once per key; a get there from another node that "
        "maps to no query or latched channel gets a reply error saying so.")


class Modem(Strict):
    """Mission-wide modem defaults."""

    backend: str = Field("sim", description="sim, udp, or a backend from the zab.backends group.")
    frame_bytes: int = Field(64, ge=4, le=4096, description="Largest frame the modem sends.")
    broadcast: int | None = Field(None, ge=0, le=65535, description=BROADCAST_DESCRIPTION)
    options: dict[str, Any] = Field(default_factory=dict, description=OPTIONS_DESCRIPTION)


class TdmaMac(Strict):
    """Static TDMA: slots of ``slot_s`` in ``order``, aligned to wall-clock time."""

    type: Literal["tdma"]
    slot_s: float = Field(gt=0, description="Length of one slot, seconds.")
    guard_s: float = Field(0.0, ge=0, description="Silence kept at the end of each slot, seconds.")
    order: list[NodeName] = Field(min_length=1, description="Slot owners; a node may repeat.")

    @field_validator("guard_s")
    @classmethod
    def _guard_inside_slot(cls, guard_s: float, info: ValidationInfo) -> float:
        slot_s = info.data.get("slot_s")
        if slot_s is not None and guard_s >= slot_s:
            raise ValueError(f"a guard of {guard_s:g} s leaves nothing of a {slot_s:g} s slot "
                             "(the guard is the slot's silent end): no frame could ever be "
                             "sent; make guard_s shorter than slot_s (the propagation time "
                             "over the longest range, with margin)")
        return guard_s


class RangingSlots(Strict):
    """Seed 001's ranging rounds, reserved inside a random-access MAC.

    Every frame of ``requester`` is a ranging request (it sends one at least every
    ``interval_s``, carrying whatever is due). The ``anchors`` answer in order: the first at
    once, each next one right after hearing the previous answer or ``tmax_s`` after the previous
    anchor's turn. Every other node keeps quiet until the round is over.
    """

    requester: NodeName
    anchors: list[NodeName] = Field(min_length=1, description="Answering nodes, in turn order.")
    interval_s: float = Field(gt=0, description="A request at least this often, seconds.")
    tmax_s: float | None = Field(None, gt=0, description="One anchor's turn, seconds; default "
                                 "seed 001 eq. 6 from the preset: modem latency + largest "
                                 "anchor frame's airtime + propagation over the longest range.")


class NoMac(Strict):
    """No access control: send as soon as something is due (ideal links, tests)."""

    type: Literal["none"]
    min_gap_s: float = Field(0.0, ge=0, description="Least time between two frames of a node.")
    ranging: RangingSlots | None = None


class PolledMac(Strict):
    """Master/slave polling (seed 002's token passing, seed 003's polled uplinks).

    The ``master`` sends a frame every ``ipg_s``, each polling the next slave of its sequence;
    a slave sends only right after hearing a frame that polls it. No clock sync is needed.
    """

    type: Literal["polled"]
    master: NodeName
    order: list[NodeName] | None = Field(None, min_length=1, description="Slaves polled in "
                                         "turn; repeat a name to poll it more often. Default: "
                                         "every other node, in mission order.")
    weights: dict[NodeName, Annotated[int, Field(ge=1)]] | None = Field(
        None, description="Polls per cycle of each slave, interleaved (instead of order).")
    ipg_s: float | None = Field(None, gt=0, description="Inter-packet gap between two polls, "
                                "seconds; default: the master's frame time plus the slowest "
                                "slave's reply (latency + 3 sigma jitter, airtime, propagation) "
                                "plus guard_s.")
    guard_s: float = Field(0.0, ge=0, description="Spare time added to a computed ipg_s.")

    @model_validator(mode="after")
    def _one_sequence(self) -> PolledMac:
        if self.order is not None and self.weights is not None:
            raise ValueError("give either order or weights, not both")
        return self


class AlohaMac(Strict):
    """Random access: send when something is due, after a random backoff (pure or slotted)."""

    type: Literal["aloha"]
    slotted: bool = Field(False, description="Start frames only on slot boundaries (slots "
                          "aligned to the Unix epoch, as TDMA: clocks must agree).")
    slot_s: float | None = Field(None, gt=0, description="Slot length, seconds; default: a "
                                 "full frame's time (latency + 3 sigma, airtime, propagation).")
    backoff_s: float = Field(0.0, ge=0, description="Largest random wait before a frame, "
                             "seconds (slotted: whole slots up to this).")
    max_airtime_share: float = Field(1.0, gt=0, le=1, description="Cap on the share of time "
                                     "this node transmits: after a frame of airtime a, the next "
                                     "starts at least a / share later.")
    ranging: RangingSlots | None = None


Mac = Annotated[TdmaMac | NoMac | PolledMac | AlohaMac, Field(discriminator="type")]


class LinkHealth(Strict):
    """When a silent peer counts as degraded or down (seed 002: lost after 5 s of silence).

    Unset thresholds follow the MAC: with TDMA, 2 and 4 cycles; otherwise 10 s and 30 s.
    ``heartbeat_s`` makes a node send a frame (empty if need be) at least that often.
    """

    degraded_after_s: float | None = Field(None, gt=0)
    down_after_s: float | None = Field(None, gt=0)
    heartbeat_s: float | None = Field(None, gt=0)
    failback_s: float | None = Field(None, gt=0, description="With several links: how long "
                                     "a more preferred link must stay up before traffic "
                                     "returns to it; default: its degraded_after_s.")


class LinkNode(Strict):
    """A member's own settings on one link."""

    address: int | None = Field(None, ge=0, le=254, description="Its address on this link's "
                                "modems; default: the node's address.")
    modem: ModemOverride = Field(default_factory=ModemOverride)


class LinkSpec(Strict):
    """One link of a mission with several: a kind of modem its members carry, with its own
    frame size and MAC (seed 002's generic link layer: acoustic, RF, optical)."""

    kind: Literal["acoustic", "rf", "optical"] = Field(
        "acoustic", description="What the link is (the GUI draws it so; presets say its range).")
    modem: Modem = Field(default_factory=Modem)
    mac: Mac = Field(default_factory=lambda: NoMac(type="none"))
    link: LinkHealth | None = Field(None, description="When a silent peer on this link counts "
                                    "as degraded or down; default: the mission's ``link``.")
    nodes: list[NodeName] | dict[NodeName, LinkNode] | None = Field(
        None, description="The members (a list, or a mapping to each one's address and modem "
        "settings on this link); default: every node.")

    def member(self, name: str) -> LinkNode:
        """``name``'s settings on this link (defaults when it gives none)."""
        return self.nodes.get(name, LinkNode()) if isinstance(self.nodes, dict) else LinkNode()


class Dccl(Strict):
    """How the mission's DCCL messages are read and encoded (see docs/dccl.md)."""

    numeric: Literal["dccl-4.2", "dccl-2026"] = Field(
        "dccl-4.2", description="The numeric rule of the fleet's libdccl: dccl-4.2 (the 4.2.0 "
        "release, as packaged Goby3 has it) or dccl-2026 (libdccl after its January 2026 "
        "precise-floats change); they write some float and double values differently.")
    proto_path: list[Path] = Field(
        default_factory=list, description="Folders where a .proto file's imports are looked "
        "up, in order, after its own folder (protoc -I, dccl --proto_path); relative to the "
        "mission file.")

    @field_validator("proto_path")
    @classmethod
    def _from_mission_dir(cls, value: list[Path], info: ValidationInfo) -> list[Path]:
        base = (info.context or {}).get("mission_dir")
        return [Path(base) / p if base is not None and not p.is_absolute() else p for p in value]


class Element(Strict):
    """One Zenoh key carried by a channel: read at the sender, published at each receiver.

    Either ``in`` and ``out`` (msgpack/JSON payloads) or ``ros2`` (a ROS 2 topic over
    rmw_zenoh's keys, CDR payloads; see docs/ros2.md)."""

    in_: AnyTemplateKey | None = Field(None, alias="in", description="Input key at the "
                                       "sender; may use {node}/{src}.")
    out: AnyTemplateKey | None = Field(None, description="Output key at receivers; may use "
                                       "{src}, {dst} and {node}.")
    encoding: Literal["msgpack", "json", "as_sent"] = Field(
        "msgpack", description="Published payload: msgpack, json, or as_sent: the class of "
        "encoding the sender's application used (msgpack, JSON, JSON as text/plain, or any "
        "other label: untagged), carried in 2 bits per value and published as that class's "
        "(a ;schema suffix or another label is not kept).")
    ros2: Ros2Topic | None = Field(None, description="A ROS 2 topic instead of in/out.")
    fields: list[FieldSpec] = Field(default_factory=list, description="The field codecs "
                                    "(required unless ``dccl`` is given).")
    dccl: str | None = Field(None, description="A DCCL message instead of fields: "
                             "'file.proto:Message', the file relative to the mission file; "
                             "the element's bytes are libdccl's (see docs/dccl.md).")

    _dccl_options: Dccl | None = PrivateAttr(None)

    @property
    def dccl_options(self) -> Dccl:
        """The mission's ``dccl`` settings this element's message is read with."""
        return self._dccl_options or Dccl()

    @field_validator("dccl")
    @classmethod
    def _dccl_path(cls, value: str | None, info: ValidationInfo) -> str | None:
        """A relative .proto path is taken from the mission file's folder."""
        base = (info.context or {}).get("mission_dir") if value else None
        path, sep, name = (value or "").rpartition(":")
        if base is not None and sep and path and not Path(path).is_absolute():
            return f"{Path(base) / path}:{name}"
        return value

    @model_validator(mode="after")
    def _fields_or_dccl(self) -> Element:
        if bool(self.fields) == bool(self.dccl):
            raise ValueError("give either fields (at least one) or dccl, not both")
        if self.encoding == "as_sent" and self.dccl:
            raise ValueError("encoding as_sent needs fields: a DCCL element's bytes are "
                             "libdccl's")
        _no_bridge_fields(self.fields)
        return self

    @model_validator(mode="after")
    def _keys(self) -> Element:
        if self.ros2 is None and (self.in_ is None or self.out is None):
            raise ValueError("an element needs `in` and `out` keys (or a `ros2` topic)")
        if self.ros2 is not None and (self.in_ is not None or self.out is not None):
            raise ValueError("a `ros2` element takes its keys from ros2.topic/out_topic: "
                             "leave out `in` and `out`")
        if self.ros2 is not None and "encoding" in self.model_fields_set:
            raise ValueError("a `ros2` element's payloads are CDR: leave out `encoding`")
        return self


def _no_bridge_fields(fields: list[FieldSpec]) -> None:
    """Field names starting with ``_zab`` are the bridge's own (deletes, encodings, ages)."""
    for spec in fields:
        if spec.field.split(".")[0].startswith("_zab"):
            raise ValueError(f"field {spec.field!r}: names starting with _zab are the bridge's")


class Age(Strict):
    """The value's age carried beside it, so receivers stamp each sample with when its value
    was taken at the source (see docs/concepts.md)."""

    step_s: float = Field(gt=0, description="Resolution of the age, seconds.")
    max_s: float = Field(gt=0, description="Longest age told; an older value says at least "
                         "this old.")

    @field_validator("max_s")
    @classmethod
    def _a_step_at_least(cls, value: float, info: ValidationInfo) -> float:
        step = info.data.get("step_s")
        if step is not None and value < step:
            raise ValueError(f"max_s {value:g} is shorter than one step ({step:g} s): every age "
                             "would say only 'fresh' or 'at least max_s'; give max_s the "
                             "longest age to tell (at least step_s), or a finer step_s")
        return value


class NodeKeys(Strict):
    """A key family with one member per node: ``{key}`` takes each matching node's name."""

    nodes: NodePattern = Field(description="Node names (or a pattern) that are the members.")


class LearnedKeys(Strict):
    """A key family learned at run time: each new concrete key on the input becomes a member,
    up to ``learn`` members (a further key is refused, counted); receivers learn each member's
    name from a ``@key`` entry sent beside its first values."""

    learn: int = Field(ge=1, le=65536, description="Most members the sender learns.")
    name_bytes: int = Field(12, ge=1, le=64, description="Longest member name, bytes (UTF-8); "
                            "a longer one is refused, counted.")


def _family_kind(value: Any) -> str | None:
    """Which form of ``keys`` a value is, so that a mistake is told in that form's terms
    (``{learn: 0}`` is a learned family of no member, not "not a list")."""
    if isinstance(value, list):
        return "[names]"
    if isinstance(value, NodeKeys | LearnedKeys):
        return "{nodes}" if isinstance(value, NodeKeys) else "{learn}"
    if isinstance(value, dict):
        return "{nodes}" if "nodes" in value else "{learn}" if "learn" in value else None
    return None


FamilyKeys = Annotated[
    Annotated[list[Annotated[str, Field(pattern=r"^[^/*$#?{}]+$")]], Tag("[names]")]
    | Annotated[NodeKeys, Tag("{nodes}")] | Annotated[LearnedKeys, Tag("{learn}")],
    Discriminator(_family_kind, custom_error_type="zab_keys", custom_error_message=(
        "keys are a list of member names, {nodes: pattern} or {learn: n}")),
    Field(description="The members of a key family: a list of names, ``{nodes: pattern}``, or "
          "``{learn: n}``."),
]


class Channel(Strict):
    """A set of elements sent together, always whole, with a fixed bit length."""

    name: NodeName
    from_: NodePattern = Field(alias="from")
    to: NodePattern
    interval_s: float = Field(
        0.0, ge=0, description="Least time between two sends; 0 means every opportunity."
    )
    latching: bool = Field(False, description="Re-send the last value even without new data.")
    priority: int = Field(0, description="Higher first when a frame is full.")
    ack: bool = Field(False, description="Ask the modem to confirm delivery of frames that "
                      "carry this channel to a single node (modems that offer it).")
    on_out_of_range: Literal["clamp", "reject"] = "clamp"
    ttl_s: float | None = Field(None, gt=0, description="Data older than this is never sent "
                                "(a reliable value older than this is reported failed).")
    reliable: bool = Field(False, description="Every value delivered exactly once and in order, "
                           "acknowledged by the receivers, or reported failed.")
    queue: int = Field(32, ge=1, le=4096, description="Values a reliable channel holds "
                       "(queued and in flight).")
    overflow: Literal["reject", "drop_oldest"] = Field(
        "reject", description="A reliable channel's full queue refuses the new value, or "
        "gives up its oldest unsent one; either is reported failed.")
    retries: int | None = Field(10, ge=0, description="Retransmissions of a reliable value "
                                "(or fragment) before it is reported failed; null: until ttl_s.")
    retry_s: float | None = Field(None, gt=0, description="Wait for an acknowledgement before "
                                  "the first retransmission (doubles up to 4x); default: one "
                                  "TDMA cycle, else 10 s; with several links or routes, "
                                  "learned from each receiver's round trips (at first the "
                                  "worst-case round trip).")
    always: bool = Field(False, description="With ``demand``: send even while no application "
                         "at a destination subscribes (latched state, safety data).")
    prefer: list[NodeName] | None = Field(None, min_length=1, description="With several "
                                          "links: the links (by name) this channel takes, "
                                          "best first (``[rf, acoustic]``).")
    keys: FamilyKeys | None = Field(None, description="Make the channel a key family: its "
                                    "input keys hold ``{key}`` (or one ``*`` chunk) and each "
                                    "member keeps its own value, age and output key.")
    deletes: bool = Field(False, description="A Zenoh delete on an input key crosses as a "
                          "tombstone (1 bit per element in every entry): receivers publish a "
                          "delete and forget the latched value; the sender stops re-sending it.")
    age: Age | None = Field(None, description="Carry each value's age (latest-value channels "
                            "without keys): receivers stamp the sample with when it was "
                            "taken at the source, to this resolution.")
    attachment_bytes: int = Field(0, ge=0, le=64, description="Carry the application's Zenoh "
                                  "attachment, up to this many bytes (a length and the bytes, "
                                  "per element); 0: not carried.")
    elements: list[Element] = Field(min_length=1)

    @field_validator("queue", "overflow")
    @classmethod
    def _reliable_queue(cls, value: Any, info: ValidationInfo) -> Any:
        """``queue`` and ``overflow`` bound a reliable channel's values waiting for their
        acknowledgement; any other channel holds only its latest value."""
        if not info.data.get("reliable", True):  # (reliable itself failed: said there)
            raise ValueError(f"{info.field_name} is a reliable channel's setting: this channel "
                             "is not reliable and sends only its latest value, so nothing "
                             f"queues; give reliable: true, or remove {info.field_name}")
        return value

    @model_validator(mode="after")
    def _zenoh_fidelity(self) -> Channel:
        if (self.deletes or self.age or self.attachment_bytes) and any(
                e.dccl or e.ros2 for e in self.elements):
            raise ValueError("deletes, age and attachment_bytes need fields: not with dccl or "
                             "ros2 elements")
        if self.age is not None and (self.keys is not None or self.reliable):
            raise ValueError("age is carried on latest-value channels without keys")
        return self

    @model_validator(mode="after")
    def _policy(self) -> Channel:
        if self.reliable and self.latching:
            raise ValueError("a reliable channel cannot be latching: each value is sent until "
                             "acknowledged, once")
        if self.keys is not None and self.reliable:
            raise ValueError("a key family cannot be reliable")
        if isinstance(self.keys, list) and len(set(self.keys)) != len(self.keys):
            raise ValueError("a key family lists a member twice")
        return self


class Query(Strict):
    """Zenoh queries across the water: a ``get`` on ``key`` at an asking node becomes a compact
    request; the serving node's bridge runs a local ``get`` on ``local_key`` with the request's
    parameters and sends the replies back; the asking bridge answers the original ``get``, or
    ends it with a reply error at the deadline the MAC allows."""

    name: NodeName
    key: AnyTemplateKey = Field(description="Key expression applications get at the asking "
                                "nodes; with several servers it holds {node}, the serving node "
                                "(e.g. {node}/info).")
    serve: NodePattern = Field(description="Serving node(s): where the queryable lives.")
    ask: NodePattern | None = Field(None, description="Nodes whose applications may ask "
                                    "(default: every node that does not serve).")
    local_key: AnyTemplateKey | None = Field(None, description="Key the serving bridge gets "
                                             "on its own session ({node} = the server); "
                                             "default: the asked key.")
    request: list[FieldSpec] = Field(default_factory=list, description="The parameters "
                                     "(selector parameters or a msgpack/JSON payload); none: "
                                     "a bare get.")
    reply: list[FieldSpec] = Field(min_length=1, description="Fields of each reply.")
    encoding: Literal["msgpack", "json"] = Field("msgpack", description="Replies' payload.")
    max_replies: int = Field(1, ge=1, le=8, description="Replies carried back per request.")
    timeout_s: float | None = Field(None, gt=0, description="Give up after this long; default: "
                                    "the MAC's bound for a request and its reply.")
    cached_s: float | None = Field(None, gt=0, description="Answer at once, without an acoustic "
                                   "request, when the asked key holds a value this node's "
                                   "bridge published for a latched channel no older than this.")
    deadline_bits: int = Field(0, ge=0, le=8, description="Carry the asker's remaining time in "
                               "each request, in this many bits (steps of the query's longest "
                               "deadline / (2**bits - 1)): the serving bridge drops a request "
                               "whose caller gave up, and stops its replies then. 0: not "
                               "carried (the request entry as before).")


class NextKey(Strict):
    """The frame key that takes over from the mission key at ``at`` (key rotation): both are
    accepted within ``overlap_s`` of the switch, so nothing is lost across it. Like the
    mission key it is never in the mission file."""

    key_env: str = Field("ZAB_NEXT_KEY", description="Environment variable holding the key.")
    key_file: Path | None = Field(None, description="File holding the key (used if the "
                                  "variable is unset).")
    at: AwareDatetime = Field(description="When frames start being sealed with it (an ISO "
                              "time with its zone, e.g. 2026-06-01T12:00:00Z).")
    overlap_s: float = Field(600.0, gt=0, description="Either side of ``at``, frames sealed "
                             "with either key are accepted (clocks differ; frames in flight).")


class Auth(Strict):
    """Authenticated frames. The key is never in the mission: it comes from the environment
    variable ``key_env`` or else from ``key_file``."""

    tag_bytes: int = Field(4, ge=2, le=16, description="Bytes of the truncated tag.")
    key_env: str = Field("ZAB_KEY", description="Environment variable holding the key.")
    key_file: Path | None = Field(None, description="File holding the key (used if the "
                                  "variable is unset).")
    encrypt: bool = Field(False, description="Confidential frames: the body encrypted and "
                          "authenticated with AES-CCM (the same counter and tag sizes as the "
                          "HMAC; tag_bytes even); the DLBL delays stay in the clear, "
                          "authenticated (docs/wire-format.md).")
    next_key: NextKey | None = Field(None, description="Key rotation: the key that takes "
                                     "over, and when (encrypted frames).")
    sign_outputs: bool = Field(False, description="Sign what the bridge publishes on Zenoh "
                               "(values, delivery reports, status, events) with the key: "
                               "applications holding it can tell the bridge's samples from "
                               "anyone else's (docs/developers.md).")

    @model_validator(mode="after")
    def _sealed(self) -> Auth:
        if self.encrypt and self.tag_bytes % 2:
            raise ValueError("an encrypted frame's tag_bytes is even (AES-CCM: 4 to 16)")
        if self.encrypt and self.tag_bytes < 4:
            raise ValueError("an encrypted frame's tag_bytes is at least 4 (AES-CCM)")
        if self.next_key is not None and not self.encrypt:
            raise ValueError("next_key rotates the key of encrypted frames: give encrypt: true")
        return self


def _auth_off_in_schema(schema: dict[str, Any]) -> None:
    """`auth: off` is False to PyYAML (YAML 1.1) and "off" to YAML 1.2 editors: both mean off."""
    schema["anyOf"].insert(1, {"enum": ["off", False], "description": "Frames are not "
                               "authenticated, on purpose."})


class Wire(Strict):
    """Options of the frame format shared by every node.

    ``auth`` absent means the mission does not say; ``auth: off`` says frames go
    unauthenticated on purpose (``zab run`` and ``zab check`` refuse a mission that does not
    say while a frame key is present). Either way ``auth`` is then None: read :attr:`auth_off`
    to tell them apart."""

    dlbl: bool = Field(False, description="Start each frame with the DLBL delay vector.")
    auth: Auth | None = Field(None, description="Counter + keyed tag in every frame; `off`: no "
                              "authentication, on purpose (absent: not said, which zab run "
                              "refuses while a frame key is present).",
                              json_schema_extra=_auth_off_in_schema)
    format: Literal["zab", "goby"] = Field(
        "zab", description="zab's frame, or goby: DCCL messages back to back as Goby3's "
        "queue packs them (every channel one dccl element; see docs/dccl.md).")
    _auth_off: bool = PrivateAttr(False)

    @model_validator(mode="wrap")
    @classmethod
    def _explicit_off(cls, data: Any, handler: ModelWrapValidatorHandler[Wire]) -> Wire:
        value = data.get("auth") if isinstance(data, dict) else None
        off = value is False or value == "off"
        if off:
            data = {k: v for k, v in data.items() if k != "auth"}
        wire = handler(data)
        wire._auth_off = off or wire._auth_off
        return wire

    @model_serializer(mode="wrap")
    def _dump_off(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        if self._auth_off:
            data["auth"] = "off"  # a dump reads back as the same mission
        return data

    @property
    def auth_off(self) -> bool:
        """The mission says ``auth: off``: frames go unauthenticated on purpose."""
        return self._auth_off


class Demand(Strict):
    """Demand-driven sending: a node sends a channel only while an application at one of its
    destinations subscribes to its output key (except ``always`` channels). Each node tells the
    others what its applications want in an ``@want`` bitmap over the mission's channels, sent
    when it changes and at least every ``refresh_s``."""

    refresh_s: float = Field(60.0, gt=0, description="Re-send this node's interest at least "
                             "this often, seconds (it survives loss and restarts).")


class Surfacing(Strict):
    """Fidelity that follows the link: while a peer's bridge is reachable over IP (its
    liveliness token ``@zab/<mission>/<peer>/bridge`` is visible: it surfaced and its Zenoh
    joined this node's; with ``wire.auth``, it also answers a challenge with the mission key
    every 2 s), channels between the two are not carried acoustically; the sender's bridge puts
    each input sample, unquantised, on the output key instead (``republish``). When the token
    goes or the proof stops (the vehicle dives), acoustic bridging resumes at the next
    opportunity."""

    republish: bool = Field(True, description="Put full-fidelity copies of input samples on "
                            "the output keys of IP-reachable destinations (skipped when the "
                            "output key is the input key: Zenoh carries it as it is).")


class WaterProperties(Strict):
    """Temperature, salinity and depth for a computed sound speed."""

    temperature_c: float = Field(ge=-2, le=40)
    salinity_psu: float = Field(ge=0, le=42)
    depth_m: float = Field(0.0, ge=0, le=12000)
    equation: Literal["unesco", "mackenzie", "coppens"] = "unesco"
    latitude_deg: float = Field(45.0, ge=-90, le=90)


class PingRanging(Strict):
    """Who asks its modem for explicit ranges, to whom, and how often."""

    peers: list[NodeName] | None = Field(None, min_length=1, description="Nodes ranged to, in "
                                         "turn; default: the anchors.")
    nodes: list[NodeName] | None = Field(None, min_length=1, description="Nodes that range; "
                                         "default: every node that is not a peer.")
    interval_s: float = Field(30.0, gt=0, description="Least time between two ranges of a "
                              "node, seconds.")


class Ranging(Strict):
    """Ranges from DLBL delays (``wire.dlbl``) and positions from ranges to anchors."""

    sound_speed_mps: float | None = Field(None, ge=1300, le=1800, description="Fixed sound "
                                          "speed; default 1500 unless ``water`` is given.")
    water: WaterProperties | None = None
    ctd_key: FixedKey | None = Field(None, description="Live {temperature_c, salinity_psu, depth_m}"
                                " at this node; replaces the fixed sound speed.")
    tx_latency_s: float = Field(0.0, ge=0, description="Modem delay from send to emission.")
    rx_latency_s: float = Field(0.0, ge=0, description="Modem delay of reception stamps.")
    anchors: list[NodeName] | None = Field(None, description="Nodes with known positions; "
                                           "default: surface nodes with a position.")
    anchor_keys: dict[NodeName, FixedKey] = Field(default_factory=dict, description="Key with an "
                                             "anchor's live {x, y, depth} at each node.")
    fix_max_age_s: float | None = Field(None, gt=0, description="Oldest range used in a fix; "
                                        "default: one TDMA cycle, else 30 s.")
    sound_speed_mode: Literal["local", "mean_of_ends"] = Field(
        "local", description="Sound speed of a range: this node's, or the mean of both ends' "
        "(seed 001) once the peer's is known from peer_ctd_key.")
    peer_ctd_key: PeerTemplateKey | None = Field(
        None, description="Key where this node hears each peer's water, {src} = the peer (e.g. "
        "the output of a bridged CTD channel: {src}/ctd), holding {temperature_c, "
        "salinity_psu, depth_m} like ctd_key.")
    ping: PingRanging | None = Field(None, description="Explicit two-way ranges measured by "
                                     "the modems (Micro-Modem ping, EvoLogics acked IM).")


class Mission(Strict):
    """A deployment: nodes, modem, MAC and channels."""

    mission: NodeName = Field(description="Mission name; used in @zab/<mission>/... keys.")
    nodes: dict[NodeName, Node] = Field(min_length=1)
    modem: Modem = Field(default_factory=Modem)
    mac: Mac = Field(default_factory=lambda: NoMac(type="none"))
    links: dict[NodeName, LinkSpec] | None = Field(
        None, description="Several links (instead of ``modem`` and ``mac``): each a modem "
        "kind with its own frame size and MAC, by name (see docs/concepts.md).")
    max_hops: int = Field(3, ge=1, le=8, description="Most hops (transmissions) a frame takes "
                          "from its origin to its destination, through relays (nodes' "
                          "``routes``).")
    wire: Wire = Field(default_factory=Wire)
    link: LinkHealth = Field(default_factory=LinkHealth)
    demand: Demand | None = Field(None, description="Send channels only where applications "
                                  "subscribe to them (see Demand).")
    surfacing: Surfacing | None = Field(None, description="Stop carrying a peer's channels "
                                        "acoustically while it is reachable over IP.")
    ranging: Ranging = Field(default_factory=Ranging)
    dccl: Dccl = Field(default_factory=Dccl, description="How DCCL messages are read and "
                       "encoded: the numeric rule and the .proto include path.")
    channels: list[Channel] = Field(default_factory=list)
    queries: list[Query] = Field(default_factory=list, description="Queries across the water.")
    images: list[ImageChannel] = Field(default_factory=list, description="Image channels: "
                                       "progressive pictures (see ImageChannel).")
    max_open_queries: int = Field(4, ge=1, le=16, description="Acoustic queries a node keeps "
                                  "open at once; a further get ends at once with an error.")

    @model_validator(mode="after")
    def _query_fields(self) -> Mission:
        for query in self.queries:
            _no_bridge_fields(query.request)
            _no_bridge_fields(query.reply)
        return self

    @model_validator(mode="after")
    def _dccl_to_elements(self) -> Mission:
        """Each DCCL element is read with the mission's ``dccl`` settings."""
        for channel in self.channels:
            for element in channel.elements:
                element._dccl_options = self.dccl
        return self

    def node_modem(self, name: str) -> Modem:
        """The modem settings of ``name``: mission defaults with the node's overrides."""
        override = self.nodes[name].modem
        return Modem(
            backend=override.backend or self.modem.backend,
            frame_bytes=override.frame_bytes or self.modem.frame_bytes,
            broadcast=self.modem.broadcast if override.broadcast is None else override.broadcast,
            options={**self.modem.options, **override.options},
        )

    def frame_sizes_of(self, name: str) -> list[int]:
        """The frame size of each link of ``name`` (its modem's, with one link)."""
        if self.links is None:
            return [self.node_modem(name).frame_bytes]
        return [spec.member(name).modem.frame_bytes or spec.modem.frame_bytes
                for spec in self.links.values() if spec.nodes is None or name in spec.nodes]

    def frame_bytes_of(self, name: str) -> int:
        """The largest frame every link of ``name`` carries (its modem's, with one link)."""
        return min(self.frame_sizes_of(name), default=self.modem.frame_bytes)

    def address_of(self, name: str) -> int:
        return self.nodes[name].address

    def name_of(self, address: int) -> str | None:
        """The node at ``address`` (the first in file order), None if there is none."""
        name = self.names_found.get(address)  # asked per received frame: kept, and checked
        node = self.nodes.get(name) if name is not None else None
        if node is not None and node.address == address:
            return name
        name = next((n for n, node in self.nodes.items() if node.address == address), None)
        if name is not None:
            self.names_found[address] = name
        return name

    @cached_property
    def names_found(self) -> dict[int, str]:
        """Node names by address, as :meth:`name_of` found them."""
        return {}
