"""Mission logs: every frame and runtime event of one node in an MCAP file.

MCAP is the robotics log format that Foxglove and the ``mcap`` tools open. One file per node;
messages are JSON (message encoding ``json``) with a JSON Schema per topic, so Foxglove plots
them as they are. Topics:

- ``/zab/<node>/frame_sent``, ``/zab/<node>/frame_received``, ``/zab/<node>/frame_dropped``:
  the raw frame (``data_hex``), time, size, channels and, for receptions, the link metadata
  and the decoded values of every channel;
- ``/zab/<node>/channel/<channel>``: each received channel's decoded elements (its schema is
  the channel's element layouts), the easiest topic to plot;
- ``/zab/<node>/picture_published``: each picture an image channel published: its key, its
  metadata and its stream's bytes since the one before (``start``, ``data_hex``);
- ``/zab/<node>/<kind>`` for every other event: ``range``, ``position``, ``link``,
  ``payload_drops``, ``send_failed``, ``modem_down``, ``modem_up``, ``delivery``,
  ``transfer``, ...

The mission itself is attached (``mission.yaml``, as validated) with metadata ``zab``
(mission, node, fingerprint), so :func:`read_log` alone can replay the decoded data and the
pictures.

:class:`MissionLog` is an ``on_event`` callback for :class:`~bridge.runtime.zenoh_node.BridgeNode`;
it puts what it has recorded on disk every :data:`FLUSH_S` (a chunk closed, the file flushed
and fsynced, off the caller's thread), so a node killed outright loses about a second of it.
:func:`summarise` and :func:`read_log` read a file back, a cut-short one too.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import yaml
from mcap.records import Attachment, Channel, Message, Metadata
from mcap.writer import CompressionType, Writer

from bridge.codec import ArrayCodec, BytesCodec, Layout
from bridge.core.events import Event, FrameReceived
from bridge.core.loaded import LoadedMission, parse_mission
from bridge.errors import MissionError
from bridge.runtime.mcap_scan import WholeRecords
from bridge.wire.channels import ChannelCodec, ChannelTable
from bridge.wire.payload_schema import adapt_schema
from bridge.wire.payloads import encode_payload

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

__all__ = [
    "FleetLogs", "LogError", "LogRecord", "MissionLog", "MissionLogFile", "Received",
    "read_log", "received_values", "replay", "restore_bytes", "summarise",
]

PROFILE = "zab"
MISSION_ATTACHMENT = "mission.yaml"
CHUNK_BYTES = 32 * 1024
"""A chunk is closed when this big, or every :data:`FLUSH_S`, whichever comes first."""
FLUSH_S = 1.0
"""How often a log puts what it has recorded on disk: at most this much is lost to a kill."""

_OBJECT = {"type": "object"}
_TIME = {"type": "number", "description": "Host clock, seconds since 1970"}
_HEX = {"type": "string", "description": "Raw frame bytes, hex"}
_NAMES = {"type": "array", "items": {"type": "string"}}
_FRAME_SCHEMAS: dict[str, dict[str, Any]] = {
    "frame_sent": {"time": _TIME, "bytes": {"type": "integer"}, "channels": _NAMES,
                   "dest": {"type": ["string", "null"]}, "data_hex": _HEX},
    "frame_received": {"time": _TIME, "src": {"type": "string"}, "bytes": {"type": "integer"},
                       "channels": _NAMES, "data_hex": _HEX, "meta": _OBJECT,
                       "values": {"type": "object", "additionalProperties": {"type": "array"}},
                       "members": {"type": "object", "description": "Key families: channel "
                                   "-> member -> element values"}},
    "frame_dropped": {"time": _TIME, "src": {"type": ["string", "null"]},
                      "reason": {"type": "string"}, "data_hex": _HEX},
    "picture_published": {"time": _TIME, "channel": {"type": "string"},
                          "src": {"type": "string"}, "key": {"type": "string"},
                          "start": {"type": "integer"}, "meta": _OBJECT,
                          "data_hex": {"type": "string", "description": "The picture's "
                                       "stream from start, hex"}},
}


class LogError(Exception):
    """A mission log cannot be read (not MCAP, cut short before its metadata, or not written
    by zab)."""


def _jsonable(value: Any) -> Any:
    """Event data as JSON: bytes as hex, non-finite floats as null, keys as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set):
        return [_jsonable(v) for v in value]
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    if isinstance(value, int | float | str | bool) or value is None:
        return value
    return str(value)


