"""JSON Schema (draft 2020-12) of every bridged key's payload (``zab schema --payloads``).

For each channel element of a mission: the *input* key each sender reads and the *output* key
each receiver publishes, with the schema of the payload there, built from the element's field
layout (types, min/max, enum values, string/bytes lengths, arrays). Applications in any language
validate what they publish, or generate types, from these files.

Schemas describe the JSON view of a payload. In msgpack payloads (the default) a ``bytes``
field is a msgpack ``bin``; its JSON view is a hex string, as the bridge publishes it in JSON
(see :func:`json_view`). At an input key an enum also accepts its index.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Literal

from bridge.wire.channels import ChannelCodec, ChannelTable, ElementCodec
from bridge.wire.images import CONTROL_BOUNDS, PICTURE_METADATA, REQUESTS
from bridge.wire.sample_meta import HIDDEN

DRAFT = "https://json-schema.org/draft/2020-12/schema"
Direction = Literal["in", "out"]

__all__ = [
    "KeySchema", "adapt_schema", "json_view", "key_schemas", "schema_path",
    "write_payload_schemas",
]


@dataclass
class KeySchema:
    """The payload schema of one concrete key, with where it is used."""

    key: str
    direction: Direction
    channel: str
    element: int
    encoding: str
    nodes: list[str] = field(default_factory=list)
    schema: dict[str, Any] = field(default_factory=dict)

    def document(self, mission: str) -> dict[str, Any]:
        """The schema file's content: the layout schema with an id, title and ``x-zab``."""
        where = "read by" if self.direction == "in" else "published at"
        doc: dict[str, Any] = {
            "$schema": DRAFT,
            "$id": f"zab:{mission}/{self.direction}/{self.key}",
            "title": self.key,
            "description": (f"Payload of `{self.key}`, {where} {', '.join(self.nodes)}; "
                            f"channel `{self.channel}` of mission `{mission}`."),
        }
        doc.update({k: v for k, v in self.schema.items() if k not in ("$schema",
                                                                      "description")})
        if "description" in self.schema:
            doc["description"] += " " + self.schema["description"]
        doc["x-zab"] = {"mission": mission, "direction": self.direction, "channel": self.channel,
                        "element": self.element, "encoding": self.encoding,
                        "nodes": list(self.nodes)}
        return doc


def adapt_schema(node: Any, direction: Direction) -> Any:
    """Rewrite a layout schema for one direction: bytes as hex strings; input enums also take
    their index."""
    if isinstance(node, list):
        return [adapt_schema(item, direction) for item in node]
    if not isinstance(node, dict):
        return node
    out = {k: adapt_schema(v, direction) for k, v in node.items()}
    if "x-max-bytes" in out:  # a bytes field
        size = out.pop("x-max-bytes")
        out.pop("contentEncoding", None)
        out.update({"type": "string", "contentEncoding": "base16", "maxLength": 2 * size,
                    "pattern": "^([0-9a-fA-F]{2})*$", "x-msgpack": "bin"})
    if direction == "in" and "enum" in out and all(isinstance(v, str) for v in out["enum"]):
        names = out.pop("enum")
        out["anyOf"] = [{"enum": names},
                        {"type": "integer", "minimum": 0, "maximum": len(names) - 1}]
    return out


def _element_schema(element: ElementCodec, direction: Direction) -> dict[str, Any]:
    """The payload's schema; the fields the bridge carries beside it (deletes, encodings,
    attachments, ages: :mod:`bridge.wire.sample_meta`) are not the application's."""
    schema = element.layout.json_schema()
    if element.meta is not None:
        schema["properties"] = {k: v for k, v in schema["properties"].items()
                                if k not in HIDDEN}
        schema["required"] = [k for k in schema["required"] if k not in HIDDEN]
    adapted: dict[str, Any] = adapt_schema(schema, direction)
    return adapted


def _uses(channel: ChannelCodec) -> Iterator[tuple[Direction, str, int, ElementCodec, str]]:
    """(direction, key, element index, element, node) for every use of a channel's elements."""
    for i, element in enumerate(channel.elements):
        for src in channel.senders:
            if not channel.destinations(src):
                continue
            yield "in", element.input_key(src), i, element, src
            for dst in channel.destinations(src):
                yield "out", element.output_key(src, dst), i, element, dst


