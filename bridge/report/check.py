"""What ``zab check`` reports: channel sizes, worst-case frame fill, airtime against slots."""

from __future__ import annotations

import itertools
import math
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

from bridge.codec.fields import BytesCodec, StringCodec
from bridge.core.bounds import retry_floor_s, round_trip_s
from bridge.core.loaded import LoadedMission
from bridge.core.mac import mac_for, max_distance_m, node_preset
from bridge.core.positioning import mission_anchors, mission_sound_speed, water_sound_speed_of
from bridge.core.queries import deadline_s
from bridge.core.reliable import default_retry_s, stream_ttl_s
from bridge.core.routing import overhears
from bridge.core.shared_inputs import shared_input_warnings
from bridge.core.transfer import transfer_ttl_s
from bridge.dccl.numeric import RULES
from bridge.dccl.report import dccl_reports
from bridge.errors import BackendError
from bridge.mission.endpoints import shared_listens
from bridge.mission.loader import Problem, located
from bridge.mission.model import Mission
from bridge.mission.network import Network
from bridge.modems.registry import load_backend
from bridge.modems.setup import modem_options
from bridge.report.network_check import network_section
from bridge.report.steps import coarse_fields, field_steps
from bridge.wire.auth import COUNTER_BYTES
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.families import has_wildcard
from bridge.wire.frame import FrameCodec
from bridge.wire.goby import frame_codec_for
from bridge.wire.queries import QueryCodec

TICK_S = 1.0  # runtimes look at TTLs at least this often (zab run's health loop)


@dataclass
class CheckReport:
    """The result of checking a mission; ``ok`` is False when something can never fit."""

    data: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    invalid: list[Problem] = field(default_factory=list)
    """Mistakes of the mission file found here (a node that must send but never gets a turn):
    ``zab check`` exits 2 for them, as for any invalid file."""

    @property
    def ok(self) -> bool:
        return not self.errors  # (``invalid`` are among them)


LOSSES = (0.1, 0.2)
"""Losses a hop that ``zab check`` says what a reliable value over several hops meets at."""


def stream_limits(channel: ChannelCodec, mission: Mission) -> dict[str, Any]:
    """A reliable or fragmented channel's retries, first retry wait and TTL (given or
    default), and so the longest a value waits for its terminal report; with several links
    or routes, per sender and receiver of a reliable channel (``learned``): the first
    retry's wait (the worst-case round trip, until the timer has measured one), the least
    it learns to, how likely a copy and its acknowledgement both cross its hops at a loss of
    :data:`LOSSES` a hop, and the hops whose sender sends a lost copy again itself
    (``repaired``: :mod:`bridge.core.custody`)."""
    retry_s = channel.retry_s or default_retry_s(mission)
    ttl = channel.ttl_s or (transfer_ttl_s(channel, retry_s) if channel.fragmented
                            else stream_ttl_s(retry_s, channel.retries, channel.queue))
    out: dict[str, Any] = {
        "channel": channel.name, "retries": channel.retries, "retry_s": retry_s,
        "ttl_s": round(ttl, 3), "ttl_default": channel.ttl_s is None,
        "report_within_s": round(ttl + TICK_S, 3)}
    network = Network(mission)
    if channel.reliable and not channel.retry_s and network.networked:
        out["learned"] = [  # the timer learns each receiver's round trips from its worst case
            {"from": sender, "to": dest, "hops": len(path) - 1,
             "first_retry_s": round(round_trip_s(network, sender, dest), 3),
             "floor_s": round(retry_floor_s(network, sender), 3),
             "both_cross": {f"{loss:g}": round((1 - loss) ** (2 * (len(path) - 1)), 3)
                            for loss in LOSSES},
             "repaired": [f"{a} -> {b}" for a, b in itertools.pairwise(path)
                          if (a, b) != (sender, dest)
                          and overhears(network, a, sender, b, [dest])]}
            for sender in channel.senders for dest in channel.destinations(sender)
            for path, problem in (network.path(sender, dest),) if problem is None]
    return out