def _topic_schema(title: str, properties: dict[str, Any]) -> bytes:
    schema = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
              "type": "object", "properties": properties}
    return json.dumps(schema).encode()


def _channel_schema(channel: ChannelCodec) -> dict[str, Any]:
    items = [json_view_schema(e.layout) for e in channel.elements]
    return {"time": _TIME, "src": {"type": "string"},
            "elements": {"type": "array", "prefixItems": items, "minItems": len(items),
                         "maxItems": len(items)}}


def json_view_schema(layout: Layout) -> dict[str, Any]:
    """A layout's schema as the log stores it (bytes fields as hex strings)."""
    schema: dict[str, Any] = adapt_schema(layout.json_schema(), "out")
    schema.pop("$schema", None)
    return schema


def _sync(stream: IO[bytes]) -> None:
    """Have the OS write ``stream``'s file to its disk, if it can (and it is still open)."""
    with contextlib.suppress(OSError, ValueError):  # closed meanwhile (close syncs it), or
        os.fsync(stream.fileno())  # a file system without fsync


class MissionLog:
    """Records one node's events into an MCAP file; call it as ``on_event(event)``.

    Never raises into the runtime: an event that cannot be written is counted in ``failed``.
    A thread puts what was recorded on disk every ``flush_s`` (:meth:`flush`; ``None``: only
    when a chunk fills and at :meth:`close`).
    """

    def __init__(self, path: str | Path, loaded: LoadedMission, node: str,
                 clock: Callable[[], float] = time.time,
                 flush_s: float | None = FLUSH_S) -> None:
        self.path = Path(path)
        self.loaded = loaded
        self.node = node
        self.clock = clock
        self.counts: Counter[str] = Counter()
        self.failed = 0
        self._channels: dict[str, int] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream: IO[bytes] = self.path.open("wb")
        self._writer = Writer(self._stream, chunk_size=CHUNK_BYTES,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library="zenoh-acoustic-bridge")
        mission = loaded.mission
        self._writer.add_metadata("zab", {
            "mission": mission.mission, "node": node,
            "fingerprint": loaded.table.fingerprint.hex(), "source": str(loaded.path)})
        text = yaml.safe_dump(mission.model_dump(by_alias=True, mode="json", exclude_unset=True),
                              sort_keys=False)
        now_ns = int(clock() * 1e9)
        self._writer.add_attachment(now_ns, now_ns, MISSION_ATTACHMENT, "application/yaml",
                                    text.encode())
        self._closed = False
        self._lock = threading.Lock()  # the writer is used by the caller and the flusher
        self._dirty = True  # recorded since the last flush
        self.flush()  # the mission is on disk from the start
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_s is not None:
            self._flusher = threading.Thread(target=self._flush_every, args=(flush_s,),
                                             name=f"log-{node}", daemon=True)
            self._flusher.start()

    def flush(self) -> None:
        """Close the chunk in progress and put the file on disk (fsync); a failure is
        counted in ``failed``, never raised."""
        with self._lock:
            if self._closed or not self._dirty:
                return
            self._dirty = False
            try:
                self._writer.flush()
            except Exception:  # as an event that cannot be written: counted
                self.failed += 1
                return
        _sync(self._stream)  # (outside the lock: the caller never waits for the disk)

    def _flush_every(self, period: float) -> None:
        while not self._stop.wait(period):
            self.flush()

    def _channel_id(self, topic: str, properties: dict[str, Any]) -> int:
        found = self._channels.get(topic)
        if found is None:
            schema_id = self._writer.register_schema(topic.rsplit("/", 1)[-1], "jsonschema",
                                                     _topic_schema(topic, properties))
            found = self._channels[topic] = self._writer.register_channel(topic, "json",
                                                                          schema_id)
        return found

    def _write(self, topic: str, properties: dict[str, Any], message: dict[str, Any],
               t: float) -> None:
        channel = self._channel_id(topic, properties)
        ns = int(t * 1e9)
        self._writer.add_message(channel, ns, json.dumps(message).encode(), ns)

    def __call__(self, event: Event) -> None:
        with self._lock:
            if self._closed:
                return
            self._dirty = True
            try:
                self._record(event)
            except Exception:  # a log must never stop the bridge; counted instead
                self.failed += 1

    def _record(self, event: Event) -> None:
        kind, info = event.kind, event.to_dict()
        t = float(event.time) if math.isfinite(event.time) else self.clock()
        message = _jsonable({k: v for k, v in info.items() if k != "data"})
        message["time"] = t
        if "data" in info and isinstance(info["data"], bytes | bytearray):
            message["data_hex"] = bytes(info["data"]).hex()
        prefix = f"/zab/{self.node}"
        self.counts[kind] += 1
        self._write(f"{prefix}/{kind}", _FRAME_SCHEMAS.get(kind, {}), message, t)
        if not isinstance(event, FrameReceived):
            return
        for name, elements in event.values.items():
            try:
                channel = self.loaded.table.by_name(name)
            except StopIteration:
                continue
            self._write(f"{prefix}/channel/{name}", _channel_schema(channel),
                        {"time": t, "src": event.src, "elements": _jsonable(elements)}, t)

    def close(self) -> None:
        """Write the summary and close the file (safe to call twice)."""
        self._stop.set()
        if self._flusher is not None and self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
                self._stream.flush()
                _sync(self._stream)
            finally:
                self._stream.close()

    def __enter__(self) -> MissionLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FleetLogs:
    """One :class:`MissionLog` per node in ``folder`` (``<mission>-<node>.mcap``); call it as a
    :class:`~bridge.runtime.fleet.Fleet` ``on_event(node, event)``."""

    def __init__(self, folder: str | Path, loaded: LoadedMission,
                 flush_s: float | None = FLUSH_S) -> None:
        self.folder = Path(folder)
        self.loaded = loaded
        self.flush_s = flush_s
        self.logs: dict[str, MissionLog] = {}

    def path_of(self, node: str) -> Path:
        return self.folder / f"{self.loaded.mission.mission}-{node}.mcap"

    def __call__(self, node: str, event: Event) -> None:
        log = self.logs.get(node)
        if log is None:
            log = self.logs[node] = MissionLog(self.path_of(node), self.loaded, node,
                                               flush_s=self.flush_s)
        log(event)

    def close(self) -> None:
        for log in self.logs.values():
            log.close()