def _image_uses(channel: ChannelCodec) -> Iterator[tuple[Direction, str, str, str,
                                                           dict[str, Any]]]:
    """(direction, key, encoding, node, schema) for every use of an image channel: the
    pictures each camera reads and each receiver publishes, and the operator's control each
    receiver reads (the camera's bridge takes it: it is published nowhere)."""
    spec = channel.image
    assert spec is not None
    if spec.control:
        def whole(name: str, most: int = 1 << 62, least: int = 0) -> dict[str, Any]:
            low, high = CONTROL_BOUNDS[name]
            return {"type": "integer", "minimum": max(low, least), "maximum": min(high, most)}

        schema = {
            "description": "An operator's control (any subset): settings for the next "
                           "pictures and a request (now: the newest picture at once; cancel: "
                           "give up the one in flight).",
            "type": "object", "additionalProperties": False,
            "properties": {
                "request": {"enum": list(REQUESTS)},
                "width": whole("width"), "height": whole("height"),
                "budget_bytes": whole("budget_bytes", spec.largest_budget,
                                      spec.smallest_budget),
                "roi": {"description": "[x0, y0, x1, y1] in fractions of the picture, or "
                                       "null for none",
                        "oneOf": [{"type": "null"}, {
                            "type": "array", "minItems": 4, "maxItems": 4,
                            "items": {"type": "number", "minimum": 0, "maximum": 1}}]}}}
        for dst in channel.senders:  # (the pictures' receivers, steering each camera)
            for src in channel.destinations(dst):
                yield "in", spec.control_key.format(node=dst, dst=dst, src=src), "msgpack", \
                    dst, schema
        return
    taken = [f"image/{kind}" for kind in spec.accept]
    if spec.ros2 is not None:
        read: dict[str, Any] = {
            "description": f"A ROS 2 {spec.ros2.msgtype} (CDR, rmw_zenoh {spec.ros2.distro})."}
        encoding = "cdr"
    else:
        read = {"description": f"A picture: {' or '.join(k.upper() for k in spec.accept)} "
                               f"bytes, the Zenoh encoding ({', '.join(taken)}) or the bytes' "
                               "signature saying which.",
                "anyOf": [{"contentMediaType": kind} for kind in taken]}
        encoding = "|".join(taken)
    shown = {"description": f"The picture so far, a {spec.format.upper()} any viewer shows, "
                            "sharper at each one; zab's metadata in it as zab:<key> (PNG "
                            "text, a JPEG's JSON comment).",
             "contentMediaType": f"image/{spec.format}",
             "x-zab-metadata": {f"zab:{k}": v for k, v in PICTURE_METADATA.items()}}
    for src in channel.senders:
        if not channel.destinations(src):
            continue
        yield "in", spec.input_key(src), encoding, src, read
        for dst in channel.destinations(src):
            yield "out", spec.output_key(src, dst), f"image/{spec.format}", dst, shown
            ros2_key = spec.ros2_output_key(src, dst)
            if ros2_key is not None and spec.ros2_out is not None:
                yield "out", ros2_key, "cdr", dst, {
                    "description": f"The same picture as a ROS 2 {spec.ros2_out.msgtype} (CDR, "
                                   f"rmw_zenoh {spec.ros2_out.distro}): format "
                                   f"'<rgb8|mono8>; {spec.format} compressed <bgr8|mono8>', "
                                   "header.stamp its zab:time; while the camera is reachable "
                                   "over IP, its file as it came (format saying its type and "
                                   "pixels: mono8, mono16, rgb8 or rgba8)."}


def key_schemas(table: ChannelTable) -> list[KeySchema]:
    """Every bridged key's schema, inputs first then outputs, each sorted by key.

    A key read (or published) by several channels gets one schema whose ``allOf`` holds each.
    """
    found: dict[tuple[Direction, str], KeySchema] = {}
    for channel in table.channels:
        if channel.image is not None:
            for direction, key, encoding, node, schema in _image_uses(channel):
                use = found.setdefault((direction, key), KeySchema(
                    key, direction, channel.name, 0, encoding, schema=schema))
                if node not in use.nodes:
                    use.nodes.append(node)
            continue
        for direction, key, index, element, node in _uses(channel):
            entry = found.get((direction, key))
            schema = _element_schema(element, direction)
            if entry is None:
                entry = found[(direction, key)] = KeySchema(
                    key, direction, channel.name, index, element.encoding, schema=schema)
            elif (entry.channel, entry.element) != (channel.name, index):
                parts = entry.schema.get("allOf", [entry.schema])
                if schema not in parts:
                    entry.schema = {"allOf": [*parts, schema]}
                    entry.channel = f"{entry.channel},{channel.name}"
            if node not in entry.nodes:
                entry.nodes.append(node)
    return sorted(found.values(), key=lambda s: (s.direction != "in", s.key))


def schema_path(entry: KeySchema) -> PurePosixPath:
    """Where a key's schema goes under the output folder: ``in/<key>.schema.json``."""
    parts = entry.key.split("/")
    if any(p in ("", ".", "..") for p in parts):
        raise ValueError(f"key {entry.key!r} cannot name a file")
    return PurePosixPath(entry.direction, *parts[:-1], f"{parts[-1]}.schema.json")


def write_payload_schemas(table: ChannelTable, mission: str, out: Path) -> list[Path]:
    """Write every key's schema of ``mission`` (its channel ``table``) under ``out`` plus
    ``index.json``; return the files written."""
    written: list[Path] = []
    index = []
    for entry in key_schemas(table):
        relative = schema_path(entry)
        path = out.joinpath(*relative.parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(entry.document(mission), indent=2) + "\n", encoding="utf-8")
        written.append(path)
        index.append({"key": entry.key, "direction": entry.direction, "channel": entry.channel,
                      "encoding": entry.encoding, "nodes": entry.nodes, "file": str(relative)})
    index_path = out / "index.json"
    out.mkdir(parents=True, exist_ok=True)
    index_path.write_text(json.dumps({"mission": mission, "keys": index}, indent=2) + "\n",
                          encoding="utf-8")
    return [*written, index_path]


def json_view(value: Any) -> Any:
    """A decoded payload as the schemas see it: bytes as hex, tuples as lists."""
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    if isinstance(value, dict):
        return {k: json_view(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_view(v) for v in value]
    return value