def check_mission(loaded: LoadedMission) -> CheckReport:
    mission, table = loaded.mission, loaded.table
    codec = frame_codec_for(table)
    sent_count_bits = 0 if table.wire_format == "goby" else codec.count_bits  # goby: no count
    report = CheckReport(data={})
    channels = [
        {
            "name": c.name,
            "index": c.index,
            "bits": c.bits,
            "cost_bits": codec.channel_cost_bits(c),
            "from": list(c.senders),
            "to": [r for r in c.receivers if c.senders != (r,)],
            "interval_s": c.interval_s,
            "latching": c.latching,
            "priority": c.priority,
            "reliable": c.reliable,
            "ttl_s": c.ttl_s,
            "fragments": {"chunk_bytes": c.chunk_bytes,
                          "at_most": -(-c.value_bytes // c.chunk_bytes)} if c.fragmented else None,
            "keys": _family(c),
            "always": c.always,
            "fields": field_steps(c) if c.image is None else [],
        }
        for c in table.channels
    ]
    report.warnings.extend(w for c in table.channels for w in coarse_fields(c))
    _family_warnings(loaded, report)
    report.warnings.extend(shared_input_warnings(mission, table))
    report.warnings.extend(shared_listens({n: list(node.zenoh.listen)
                                           for n, node in mission.nodes.items()}))
    _system_entries_fit(loaded, codec, report)
    for c in table.channels:
        if c.fragmented and c.image is None:
            report.warnings.append(
                f"channel {c.name!r}: a value ({c.bits} bits) is larger than a frame; it travels "
                f"in up to {-(-c.value_bytes // c.chunk_bytes)} fragments of {c.chunk_bytes} B"
                + _untrimmed(c))
    nodes = []
    network = loaded.network
    broadcasts: dict[int | None, list[str]] = defaultdict(list)
    by_link: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for name in mission.nodes:
        found = []
        for link in network.links_of(name):
            entry = _node_on(link.view, name, codec, report, broadcasts,
                             0 if table.net is None else table.net.routed_bytes
                             if network.routed_over(name, link.name) else table.net.plain_bytes)
            if network.several:
                entry["link"] = link.name
            by_link[link.name].append(entry)
            found.append(entry)
        nodes.append({**found[0], **({"links": found} if network.several else {})})
    if len(broadcasts) > 1:  # one fleet, one convention (a Goby node takes 0 as broadcast)
        said = "; ".join(f"{', '.join(names)}: {'none' if b is None else b}"
                         for b, names in broadcasts.items())
        report.warnings.append(f"nodes disagree on the broadcast address ({said}): a frame "
                               "one sends to every node reaches the others as one to that "
                               "address (set modem.broadcast once for the mission)")
    images = [_image(c, codec) for c in table.channels
              if c.image is not None and not c.image.control]
    for image in images:  # a turn's wait for the first, then one fragment a turn at worst,
        # taking turns with the cameras of the same node at its priority or above (each sending)
        waits = [n["mac"]["worst_interval_s"] for n in nodes
                 if n["name"] in image["from"]]
        slowest: float | None = max((w for w in waits if w is not None), default=None)
        image["shares_turns_with"] = [
            other["name"] for other in images if other is not image
            and set(other["from"]) & set(image["from"]) and other["priority"] >= image["priority"]]
        turns = 1 + image["fragments_per_picture"] * (1 + len(image["shares_turns_with"]))
        image["seconds_per_picture"] = None if slowest is None else round(slowest * turns, 1)
        ttl = image["ttl_s"]
        if ttl is not None and image["seconds_per_picture"] is not None and \
                image["seconds_per_picture"] > ttl:
            report.warnings.append(
                f"image channel '{image['name']}': a picture of {image['budget_bytes']} B "
                f"takes up to {image['seconds_per_picture']} s ({image['fragments_per_picture']}"
                f" fragments, one a turn{_sharing(image)}), more than its ttl_s={ttl:g}: such a "
                "picture is given up unfinished (raise ttl_s or lower budget_bytes)")
    _shared_picture_topics(table, report)
    mac_data: dict[str, Any] = {}
    for link in network.links:
        data, warnings = mac_for(link.view).check(by_link[link.name])
        report.warnings.extend(warnings)
        mac_data.update({link.name: data} if network.several else data)
    extra: dict[str, Any] = {}
    if table.net is not None:
        extra["network"], warnings = network_section(loaded, codec, by_link)
        report.warnings.extend(warnings)
    silent = silent_nodes(loaded)
    report.invalid = located(str(loaded.path), loaded.marks,
                             [(s.pop("loc"), s["message"]) for s in silent]).problems
    for entry, problem in zip(silent, report.invalid, strict=False):
        entry.update(path=problem.path, line=problem.line, column=problem.column)
    report.errors += [str(p) for p in report.invalid]
    report.data = {
        "silent": silent,
        "streams": [stream_limits(c, mission) for c in table.streams],
        "mission": mission.mission,
        "frame_bytes": mission.modem.frame_bytes,
        "backend": mission.modem.backend,
        "mac": mission.mac.type if not network.several else ", ".join(
            f"{link.view.mac.type} ({link.name})" for link in network.links),
        "mac_timing": mac_data,
        "dlbl": mission.wire.dlbl,
        "ranging": _ranging(mission),
        "overhead_bytes": codec.overhead_bytes(),
        "auth": _auth(mission),
        "count_bits": sent_count_bits,
        "index_bits": codec.index_bits,
        "demand": None if mission.demand is None else {
            "refresh_s": mission.demand.refresh_s,
            "want_entry_bits": codec.channel_cost_bits(table.interest)  # type: ignore[arg-type]
        },
        "queries": [_query(mission, codec, c) for c in table.query_codecs if not c.reply],
        "max_open_queries": mission.max_open_queries,
        "key_entry_bits": None if table.names is None else codec.channel_cost_bits(table.names),
        "channels": channels,
        "images": images,
        "dccl": dccl_reports(table),
        "dccl_numeric": {"rule": mission.dccl.numeric, "libdccl": RULES[mission.dccl.numeric]},
        "nodes": nodes,
        **extra,
        "warnings": report.warnings,
        "errors": report.errors,
        "ok": report.ok,
    }
    return report


def _node_on(view: Mission, name: str, codec: FrameCodec, report: CheckReport,
             broadcasts: dict[int | None, list[str]], header_bytes: int) -> dict[str, Any]:
    """``zab check``'s entry of node ``name`` on one link (``view``: the mission as that link
    sees it; the mission itself with one link); ``header_bytes``: its frames' network header."""
    table, node = codec.table, view.nodes[name]
    sent_count_bits = 0 if table.wire_format == "goby" else codec.count_bits
    rules = mac_for(view)
    frame_bytes = view.node_modem(name).frame_bytes
    capacity = codec.body_capacity_bits(frame_bytes - header_bytes) - codec.count_bits
    sent = [c for c in table.channels if c.sent_by(name) and c.destinations(name)]
    worst = sum(codec.channel_cost_bits(c) * (c.family.bound if c.family else 1)
                for c in sent)  # every member of a key family at once
    modem = view.node_modem(name)
    options = modem_options(view, name)
    try:
        backend = load_backend(modem.backend)
        limit = backend.max_frame_bytes(options)
        errors, warnings = backend.setup_problems(options, node.address)
        report.errors += [f"{name}: {e}" for e in errors]
        report.warnings += [f"{name}: {w}" for w in warnings]
        broadcasts[backend.broadcast_address(options)].append(name)
    except BackendError as exc:
        report.errors.append(f"{name}: {exc}")
        limit = None
    if limit is not None and frame_bytes > limit:
        report.errors.append(f"{name}: frame_bytes {frame_bytes} exceeds the {limit} bytes a "
                             f"{modem.backend} modem sends with these options")
    for c in sent:
        if codec.channel_cost_bits(c) > capacity:
            report.errors.append(
                f"channel {c.name!r} ({codec.channel_cost_bits(c)} bits with its index) can "
                f"never fit in a {frame_bytes}-byte frame of {name!r} "
                f"({capacity} bits free after overhead)"
            )
    if worst > capacity:
        report.warnings.append(
            f"{name}: all its channels at once need {worst} bits, a frame holds {capacity}; "
            "lower priorities wait for a later frame"
        )
    preset = node_preset(view, name)
    largest = codec.frame_bytes_for(sent) if sent else codec.frame_bytes_for([])
    largest += header_bytes
    airtime = preset.airtime(min(largest, frame_bytes)) if preset else None
    entry = {
        "name": name,
        "address": node.address,
        "role": node.role,
        "listen": list(node.zenoh.listen),
        "frame_bytes": frame_bytes,
        "worst_case_bits": worst + codec.epoch_bits + sent_count_bits
        + (codec.overhead_bytes() + header_bytes) * 8,
        "capacity_bits": frame_bytes * 8,
        "fill": round(min(largest, frame_bytes) / frame_bytes, 3),
        "airtime_s": None if airtime is None else round(airtime, 3),
    }
    need = None if preset is None else preset.frame_time_s(
        min(largest, frame_bytes), max_distance_m(view, preset))
    extra, warnings = rules.check_node(name, need, airtime)
    entry.update(extra)
    report.warnings.extend(warnings)
    mac = rules.report(name, airtime, _data_per_s(sent, view.link.heartbeat_s))
    entry["mac"] = {"worst_interval_s": _round(mac.worst_interval_s),
                    "airtime_share": mac.airtime_share, "note": mac.note,
                    "random_access": mac.random_access}
    return entry


def _ranging(mission: Mission) -> dict[str, Any] | None:
    """What the nodes range and localise by: the anchors (each fixed, at its mission position,
    or live, on its key) and the sound speed the bridges assume, with where it comes from and,
    when it is not ``ranging.water``'s, the speed that water gives (what ``zab sim`` simulates);
    None when nothing ranges (no DLBL, no modem pings)."""
    r = mission.ranging
    by = [*(["DLBL"] if mission.wire.dlbl else []), *(["modem pings"] if r.ping else [])]
    if not by:
        return None
    assumed, water = mission_sound_speed(mission), water_sound_speed_of(mission)
    return {
        "by": by,
        "anchors": [{"node": a, "live_key": r.anchor_keys.get(a)}
                    for a in mission_anchors(mission)],
        "sound_speed_mps": round(assumed.mps, 2),
        "sound_speed_from": "ranging.sound_speed_mps" if r.sound_speed_mps is not None
        else "ranging.water" if water is not None else "default",
        "water_sound_speed_mps": None if water is None or r.sound_speed_mps is None
        else round(water.mps, 2),
        "live_ctd": r.ctd_key is not None,
    }


def _auth(mission: Mission) -> dict[str, Any] | None:
    """What authenticating (or sealing) frames costs: bits in every frame, and the key's
    rotation if the mission names one."""
    auth = mission.wire.auth
    if auth is None:
        return None
    nxt = auth.next_key
    return {"encrypted": auth.encrypt, "cipher": "AES-CCM" if auth.encrypt else "HMAC-SHA256",
            "counter_bits": 8 * COUNTER_BYTES, "tag_bits": 8 * auth.tag_bytes,
            "bits_per_frame": 8 * (COUNTER_BYTES + auth.tag_bytes),
            "next_key_at": None if nxt is None else nxt.at.isoformat(),
            "overlap_s": None if nxt is None else nxt.overlap_s}


def _untrimmed(channel: ChannelCodec) -> str:
    """What a fragmented channel's bytes or string field before other fields costs: a transfer
    drops only a value's trailing zero bytes, so the fields after it make every value go at
    the field's whole length (a 600 B blob before an id went as 1.5 kB)."""
    fields = [f for e in channel.elements for f in e.layout.fields]
    early = [f for f in fields[:-1] if isinstance(f, BytesCodec | StringCodec)]
    if not early:
        return ""
    names = ", ".join(repr(f.name) for f in early)
    return (f"; every value takes them all, as {names} comes before other fields: put it "
            "last to send only what a value holds")


def _family(channel: ChannelCodec) -> dict[str, Any] | None:
    """A key family as ``zab check`` shows it: members (or the learned bound) and index bits."""
    spec = channel.family
    if spec is None:
        return None
    return {"members": None if spec.learned else list(spec.members), "bound": spec.bound,
            "learned": spec.learned, "index_bits": spec.index_bits,
            "name_bytes": spec.name_bytes if spec.learned else None}


def _sharing(image: dict[str, Any]) -> str:
    """What an image channel's turns are shared with, for a warning (or nothing)."""
    others = image["shares_turns_with"]
    return f", turns shared with {', '.join(repr(o) for o in others)}" if others else ""


def _image(channel: ChannelCodec, codec: FrameCodec) -> dict[str, Any]:
    """An image channel as ``zab check`` shows it: its fragments and what a picture takes."""
    spec = channel.image
    assert spec is not None
    chunk = channel.chunk_bytes
    return {"name": spec.name, "from": list(channel.senders), "to": list(channel.receivers),
            "size": [spec.width, spec.height], "colour": spec.colour,
            "budget_bytes": spec.budget_bytes - spec.budget_bytes % chunk,
            "max_budget_bytes": spec.largest_budget, "fragment_bytes": chunk,
            "fragment_bits": codec.channel_cost_bits(channel),
            "fragments_per_picture": spec.budget_bytes // chunk,
            "priority": channel.priority, "policy": spec.policy, "send": spec.send,
            "ttl_s": channel.ttl_s}


def _query(mission: Mission, codec: FrameCodec, request: QueryCodec) -> dict[str, Any]:
    """A query as ``zab check`` shows it: entry sizes and the deadline of each asker/server."""
    spec = request.spec
    reply = next(c for c in codec.table.query_codecs if c.reply and c.spec is spec)
    return {"name": spec.name, "key": spec.key, "servers": list(spec.servers),
            "askers": list(spec.askers), "request_bits": codec.channel_cost_bits(request),
            "reply_bits": codec.channel_cost_bits(reply), "max_replies": spec.max_replies,
            "deadline_s": {f"{a}->{s}": deadline_s(mission, spec, a, s)
                           for a in spec.askers for s in spec.servers if s != a}}


def _system_entries_fit(loaded: LoadedMission, codec: FrameCodec, report: CheckReport) -> None:
    """Each node's @key, @want and query entries must fit in one of its frames."""
    mission, table = loaded.mission, loaded.table
    for name in mission.nodes:  # (its smallest frame, with the longest network header)
        capacity = codec.body_capacity_bits(mission.frame_bytes_of(name)
                                            - table.net_header_bytes) - codec.count_bits
        entries: list[Any] = []
        if table.names is not None and any(c.family and c.family.learned and c.sent_by(name)
                                           for c in table.channels):
            entries.append(table.names)
        if table.interest is not None:
            entries.append(table.interest)
        entries += [c for c in table.query_codecs
                    if name in (c.spec.servers if c.reply else c.spec.askers)]
        for entry in entries:
            if codec.channel_cost_bits(entry) > capacity:
                report.errors.append(
                    f"entry {entry.name!r} ({codec.channel_cost_bits(entry)} bits with its "
                    f"index) can never fit in a frame of {name!r} ({capacity} bits free)")


def _shared_picture_topics(table: ChannelTable, report: CheckReport) -> None:
    """An image channel's ROS 2 pictures topic that several of a camera's receivers share
    (no ``{dst}``): each receiver publishes every picture on it."""
    for c in table.channels:
        spec = c.image
        if spec is None or spec.control or spec.ros2_out is None:
            continue
        for src in c.senders:
            dests = c.destinations(src)
            keys = {spec.ros2_output_key(src, d) for d in dests}
            if len(keys) < len(dests):
                report.warnings.append(
                    f"image channel {c.name!r}: {src}'s receivers {', '.join(dests)} share "
                    f"one ROS 2 topic ({spec.ros2_out.out_topic}): where their ROS 2 graphs "
                    "meet, each picture comes once from each (give out_topic {dst})")
                break


def _family_warnings(loaded: LoadedMission, report: CheckReport) -> None:
    """A wildcard input without ``keys`` collapses every matching key into one slot."""
    for channel, spec in zip(loaded.table.channels, loaded.mission.channels, strict=False):
        if spec.keys is not None:
            continue
        for element in spec.elements:
            if element.in_ is not None and has_wildcard(element.in_):
                report.warnings.append(
                    f"channel {channel.name!r}: input {element.in_!r} is a wildcard: every "
                    "matching key shares one slot and one output key; give the channel `keys` "
                    "to carry each key on its own")


def _data_per_s(sent: list[ChannelCodec], heartbeat_s: float | None) -> float:
    """Most frames per second a node's channels can fill (inf if one sends every turn)."""
    if any(c.interval_s <= 0 for c in sent):
        return math.inf
    return sum(1 / c.interval_s for c in sent) + (1 / heartbeat_s if heartbeat_s else 0.0)


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 4)


def silent_nodes(loaded: LoadedMission) -> list[dict[str, Any]]:
    """Nodes that would have to send but never get a turn under the mission's MAC (on no link
    of theirs): a sender of a channel, a receiver of a reliable one (it acknowledges), a
    query's server (it replies) and an asker a query names in its ``ask`` (an asker by default,
    every node that does not serve, may be a listener only: its gets end at their deadline).
    Each with ``loc`` (the caller locates it, then takes it out) and ``message``."""
    mission, network = loaded.mission, loaded.network
    missing: dict[str, str] = {}
    for name in mission.nodes:
        reasons = [mac_for(link.view).turn_missing(name) for link in network.links_of(name)]
        if reasons and all(reasons):
            where = [f"on link {link.name}: " if network.several else ""
                     for link in network.links_of(name)]
            missing[name] = "; ".join(w + str(r) for w, r in zip(where, reasons, strict=True))
    if not missing:
        return []
    places = {c.name: ("channels", i) for i, c in enumerate(mission.channels)}
    places.update({c.name: ("images", i) for i, c in enumerate(mission.images)})
    found: list[dict[str, Any]] = []

    def add(node: str, what: dict[str, str], role: str, loc: tuple[str | int, ...],
            message: str) -> None:  # (what: the channel or the query, by name)
        found.append({"node": node, **what, "as": role, "why": missing[node], "loc": loc,
                      "message": message})

    for c in loaded.table.channels:
        if (c.image is not None and c.image.control) or c.name not in places:
            continue  # an image's control: its receivers steer it where they can
        for node in c.senders:
            if node in missing and c.destinations(node):
                add(node, {"channel": c.name}, "sender", (*places[c.name], "from"),
                    f"node {node} sends channel {c.name!r} but never gets a turn to send under "
                    f"the mission's MAC, so its values would never leave: {missing[node]} (or "
                    f"take {node} out of this channel's from)")
        if not c.reliable:
            continue
        for node in dict.fromkeys(r for s in c.senders for r in c.destinations(s)):
            if node in missing:
                add(node, {"channel": c.name}, "receiver", (*places[c.name], "to"),
                    f"node {node} receives reliable channel {c.name!r} but never gets a turn to "
                    f"send, so it can never acknowledge and every value would be reported "
                    f"failed: {missing[node]} (or make the channel not reliable)")
    specs = {spec.name: spec for spec in loaded.table.queries}
    for i, query in enumerate(mission.queries):
        spec = specs[query.name]
        roles = [("server", "serve", spec.servers, spec.askers, "no get would ever be answered")]
        if query.ask is not None:
            roles.append(("asker", "ask", spec.askers, spec.servers, "its gets would never leave"))
        for role, place, nodes, others, effect in roles:
            for node in nodes:
                if node in missing and any(o != node for o in others):
                    add(node, {"query": query.name}, role, ("queries", i, place),
                        f"node {node} {place}s query {query.name!r} but never gets a turn to "
                        f"send, so {effect}: {missing[node]} (or take {node} out of this "
                        f"query's {place})")
    return found