@dataclass(frozen=True)
class LogRecord:
    """One message of a mission log."""

    topic: str
    kind: str
    time: float
    data: dict[str, Any]


@dataclass
class MissionLogFile:
    """A mission log read back: its mission, node and records in time order."""

    path: Path
    node: str
    loaded: LoadedMission | None
    records: list[LogRecord] = field(default_factory=list)
    note: str | None = None
    """Set when the log ends without its footer (cut short) or is damaged: what was read."""

    @property
    def complete(self) -> bool:
        """The log was closed properly (nothing is missing from it)."""
        return self.note is None


def _kind(topic: str, node: str) -> str:
    rest = topic.removeprefix(f"/zab/{node}/")
    return "channel" if rest.startswith("channel/") else rest


def read_log(path: str | Path) -> MissionLogFile:
    """Read a mission log; :class:`LogError` with a clear message if it is not one.

    A log cut short (its node killed: no footer, a last record half written) is read as far
    as its records are whole; its ``note`` says so.
    """
    p = Path(path)
    try:
        with p.open("rb") as stream:
            scan = WholeRecords(stream)
            meta, text, messages = _contents(scan)
            cut_short = scan.cut_short
    except FileNotFoundError:
        raise LogError(f"{p}: no such file") from None
    except OSError as exc:
        raise LogError(f"{p}: cannot read it: {exc}") from None
    if meta is None:
        if scan.complete:
            raise LogError(f"{p}: an MCAP file, but not a zab mission log (no 'zab' metadata)")
        if scan.size == 0:
            raise LogError(f"{p}: an empty file (its node stopped before writing anything)")
        if cut_short:
            raise LogError(f"{p}: cut short before its 'zab' metadata (its node stopped "
                           "abruptly?): nothing to read")
        raise LogError(f"{p}: not a readable MCAP file ({scan.problem})")
    node = meta.get("node", "")
    loaded = None
    if text is not None:
        try:
            loaded = parse_mission(text.decode(), f"{p}:{MISSION_ATTACHMENT}")
        except (MissionError, UnicodeDecodeError) as exc:
            raise LogError(f"{p}: the attached mission is invalid: {exc}") from None
    messages.sort(key=lambda m: m[1])  # (stable: equal times stay in the order written)
    records = [LogRecord(topic, _kind(topic, node), t, data) for topic, t, data in messages]
    note = None
    read = f"{len(records)} record{'' if len(records) == 1 else 's'} read"
    if cut_short:
        note = f"{p}: the log ends without its footer (its node was stopped abruptly, or " \
            f"still runs): {read}"
    elif not scan.complete:
        note = f"{p}: the log is damaged at byte {scan.stopped_at} of {scan.size} " \
            f"({scan.problem}): {read} before it"
    return MissionLogFile(p, node, loaded, records, note)


