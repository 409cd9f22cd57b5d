"""Commands from the GUI: which channels it may send, their forms, and their fate (pure).

A command channel is a channel the GUI's node sends to other nodes. The GUI puts a value on
the channel's input key at that node, with the attachment ``ref:<uuid>``; a reliable channel's
sender reports the value's fate on ``@zab/<mission>/<node>/delivery/<channel>`` echoing that
``ref``. A best-effort channel reports nothing: after :data:`SENT_AFTER_S` without a report the
command counts as *sent*.
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from bridge.codec.fields import FieldCodec
from bridge.core.loaded import LoadedMission
from bridge.errors import EncodeError
from bridge.wire.channels import ElementCodec
from bridge.wire.families import FamilySpec
from bridge.words import counted

#: A best-effort command with no delivery report after this long is shown as "sent".
SENT_AFTER_S = 3.0
#: Commands remembered (and shown) at once; the oldest are forgotten first.
MAX_COMMANDS = 100
#: Longest text accepted for a ``json`` form field.
MAX_JSON_CHARS = 4096


class CommandError(ValueError):
    """A command the GUI cannot send; the message says which field and why."""


@dataclass(frozen=True)
class FormField:
    """One input of a command form, with the bounds and units from the mission."""

    path: str
    kind: str  # number | integer | boolean | enum | string | json
    minimum: float | None = None
    maximum: float | None = None
    values: tuple[str, ...] = ()
    max_length: int | None = None
    units: str | None = None
    description: str | None = None

    @classmethod
    def from_codec(cls, codec: FieldCodec) -> FormField:
        schema = codec.json_schema()
        spec = codec.spec
        kind = {"number": "number", "integer": "integer", "boolean": "boolean",
                "string": "string"}.get(str(schema.get("type")), "json")
        if "enum" in schema:
            kind = "enum"
        return cls(
            path=codec.path,
            kind=kind,
            minimum=schema.get("minimum"),
            maximum=schema.get("maximum"),
            values=tuple(str(v) for v in schema.get("enum", ())),
            max_length=schema.get("maxLength"),
            units=getattr(spec, "units", None),  # shown when the mission declares units
            description=spec.description,
        )

    def parse(self, raw: Any) -> Any:
        """The payload value for ``raw`` (as a form sends it), or :class:`CommandError`."""
        name = self.path or "(payload)"
        if self.kind in ("number", "integer"):
            number = _number(name, raw)
            if self.kind == "integer":
                if number != int(number):
                    raise CommandError(f"{name}: {raw!r} is not a whole number")
                number = int(number)
            if self.minimum is not None and number < self.minimum:
                raise CommandError(f"{name}: {number} is below the minimum {self.minimum}")
            if self.maximum is not None and number > self.maximum:
                raise CommandError(f"{name}: {number} is above the maximum {self.maximum}")
            return number
        if self.kind == "boolean":
            if isinstance(raw, bool):
                return raw
            if raw in ("true", "false"):
                return raw == "true"
            raise CommandError(f"{name}: expected true or false, got {raw!r}")
        if self.kind == "enum":
            if raw not in self.values:
                raise CommandError(f"{name}: {raw!r} is not one of {', '.join(self.values)}")
            return raw
        if self.kind == "string":
            if not isinstance(raw, str):
                raise CommandError(f"{name}: expected text, got {type(raw).__name__}")
            if self.max_length is not None and len(raw.encode()) > self.max_length:
                raise CommandError(f"{name}: longer than {self.max_length} bytes")
            return raw
        if not isinstance(raw, str) or len(raw) > MAX_JSON_CHARS:
            raise CommandError(f"{name}: expected JSON text of at most {MAX_JSON_CHARS} chars")
        try:
            return json.loads(raw)
        except ValueError as exc:
            raise CommandError(f"{name}: not valid JSON: {exc}") from None

    def describe(self) -> dict[str, Any]:
        return {"path": self.path, "kind": self.kind, "minimum": self.minimum,
                "maximum": self.maximum, "values": list(self.values),
                "max_length": self.max_length, "units": self.units,
                "description": self.description}


def _number(name: str, raw: Any) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float | str):
        raise CommandError(f"{name}: expected a number, got {raw!r}")
    try:
        number = float(raw)
    except ValueError:
        raise CommandError(f"{name}: {raw!r} is not a number") from None
    except OverflowError:  # (an integer past a float's range)
        raise CommandError(f"{name}: {raw} is not a finite number") from None
    if not math.isfinite(number):
        raise CommandError(f"{name}: {raw!r} is not a finite number")
    return number


Put = tuple[str, bytes, str]
"""A put of a command: (key, payload, encoding; ``""``: none, a ROS 2 topic's CDR)."""


@dataclass(frozen=True)
class CommandElement:
    """One element of a command channel as ``node`` puts it, and the fields of its payload."""

    fields: tuple[FormField, ...]
    element: ElementCodec
    node: str

    @property
    def key(self) -> str:
        """Where the put goes (:meth:`~bridge.wire.channels.ElementCodec.put_key`)."""
        return self.element.put_key(self.node)

    def put(self, raw: Any, now: float, member: str | None = None) -> Put:
        """The put of ``raw`` ({path: value}) at time ``now`` (a ROS 2 message's stamp), on
        the key of a key family's ``member``."""
        key = None if member is None else self.element.input_key(self.node, member)
        try:
            return self.element.sample(self.node, self.payload(raw), now, key)
        except EncodeError as exc:
            raise CommandError(f"{self.key}: {exc}") from None

    def payload(self, raw: Any) -> Any:
        """The payload built from ``raw`` ({path: value}); every field is required."""
        if not isinstance(raw, dict):
            raise CommandError(f"{self.key}: expected the fields as an object")
        unknown = set(raw) - {f.path for f in self.fields}
        if unknown:
            raise CommandError(f"{self.key}: unknown field {sorted(unknown)[0]!r}")
        out: dict[str, Any] = {}
        for spec in self.fields:
            if spec.path not in raw:
                raise CommandError(f"{self.key}: field {spec.path or '(payload)'!r} is missing")
            value = spec.parse(raw[spec.path])
            if not spec.path:
                return value
            _set(out, spec.path, value)
        return out


def _set(target: dict[str, Any], path: str, value: Any) -> None:
    *parents, last = path.split(".")
    for part in parents:
        target = target.setdefault(part, {})
    target[last] = value


def named_as_command(*names: str) -> bool:
    """A channel or key named as a command (``mission_command``, ``cmd``, ``command``),
    rather than a sensor value such as a GPS fix."""
    return any(word in name.lower() for name in names for word in ("command", "cmd"))


@dataclass(frozen=True)
class CommandChannel:
    """A channel the GUI's node sends: its form, its receivers, whether it is acknowledged."""

    channel: str
    destinations: tuple[str, ...]
    reliable: bool
    interval_s: float
    elements: tuple[CommandElement, ...]
    family: FamilySpec | None = None  # a key family: a command goes to one member's key

    def puts(self, values: Any, now: float, vehicle: str | None = None) -> list[Put]:
        """The put of each element from ``values`` (one {path: value} per element); on a
        key family, on the member named as the ``vehicle`` it goes to (a put on the family's
        expression names no one member: the bridge counts it and sends nothing)."""
        if isinstance(values, dict) and len(self.elements) == 1:
            values = [values]
        if not isinstance(values, list) or len(values) != len(self.elements):
            raise CommandError(f"channel {self.channel!r} needs values for "
                               f"{counted(len(self.elements), 'element')}")
        member = None
        if self.family is not None:
            if vehicle is None or not (self.family.learned or vehicle in self.family.members):
                raise CommandError(f"channel {self.channel!r} is a key family of "
                                   f"{', '.join(self.family.members)}: the GUI sends a vehicle "
                                   f"the member of its name, and {vehicle!r} is none of them")
            member = vehicle
        return [e.put(v, now, member) for e, v in zip(self.elements, values, strict=True)]

    def is_command(self) -> bool:
        """Named as a command: what an operator most likely wants to send."""
        return named_as_command(self.channel, *(e.key for e in self.elements))

    def describe(self) -> dict[str, Any]:
        return {"channel": self.channel, "destinations": list(self.destinations),
                "reliable": self.reliable, "interval_s": self.interval_s,
                "elements": [{"key": e.key, "fields": [f.describe() for f in e.fields]}
                             for e in self.elements]}


def command_channels(loaded: LoadedMission, node: str) -> list[CommandChannel]:
    """Channels ``node`` sends to others: reliable ones first, then those named as commands,
    then in mission order (the form opens on the first)."""
    found = []
    for model, channel in zip(loaded.mission.channels, loaded.table.channels, strict=False):
        if not channel.sent_by(node) or not channel.destinations(node):
            continue
        elements = tuple(
            CommandElement(tuple(FormField.from_codec(f) for f in element.layout.fields),
                           element, node)
            for element in channel.elements
        )
        found.append(CommandChannel(channel.name, channel.destinations(node),
                                    bool(getattr(model, "reliable", False)),
                                    channel.interval_s, elements, channel.family))
    return sorted(found, key=lambda c: (not c.reliable, not c.is_command()))


@dataclass
class Command:
    """One command sent from the GUI and what is known of its fate."""

    ref: str
    vehicle: str
    channel: str
    values: Any
    reliable: bool
    time: float
    state: str = "pending"  # pending | sent | delivered | failed
    detail: str | None = None  # the sender's last report: queued, sent, retrying ...
    reason: str | None = None
    others: dict[str, str] = field(default_factory=dict)  # other receivers' states
    updated: float = 0.0

    def item(self) -> dict[str, Any]:
        return {"kind": "command", "ref": self.ref, "vehicle": self.vehicle,
                "channel": self.channel, "values": self.values, "reliable": self.reliable,
                "time": self.time, "state": self.state, "detail": self.detail,
                "reason": self.reason, "others": dict(self.others), "updated": self.updated}


class CommandBook:
    """The GUI's commands by ``ref``: pending until a report (or, best effort, a timeout)."""

    def __init__(self, sent_after_s: float = SENT_AFTER_S, size: int = MAX_COMMANDS) -> None:
        self.sent_after_s = sent_after_s
        self.size = size
        self.commands: OrderedDict[str, Command] = OrderedDict()

    def add(self, command: Command) -> dict[str, Any]:
        command.updated = command.time
        self.commands[command.ref] = command
        while len(self.commands) > self.size:
            self.commands.popitem(last=False)
        return command.item()

    def report(self, report: dict[str, Any], now: float) -> dict[str, Any] | None:
        """Apply a delivery report; the command's new item, or None if the ref is not ours."""
        ref = report.get("ref")
        command = self.commands.get(ref) if isinstance(ref, str) else None
        if command is None:
            return None
        state = str(report.get("state"))
        dst = report.get("dst")
        if dst is not None and dst != command.vehicle:
            command.others[str(dst)] = state
        elif state in ("delivered", "failed"):
            command.state = state
            command.reason = report.get("reason")
        elif command.state == "pending":
            command.detail = state
        command.updated = now
        return command.item()

    def tick(self, now: float) -> list[dict[str, Any]]:
        """Best-effort commands silent for ``sent_after_s`` become "sent"."""
        changed = []
        for command in self.commands.values():
            if (command.state == "pending" and not command.reliable
                    and now - command.time >= self.sent_after_s):
                command.state = "sent"
                command.updated = now
                changed.append(command.item())
        return changed

    def items(self) -> list[dict[str, Any]]:
        return [c.item() for c in self.commands.values()]