def _contents(scan: WholeRecords) -> tuple[dict[str, str] | None, bytes | None,
                                           list[tuple[str, float, Any]]]:
    """The 'zab' metadata, the attached mission and the messages (topic, time, data) of the
    whole records of a log."""
    meta: dict[str, str] | None = None
    text: bytes | None = None
    topics: dict[int, str] = {}
    messages: list[tuple[str, float, Any]] = []
    for record in scan:
        if isinstance(record, Message):
            topic = topics.get(record.channel_id)
            if topic is not None:
                try:
                    data = json.loads(record.data)
                except ValueError:
                    continue  # not zab's JSON (a whole record is as written): left out
                messages.append((topic, record.log_time / 1e9, data))
        elif isinstance(record, Channel):
            topics[record.id] = record.topic
        elif isinstance(record, Metadata) and record.name == "zab" and meta is None:
            meta = record.metadata
        elif isinstance(record, Attachment) and record.name == MISSION_ATTACHMENT:
            text = record.data
    return meta, text, messages


def summarise(log: MissionLogFile) -> dict[str, Any]:
    """Per-channel counts and ages, and per-kind event counts, as plain data.

    A channel's ``age_s`` is the time from its last reception to the end of the log;
    ``max_gap_s`` the longest time between two receptions (or from the log's start).
    """
    if not log.records:
        return {"node": log.node, "start": None, "end": None, "duration_s": 0.0,
                "events": {}, "channels": {}}
    start, end = log.records[0].time, log.records[-1].time
    events = Counter(r.kind for r in log.records if r.kind != "channel")
    sent: Counter[str] = Counter()
    received: dict[str, list[float]] = defaultdict(list)
    sources: dict[str, set[str]] = defaultdict(set)
    for r in log.records:
        if r.kind == "frame_sent":
            sent.update(r.data.get("channels") or [])
        elif r.kind == "frame_received":
            for name in r.data.get("channels") or ():
                received[name].append(r.time)
                sources[name].add(str(r.data.get("src")))
    names = list(dict.fromkeys([*sent, *received]))
    if log.loaded is not None:
        names = [c.name for c in log.loaded.table.channels if c.name in sent or c.name in received]
    channels = {}
    for name in names:
        times = received.get(name, [])
        gaps = [b - a for a, b in zip([start, *times], times, strict=False)]
        channels[name] = {
            "sent": sent[name],
            "received": len(times),
            "from": sorted(sources.get(name, ())),
            "last": times[-1] if times else None,
            "age_s": round(end - times[-1], 3) if times else None,
            "max_gap_s": round(max(gaps), 3) if gaps else None,
        }
    return {"node": log.node, "mission": log.loaded.mission.mission if log.loaded else None,
            "start": start, "end": end, "duration_s": round(end - start, 3),
            "events": dict(events), "channels": channels}


def restore_bytes(layout: Layout, value: Any) -> Any:
    """Undo the log's hex for the ``bytes`` fields of ``layout`` (other values unchanged)."""
    for codec in layout.fields:
        element = codec.element if isinstance(codec, ArrayCodec) else codec
        if not isinstance(element, BytesCodec):
            continue
        parts = codec.path.split(".") if codec.path else []
        if not parts:
            return _unhex(value)
        node = value
        for part in parts[:-1]:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and parts[-1] in node:
            node[parts[-1]] = _unhex(node[parts[-1]])
    return value


def _unhex(value: Any) -> Any:
    if isinstance(value, list):
        return [_unhex(v) for v in value]
    if isinstance(value, str):
        try:
            return bytes.fromhex(value)
        except ValueError:
            return value
    return value


@dataclass(frozen=True)
class Received:
    """One value a node published, as its log tells it: at ``time`` on ``key``; a ROS 2
    topic's (``ros2`` set) is the message's plain data, a picture its file (``image/…``)."""

    time: float
    key: str
    value: Any
    encoding: str
    ros2: Ros2Element | None = None


def received_values(log: MissionLogFile) -> Iterator[Received]:
    """Every decoded value the node published, and every picture (its file, and its ROS 2
    CompressedImage where the channel has ``out_topic``)."""
    if log.loaded is None:
        raise LogError(f"{log.path}: no mission attached; cannot name the output keys")
    table = log.loaded.table
    streams: dict[tuple[str, str, Any], bytearray] = {}  # (channel, src, sequence): so far
    for r in log.records:
        if r.kind == "picture_published":
            yield from _picture(r.time, table, streams, r.data, log.node)
            continue
        if r.kind != "frame_received":
            continue
        src = str(r.data.get("src"))
        for name, elements in (r.data.get("values") or {}).items():
            try:
                channel = table.by_name(name)
            except StopIteration:
                continue
            members = (r.data.get("members") or {}).get(name, {}) if channel.family else \
                {"*": elements}
            for member, values in members.items():
                for element, value in zip(channel.elements, values, strict=False):
                    yield Received(r.time, element.output_key(src, log.node, member),
                                   restore_bytes(element.layout, value), element.encoding,
                                   element.ros2)


def _picture(at: float, table: ChannelTable, streams: dict[tuple[str, str, Any], bytearray],
             data: dict[str, Any], node: str) -> Iterator[Received]:
    """A logged picture, decoded from its stream so far as the receiver did (nothing where
    the log lacks its start: it began in the middle)."""
    from bridge.core.images import picture_file, pixel_encoding, ros2_picture
    from bridge.image.codec import ImageStreamError, decode

    meta = data.get("meta") or {}
    stream = streams.setdefault((data["channel"], data["src"], meta.get("sequence")),
                                bytearray())
    start, chunk = int(data["start"]), bytes.fromhex(data["data_hex"])
    if start > len(stream):
        return
    stream[start:] = chunk
    try:
        spec = table.by_name(data["channel"]).image
        pixels = decode(bytes(stream)).pixels
    except (StopIteration, ImageStreamError):
        return
    if spec is None:
        return
    file = picture_file(pixels, spec, meta)
    yield Received(at, str(data["key"]), file, f"image/{spec.format}")
    ros2 = ros2_picture(spec, str(data["src"]), node, file, pixel_encoding(pixels),
                        float(meta.get("time", at)))
    if ros2 is not None:
        yield Received(at, *ros2, "cdr", spec.ros2_out)


def replay(
    log: MissionLogFile,
    publish: Callable[[str, bytes, str], None],
    *,
    publish_ros2: Callable[[str, Any, Ros2Element, float], None] | None = None,
    speed: float = 1.0,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> int:
    """Publish every decoded value again, ``speed`` times faster than recorded (0: at once).

    ``publish(key, payload, encoding)`` gets the payload encoded as the element says
    (msgpack by default, a picture's file as it is); a ROS 2 topic's value goes to
    ``publish_ros2(key, message, element, time recorded)`` instead (its publisher writes
    rmw_zenoh's CDR and attachment), or is left out without one. Returns how many values
    were published.
    """
    if speed < 0 or not math.isfinite(speed):
        raise ValueError(f"speed must be >= 0 (0 = as fast as possible), not {speed}")
    count = 0
    first: float | None = None
    started = clock()
    for got in received_values(log):
        if got.ros2 is not None and publish_ros2 is None:
            continue
        if first is None:
            first = got.time
        if speed > 0:
            delay = (got.time - first) / speed - (clock() - started)
            if delay > 0:
                sleep(delay)
        if got.ros2 is not None:
            assert publish_ros2 is not None
            publish_ros2(got.key, got.value, got.ros2, got.time)
        else:
            publish(got.key, *encode_payload(got.value, got.encoding))
        count += 1
    return count
