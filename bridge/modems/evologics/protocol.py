"""EvoLogics S2C AT interface, host side: bytes from the modem in, events out (sans-I/O).

Rules of this module (see ``modem-protocols.md`` §1; its [V]/[C]/[U] tags are repeated here):

- No I/O, no clock, no threads. :class:`HostProtocol` takes bytes with
  :meth:`~HostProtocol.receive_data` and returns events from :meth:`~HostProtocol.next_event`
  (or :data:`~bridge.modems.protocol.NEED_DATA`), like h11. Commands go out through
  :meth:`HostProtocol.send`, which returns the bytes to write and remembers which reply is
  expected.
- Modem bytes never raise: anything that cannot be parsed becomes a :class:`Malformed` event and
  the parser resynchronises. :class:`LocalProtocolError` is raised only for our own misuse (an
  impossible event or command), never for what the modem sends.
- Two modes. In **command mode** the modem prints bare ``OK\\r\\n`` and ``NAME,fields\\r\\n``.
  In **data mode** everything it says is wrapped ``+++AT<cmd>:<len>:<body>\\r\\n`` (``<cmd>``
  empty for notifications) and bytes outside such packets are raw burst data [V evins/BIR].
  Wrapped packets are also recognised at the start of a line in command mode (a reply printed
  while the modem switches modes).
- Payloads (``RECVIM`` & co.) are framed by their declared length, never by EOL: they may hold
  commas, CR/LF, NUL or ``+++AT`` [V BIR/evins].
- In command mode a bare reply line (``OK``, ``2``, ``ERROR ...``) is attributed to the oldest
  command sent that is still unanswered; data mode names the command in the wrapper. An
  asynchronous ``ERROR EFAULT`` in command mode is therefore indistinguishable from a reply when
  a command is pending; prefer data mode.
"""

from __future__ import annotations

import contextlib
import enum
import re
import typing
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from bridge.modems.protocol import NEED_DATA, NeedData

__all__ = [
    "BROADCAST",
    "IM_MAX_BYTES",
    "MAX_INCOMPLETE",
    "BurstData",
    "Busy",
    "CanceledIm",
    "Delivered",
    "DeliveredIm",
    "Error",
    "Event",
    "ExpiredIms",
    "Failed",
    "FailedIm",
    "HostProtocol",
    "LocalProtocolError",
    "Malformed",
    "Mode",
    "Notification",
    "Ok",
    "Recv",
    "RecvEnd",
    "RecvFailed",
    "RecvIm",
    "RecvImLegacy",
    "RecvIms",
    "RecvPbm",
    "RecvPbmLegacy",
    "RecvStart",
    "SendEnd",
    "SendStart",
    "UsblAngles",
    "UsblLong",
    "Value",
    "from_modem",
    "parse_body",
    "wrap",
]

IM_MAX_BYTES = 64
"""Largest instant-message payload [V DUNE ``c_im_max_size=64``, SUNSET, OSL]."""

BROADCAST = 255
"""Destination address of a broadcast IM (driver practice [V BIR]; firmware rule [U])."""

MAX_INCOMPLETE = 4096
"""Longest line or packet header kept while waiting for its end. ``AT&V`` (~400 B) and the
longest notification (``USBLPHYP``, ~250 B) fit easily; beyond this the bytes are garbage and are
reported as :class:`Malformed` rather than buffered forever (like h11's
``DEFAULT_MAX_INCOMPLETE_EVENT_SIZE``)."""

MAX_PAYLOAD = 1024
"""Largest declared payload accepted: a burst ``RECV`` (drivers cap a send at 1024 B [V OSL,
SUNSET]; an IM holds at most 64). A longer one is a corrupt length, not a wait."""

MAX_BODY = MAX_PAYLOAD + 256
"""Longest body of a ``+++AT`` packet: a ``RECV`` of :data:`MAX_PAYLOAD` and its header
(``AT&V`` ~400 B and ``USBLPHYP`` ~250 B are shorter)."""

MULTILINE_REPLIES = frozenset(["&V", "?P", "?S"])
"""Replies whose body may hold line ends (§1.4); every other body without a payload is one
line."""

TIES = b"+++AT"
CRLF = b"\r\n"



class Mode(enum.Enum):
    """Which interpreter the modem's host port is in."""

    COMMAND = "command"
    DATA = "data"


class LocalProtocolError(ValueError):
    """We asked for something the protocol cannot express (our bug, not the modem's)."""


# -- events ------------------------------------------------------------------------------------


class Event:
    """Base class of everything :class:`HostProtocol` emits."""

    def body(self) -> bytes:
        """The modem's text for this event, without wrapper and final CRLF (for emulators)."""
        raise NotImplementedError


@dataclass(frozen=True)
class Ok(Event):
    """``OK`` (``pending``: ``[*]OK``, accepted but applied later [V DUNE/SUNSET])."""

    command: str | None = None
    pending: bool = False

    def body(self) -> bytes:
        return b"[*]OK" if self.pending else b"OK"


@dataclass(frozen=True)
class Value(Event):
    """Any other synchronous reply: a value (``2``), a state, or a multi-line block."""

    command: str | None
    text: str

    def body(self) -> bytes:
        return self.text.encode("latin-1")


@dataclass(frozen=True)
class Error(Event):
    """``ERROR <reason>``; ``command`` is ``None`` when asynchronous (``ERROR EFAULT``)."""

    command: str | None
    reason: str

    def body(self) -> bytes:
        return f"ERROR {self.reason}".encode("latin-1") if self.reason else b"ERROR"


@dataclass(frozen=True)
class Busy(Event):
    """``BUSY <reason>``: the request was refused for now (``BACKOFF STATE``, ``DELIVERING``)."""

    command: str | None
    reason: str

    def body(self) -> bytes:
        return f"BUSY {self.reason}".encode("latin-1") if self.reason else b"BUSY"


@dataclass(frozen=True)
class BurstData(Event):
    """Raw bytes outside ``+++AT`` packets in data mode: received burst data."""

    data: bytes

    def body(self) -> bytes:
        return self.data


@dataclass(frozen=True)
class Malformed(Event):
    """Bytes the parser could not make sense of (kept for logs; the parser moved past them)."""

    data: bytes
    reason: str

    def body(self) -> bytes:
        return self.data


@dataclass(frozen=True)
class Notification(Event):
    """An asynchronous line without a typed event (``BITRATE``, ``RADDR``, ``PHYOFF``, ...).

    ``data`` holds the binary tail of ``NOISE`` lines.
    """

    name: str
    fields: tuple[str, ...] = ()
    data: bytes = b""

    def body(self) -> bytes:
        parts = [self.name, *self.fields]
        out = ",".join(parts).encode("latin-1")
        if self.name == "NOISE":
            out += b"," + self.data
        return out


class _Typed(Event):
    """A notification with a fixed, typed field list: ``NAME,f1,f2,...``.

    Subclasses are dataclasses whose fields, in order, are the line's fields. Classes with
    ``PAYLOAD`` carry ``len`` first (implicit, from ``data``), an optional ``p<pid>`` before it,
    and ``data`` last.
    """

    NAME: ClassVar[str]
    PAYLOAD: ClassVar[bool] = False
    _types: ClassVar[tuple[tuple[str, type], ...]] = ()

    @classmethod
    def _spec(cls) -> tuple[tuple[str, type], ...]:
        if "_types" not in cls.__dict__:
            hints = typing.get_type_hints(cls)
            cls._types = tuple(
                (f.name, _base_type(hints[f.name]))
                for f in fields(cls)  # type: ignore[arg-type]
                if f.name not in ("data", "pid")
            )
        return cls._types

    @classmethod
    def n_fields(cls) -> int:
        """Fields after the name (and after ``len`` for payload lines), ``data`` excluded."""
        return len(cls._spec())

    @classmethod
    def from_fields(cls, values: list[bytes], data: bytes = b"", pid: int | None = None) -> Any:
        spec = cls._spec()
        if len(values) != len(spec):
            raise ValueError(f"{cls.NAME} needs {len(spec)} fields, got {len(values)}")
        kwargs: dict[str, Any] = {name: _convert(raw, kind) for (name, kind), raw in
                                  zip(spec, values, strict=True)}
        if cls.PAYLOAD:
            kwargs["data"] = data
            kwargs["pid"] = pid
        return cls(**kwargs)

    def body(self) -> bytes:
        parts: list[str] = [self.NAME]
        if self.PAYLOAD:
            pid = self.pid  # type: ignore[attr-defined]
            if pid is not None:
                parts.append(f"p{pid}")
            parts.append(str(len(self.data)))  # type: ignore[attr-defined]
        parts.extend(_format(getattr(self, name)) for name, _ in self._spec())
        out = ",".join(parts).encode("latin-1")
        if self.PAYLOAD:
            out += b"," + self.data  # type: ignore[attr-defined]
        return out


def _base_type(hint: Any) -> type:
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    found: type = args[0] if args else hint
    return found


_INT = re.compile(rb"[+-]?\d{1,20}")
_FLOAT = re.compile(rb"[+-]?(\d{1,20}(\.\d{0,20})?|\.\d{1,20})([eE][+-]?\d{1,3})?")
_WORD = re.compile(rb"[A-Za-z0-9_.+-]{0,32}")


def _convert(raw: bytes, kind: type) -> Any:
    if kind is int:
        if not _INT.fullmatch(raw):
            raise ValueError(f"not an integer: {raw!r}")
        return int(raw)
    if kind is float:
        if not _FLOAT.fullmatch(raw):
            raise ValueError(f"not a number: {raw!r}")
        return float(raw)
    if not _WORD.fullmatch(raw):
        raise ValueError(f"bad word: {raw!r}")
    return raw.decode("ascii")


def _format(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


@dataclass(frozen=True)
class RecvIm(_Typed):
    """An instant message arrived [V evins/BIR]. ``duration_us``: its airtime."""

    NAME: ClassVar[str] = "RECVIM"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    flag: str
    duration_us: int
    rssi: int
    integrity: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


@dataclass(frozen=True)
class RecvImLegacy(_Typed):
    """``RECVIM`` of firmware 1.6: bitrate and propagation time instead of duration [V DUNE]."""

    NAME: ClassVar[str] = "RECVIM"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    flag: str
    bitrate: int
    rssi: int
    integrity: int
    ptime_us: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


@dataclass(frozen=True)
class RecvIms(_Typed):
    """A synchronous IM arrived; ``timestamp_us`` is the modem clock at reception [V fields]."""

    NAME: ClassVar[str] = "RECVIMS"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    timestamp_us: int
    duration_us: int
    rssi: int
    integrity: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


@dataclass(frozen=True)
class RecvPbm(_Typed):
    """A piggy-back message arrived (no flag field) [V fields]."""

    NAME: ClassVar[str] = "RECVPBM"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    duration_us: int
    rssi: int
    integrity: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


@dataclass(frozen=True)
class RecvPbmLegacy(_Typed):
    """``RECVPBM`` of firmware 1.6: bitrate and propagation time in place of duration, as in
    its ``RECVIM`` [C: by analogy with the 1.6 ``RECVIM`` of DUNE; no 1.6 ``RECVPBM`` is in a
    stored source]."""

    NAME: ClassVar[str] = "RECVPBM"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    bitrate: int
    rssi: int
    integrity: int
    ptime_us: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


LEGACY: dict[bytes, type[_Typed]] = {b"RECVIM": RecvImLegacy, b"RECVPBM": RecvPbmLegacy}
"""Firmware 1.6's layouts of the length-framed lines that changed in 1.7 (DUNE)."""


def firmware_is_legacy(version: str) -> bool:
    """Whether an ``ATI0`` reply (``1.6``, ``1.9``, ``2.0.1`` ...) names firmware older than
    1.7, which prints ``RECVIM``/``RECVPBM`` in the 1.6 layout [V DUNE]; ``ValueError`` if it
    is not a version."""
    match = re.match(r"\s*(\d+)\.(\d+)", version)
    if match is None:
        raise ValueError(f"not a firmware version: {version!r}")
    return (int(match[1]), int(match[2])) < (1, 7)


@dataclass(frozen=True)
class Recv(_Typed):
    """Burst data arrived (command mode) [V fields]."""

    NAME: ClassVar[str] = "RECV"
    PAYLOAD: ClassVar[bool] = True
    src: int
    dst: int
    bitrate: int
    rssi: int
    integrity: int
    ptime_us: int
    velocity: float
    data: bytes = b""
    pid: int | None = None


@dataclass(frozen=True)
class DeliveredIm(_Typed):
    """The ack of the IM to ``dst`` came back [V]."""

    NAME: ClassVar[str] = "DELIVEREDIM"
    dst: int


@dataclass(frozen=True)
class FailedIm(_Typed):
    """No ack for the IM to ``dst`` after the modem's retries (``AT!RI``) [V]."""

    NAME: ClassVar[str] = "FAILEDIM"
    dst: int


@dataclass(frozen=True)
class ExpiredIms(_Typed):
    """A synchronous IM to ``dst`` was too late to send [V]."""

    NAME: ClassVar[str] = "EXPIREDIMS"
    dst: int


@dataclass(frozen=True)
class CanceledIm(Event):
    """``CANCELEDIM``/``CANCELEDIMS``/``CANCELEDPBM`` (``kind`` ``IM``/``IMS``/``PBM``) [V]."""

    kind: str
    dst: int

    def body(self) -> bytes:
        return f"CANCELED{self.kind},{self.dst}".encode()


@dataclass(frozen=True)
class Delivered(_Typed):
    """Burst data delivered: ``count`` bytes to ``dst`` [V evins]."""

    NAME: ClassVar[str] = "DELIVERED"
    count: int
    dst: int


@dataclass(frozen=True)
class Failed(_Typed):
    """Burst data failed: ``count`` bytes to ``dst`` [V evins]."""

    NAME: ClassVar[str] = "FAILED"
    count: int
    dst: int


@dataclass(frozen=True)
class SendStart(_Typed):
    """Transmission to ``addr`` begins (``@ZX1``): ``kind`` ``im``/``ims``/``pbm``/... [V]."""

    NAME: ClassVar[str] = "SENDSTART"
    addr: int
    kind: str
    duration_us: int
    delay_us: int


@dataclass(frozen=True)
class SendEnd(_Typed):
    """Transmission ended; ``timestamp_us`` (modem clock) marks its START [V]."""

    NAME: ClassVar[str] = "SENDEND"
    addr: int
    kind: str
    timestamp_us: int
    duration_us: int


@dataclass(frozen=True)
class RecvStart(_Typed):
    """A signal is being received (``@ZX1``) [V]."""

    NAME: ClassVar[str] = "RECVSTART"


@dataclass(frozen=True)
class RecvEnd(Event):
    """Reception ended; ``timestamp_us`` (modem clock) marks its start. ``velocity`` is the
    optional fifth field seen in a BIR test [V]."""

    timestamp_us: int
    duration_us: int
    rssi: int
    integrity: int
    velocity: float | None = None

    def body(self) -> bytes:
        parts = [self.timestamp_us, self.duration_us, self.rssi, self.integrity]
        text = "RECVEND," + ",".join(map(str, parts))
        if self.velocity is not None:
            text += "," + repr(self.velocity)
        return text.encode()


@dataclass(frozen=True)
class RecvFailed(_Typed):
    """A signal was detected but could not be decoded [V fields]."""

    NAME: ClassVar[str] = "RECVFAILED"
    velocity: float
    rssi: int
    integrity: int


@dataclass(frozen=True)
class UsblLong(_Typed):
    """USBL fix of ``remote_addr`` (``@ZU1``, USBL heads): XYZ in the head frame, ENU, attitude,
    propagation time (µs), RSSI, integrity and accuracy [V 16 fields]."""

    NAME: ClassVar[str] = "USBLLONG"
    cur_time: float
    meas_time: float
    remote_addr: int
    x: float
    y: float
    z: float
    e: float
    n: float
    u: float
    roll: float
    pitch: float
    yaw: float
    ptime_us: int
    rssi: int
    integrity: int
    accuracy: float


@dataclass(frozen=True)
class UsblAngles(_Typed):
    """USBL bearing/elevation of ``remote_addr`` (angles in radians) [V fields]."""

    NAME: ClassVar[str] = "USBLANGLES"
    cur_time: float
    meas_time: float
    remote_addr: int
    lbearing: float
    lelevation: float
    bearing: float
    elevation: float
    roll: float
    pitch: float
    yaw: float
    rssi: int
    integrity: int
    accuracy: float


_TYPED: dict[str, type[_Typed]] = {
    cls.NAME: cls
    for cls in (
        RecvIm, RecvIms, RecvPbm, Recv, DeliveredIm, FailedIm, ExpiredIms, Delivered, Failed,
        SendStart, SendEnd, RecvStart, RecvFailed, UsblLong, UsblAngles,
    )
}

_PAYLOAD_NAMES = {b"RECVIM": 7, b"RECVIMS": 7, b"RECVPBM": 6, b"RECV": 7, b"NOISE": 3}
"""Length-framed lines: fields between ``len`` and the payload [V evins/BIR]."""

KNOWN_NOTIFICATIONS = frozenset(
    [*_TYPED, "RECVEND", "CANCELEDIM", "CANCELEDIMS", "CANCELEDPBM", "BITRATE", "SRCLEVEL",
     "RADDR", "PHYON", "PHYOFF", "DROPCNT", "STATUS", "RECVSRV", "RECVPROBE", "USBLPHYD",
     "USBLPHYP", "ECLK", "RTO", "NOISE"]
)
"""Names that start an asynchronous line (§1.7); any other line in command mode is a reply."""

_NAME = re.compile(r"%?[A-Z][A-Z0-9]*")


_DATA_MODE_REPLY = re.compile(rb"\+\+\+AT[^:\r\n]*:\d+:")


def from_modem(line: bytes) -> bool:
    """Whether ``line`` is one an EvoLogics modem writes: a data-mode reply
    (``+++AT<command>:<len>:…``), a reply (``OK``, ``ERROR …``, ``BUSY …``) or a notification
    it names (§1.7)."""
    body = line.strip(b"\r\n")
    if _DATA_MODE_REPLY.match(body) or body in (b"OK", b"[*]OK"):
        return True
    return body.startswith((b"ERROR", b"BUSY")) or \
        body.partition(b",")[0].decode("latin-1") in KNOWN_NOTIFICATIONS


def wrap(body: bytes, mode: Mode, command: str = "") -> bytes:
    """What the modem writes for ``body``: bare + CRLF in command mode, or the data-mode packet
    ``+++AT<command>:<len>:<body>\\r\\n`` [V]."""
    if mode is Mode.COMMAND:
        return body + CRLF
    return b"+++AT%s:%d:%s\r\n" % (command.encode("latin-1"), len(body), body)


def parse_body(command: str | None, body: bytes, *, legacy_recvim: bool = False) -> Event:
    """The event for one complete body (a wrapped packet's, or one command-mode line).

    ``command`` is the reply's command name (``"?AL"``), or ``None``/``""`` for a notification.
    Never raises: a body that does not parse is a :class:`Malformed`.
    """
    try:
        if command:
            return _reply(command, body)
        return _notification(body, legacy_recvim)
    except (ValueError, UnicodeDecodeError) as exc:
        return Malformed(body, str(exc))


def _reply(command: str | None, body: bytes) -> Event:
    if body == b"OK":
        return Ok(command)
    if body == b"[*]OK":
        return Ok(command, pending=True)
    if body == b"ERROR" or body.startswith(b"ERROR "):
        return Error(command, body[6:].decode("latin-1"))
    if body == b"BUSY" or body.startswith(b"BUSY "):
        return Busy(command, body[5:].decode("latin-1"))
    return Value(command, body.decode("latin-1"))


def _notification(body: bytes, legacy_recvim: bool) -> Event:
    if body in (b"OK", b"[*]OK") or body.startswith((b"ERROR", b"BUSY")):
        return _reply(None, body)
    name_raw, sep, rest = body.partition(b",")
    name = name_raw.decode("ascii")
    if name_raw in _PAYLOAD_NAMES:
        event = _payload_event(name_raw, rest if sep else b"", legacy_recvim, whole=True)[0]
        assert not isinstance(event, NeedData)  # (whole: the line is all there is)
        return event
    if name.startswith("CANCELED") and name[8:] in ("IM", "IMS", "PBM"):
        return CanceledIm(name[8:], int(_convert(rest, int)))
    if name == "RECVEND":
        values = rest.split(b",")
        if len(values) not in (4, 5):
            raise ValueError(f"RECVEND needs 4 or 5 fields, got {len(values)}")
        start, duration, rssi, integrity = (int(_convert(v, int)) for v in values[:4])
        velocity = _convert(values[4], float) if len(values) == 5 else None
        return RecvEnd(start, duration, rssi, integrity, velocity)
    cls = _TYPED.get(name)
    if cls is not None:
        values = rest.split(b",") if sep else []
        return cls.from_fields(values)
    if _NAME.fullmatch(name) and b"\r" not in rest and b"\n" not in rest:
        return Notification(name, tuple(rest.decode("latin-1").split(",")) if sep else ())
    raise ValueError("not a notification")


def _payload_header(rest: bytes, n_fields: int) -> tuple[int | None, int, list[bytes], int] | None:
    """Parse ``[p<pid>,]len,f1,...,fn,`` at the start of ``rest``.

    Returns ``(pid, len, fields, offset of the payload)``, or ``None`` if ``rest`` ends first.
    Raises ``ValueError`` for a header that can never become valid.
    """
    pos = 0
    values: list[bytes] = []
    pid: int | None = None
    need = n_fields + 1  # len and the fixed fields
    while len(values) < need:
        comma = rest.find(b",", pos, pos + 40)
        if comma < 0:
            chunk = rest[pos : pos + 40]
            if len(chunk) >= 40 or b"\r" in chunk or b"\n" in chunk:
                raise ValueError("payload header field too long or cut by a line end")
            return None
        value = rest[pos:comma]
        if b"\r" in value or b"\n" in value:
            raise ValueError("payload header cut by a line end")
        if not values and pid is None and value.startswith(b"p"):
            pid = int(_convert(value[1:], int))
        else:
            values.append(value)
        pos = comma + 1
    length = int(_convert(values[0], int))
    if not 0 <= length <= MAX_PAYLOAD:
        raise ValueError(f"declared length {length} out of range")
    return pid, length, values[1:], pos


def _payload_event(
    name: bytes, rest: bytes, legacy_recvim: bool, *, whole: bool
) -> tuple[Event | NeedData, int]:
    """Build a length-framed event from ``rest`` (after ``NAME,``).

    With ``whole`` the payload must end ``rest`` exactly (a data-mode body); otherwise it must be
    followed by CRLF and the number of bytes used (including CRLF) is returned; ``(NEED_DATA, 0)``
    if more bytes are needed.
    """
    cls: type[_Typed] | None = None
    if name != b"NOISE":
        cls = LEGACY.get(name) if legacy_recvim else None
        cls = cls or _TYPED[name.decode()]
    header = _payload_header(rest, cls.n_fields() if cls is not None else 3)
    if header is None:
        if whole:
            raise ValueError(f"{name.decode()} header incomplete")
        return NEED_DATA, 0
    pid, length, values, start = header
    end = start + length
    if whole:
        if len(rest) != end:
            raise ValueError(f"{name.decode()} declares {length} B, body holds {len(rest) - start}")
    else:
        if len(rest) < end + 2:
            return NEED_DATA, 0
        if rest[end : end + 2] != CRLF:
            raise ValueError(f"{name.decode()} payload of {length} B not followed by CRLF")
    data = rest[start:end]
    if cls is None:
        fields_ = (str(length), *(v.decode("latin-1") for v in values))
        return Notification("NOISE", fields_, data), end + 2
    return cls.from_fields(values, data, pid), end + 2


# -- the host-side connection ------------------------------------------------------------------


@dataclass
class HostProtocol:
    """The host's view of one modem port: feed bytes, read events, serialise commands.

    ``eol`` is what ends a host command: ``b"\\r"`` on serial, ``b"\\n"`` on Ethernet [V].
    ``legacy_recvim`` parses ``RECVIM`` and ``RECVPBM`` in the firmware-1.6 layout.
    """

    mode: Mode = Mode.DATA
    eol: bytes = b"\r"
    legacy_recvim: bool = False
    _buffer: bytearray = field(default_factory=bytearray, repr=False)
    _outgoing: bytearray = field(default_factory=bytearray, repr=False)
    _pending: deque[str] = field(default_factory=deque, repr=False)
    _block: list[bytes] | None = field(default=None, repr=False)

    def send(self, text: str | bytes, *, name: str | None = None, reply: bool = True) -> None:
        """Queue the command ``AT<text>`` in the current mode (take its bytes with
        :meth:`data_to_send`); remembers the expected reply.

        ``text`` is what follows ``AT`` (``"?AL"``, ``b"*SENDIM,2,1,ack,hi"``); ``name`` is the
        reply's command name (default: derived, see :func:`command_name`).
        """
        raw = text.encode("latin-1") if isinstance(text, str) else bytes(text)
        if not raw:
            raise LocalProtocolError("empty command")
        prefix = TIES if self.mode is Mode.DATA else b"AT"
        if reply:
            self._pending.append(name or command_name(raw))
        self._outgoing += prefix + raw + self.eol

    def data_to_send(self) -> bytes:
        """The bytes queued for the modem since the last call (as the Micro-Modem's)."""
        data, self._outgoing = bytes(self._outgoing), bytearray()
        return data

    @property
    def pending(self) -> tuple[str, ...]:
        """Names of the commands sent and not answered yet (oldest first)."""
        return tuple(self._pending)

    def clear_pending(self) -> None:
        """Forget unanswered commands (after a timeout) and any half-read multi-line reply."""
        self._pending.clear()
        self._block = None

    def receive_data(self, data: bytes) -> None:
        """Add bytes received from the modem."""
        self._buffer += data

    def events(self) -> Iterator[Event]:
        """Every event that the bytes received so far complete."""
        while (event := self.next_event()) is not NEED_DATA:
            yield event

    def next_event(self) -> Event | NeedData:
        """The next event, or :data:`~bridge.modems.protocol.NEED_DATA`."""
        while True:
            if not self._buffer:
                return NEED_DATA
            data_mode = self.mode is Mode.DATA
            event = self._next_data_mode() if data_mode else self._next_command_mode()
            if event is not None:
                return event

    # -- data mode -----------------------------------------------------------------------------

    def _next_data_mode(self) -> Event | NeedData | None:
        buf = self._buffer
        at = buf.find(TIES)
        if at < 0:
            keep = _partial_prefix(buf)
            raw = bytes(buf[: len(buf) - keep])
            if not raw:
                return NEED_DATA
            del buf[: len(raw)]
            return BurstData(raw)
        if at > 0:
            raw = bytes(buf[:at])
            del buf[:at]
            return BurstData(raw)
        return self._wrapped()

    def _wrapped(self) -> Event | NeedData | None:
        """A ``+++AT<cmd>:<len>:<body>\\r\\n`` packet at the start of the buffer."""
        buf = self._buffer
        colon = buf.find(b":", 5, 5 + 40)
        if colon < 0:
            head = bytes(buf[5 : 5 + 40])
            if len(head) < 40 and _command_chars(head):
                return NEED_DATA
            return self._bad(5, "no ':' after +++AT<command>")
        command = bytes(buf[5:colon])
        if not _command_chars(command):
            return self._bad(5, f"bad command name {command!r}")
        colon2 = buf.find(b":", colon + 1, colon + 9)
        if colon2 < 0:
            digits = bytes(buf[colon + 1 : colon + 9])
            if not digits or (len(digits) < 8 and digits.isdigit()):
                return NEED_DATA
            return self._bad(5, "bad length in +++AT packet")
        digits = bytes(buf[colon + 1 : colon2])
        if not digits.isdigit() or int(digits) > MAX_BODY:
            reason = f"bad length {digits[:12]!r} in +++AT packet"
            return self._bad(self._line_end(colon2 + 1), reason)
        name = command.decode("ascii")
        start = colon2 + 1
        end = start + int(digits)
        own = _body_length(name, bytes(buf[start : start + MAX_BODY + 2]), self.legacy_recvim)
        if own is not None and own != end - start:
            # the body ends where its own content says: a corrupt length gives up there rather
            # than wait for the length's bytes and swallow the packets behind it
            if buf[start + own : start + own + 2] == CRLF:
                return self._bad(start + own + 2,
                                 f"+++AT packet declares {end - start} B, its body holds {own}")
            if len(buf) < start + own + 2 and buf[end : end + 2] != CRLF:
                return NEED_DATA
        if buf[end : end + 2] != CRLF:
            if len(buf) < end + 2:
                return NEED_DATA
            return self._bad(5, f"+++AT packet of {end - start} B not followed by CRLF")
        body = bytes(buf[start:end])
        del buf[: end + 2]
        if name:
            self._answered(name)
        return parse_body(name or None, body, legacy_recvim=self.legacy_recvim)

    def _line_end(self, at: int) -> int:
        """Bytes up to and including the first CRLF from ``at`` (up to ``at`` if none yet)."""
        crlf_at = self._buffer.find(CRLF, at, at + MAX_INCOMPLETE)
        return crlf_at + 2 if crlf_at >= 0 else at

    def _bad(self, skip: int, reason: str) -> Malformed:
        data = bytes(self._buffer[:skip])
        del self._buffer[:skip]
        return Malformed(data, reason)

    def _answered(self, name: str) -> None:
        with contextlib.suppress(ValueError):  # a reply to a command we gave up on
            self._pending.remove(name)

    # -- command mode --------------------------------------------------------------------------

    def _next_command_mode(self) -> Event | NeedData | None:
        buf = self._buffer
        if buf.startswith(TIES) or (len(buf) < 5 and TIES.startswith(buf)):
            if len(buf) < 5:
                return NEED_DATA
            return self._wrapped()
        if self._block is None:
            comma = buf.find(b",", 0, 16)
            crlf_at = buf.find(CRLF, 0, 16)
            name = bytes(buf[:comma]) if comma >= 0 and (crlf_at < 0 or comma < crlf_at) else None
            if name in _PAYLOAD_NAMES:
                try:
                    event, used = _payload_event(name, bytes(buf[comma + 1 :]),
                                                 self.legacy_recvim, whole=False)
                except ValueError as exc:
                    return self._skip_line(str(exc))
                if event is NEED_DATA:
                    return self._need_or_overflow(len(name) + 1 + MAX_PAYLOAD + 600)
                del buf[: comma + 1 + used]
                return event
        crlf_at = buf.find(CRLF)
        if crlf_at < 0:
            return self._need_or_overflow(MAX_INCOMPLETE)
        line = bytes(buf[:crlf_at])
        del buf[: crlf_at + 2]
        return self._line(line)

    def _line(self, line: bytes) -> Event | None:
        if self._block is not None:  # inside a multi-line AT&V block, ended by an empty line
            if line:
                self._block.append(line)
                return None
            text = b"\r\n".join(self._block) + CRLF
            self._block = None
            self._answered("&V")
            return Value("&V", text.decode("latin-1"))
        if not self._pending:
            return parse_body(None, line, legacy_recvim=self.legacy_recvim) if line else None
        if line.split(b",", 1)[0].decode("latin-1") in KNOWN_NOTIFICATIONS:
            event = parse_body(None, line, legacy_recvim=self.legacy_recvim)
            if not isinstance(event, Malformed):
                return event
        return self._reply_line(line)  # e.g. "FAILED" is also a reply to AT?DI

    def _reply_line(self, line: bytes) -> Event | None:
        command = self._pending[0]
        if command == "&V" and line not in (b"OK", b"[*]OK") and not line.startswith(
            (b"ERROR", b"BUSY")
        ):
            self._block = [line] if line else []
            if not line:
                self._block = None
                self._pending.popleft()
                return Value("&V", "")
            return None
        self._pending.popleft()
        return parse_body(command, line, legacy_recvim=self.legacy_recvim)

    def _skip_line(self, reason: str) -> Malformed:
        buf = self._buffer
        crlf_at = buf.find(CRLF)
        end = crlf_at + 2 if crlf_at >= 0 else len(buf)
        data = bytes(buf[:end])
        del buf[:end]
        return Malformed(data, reason)

    def _need_or_overflow(self, limit: int) -> Event | NeedData:
        if len(self._buffer) <= limit:
            return NEED_DATA
        return self._bad(limit, f"no line end within {limit} bytes")


def _body_length(command: str, body: bytes, legacy_recvim: bool) -> int | None:
    """Where a wrapped body ends by its own content, before its declared length is read:
    a payload line's ``len`` field, else the first CRLF of a one-line body. ``None``: not
    known yet (or a multi-line reply)."""
    name, sep, rest = body.partition(b",")
    if sep and name in _PAYLOAD_NAMES:
        cls = LEGACY.get(name) if legacy_recvim else None
        n = 3 if name == b"NOISE" else (cls or _TYPED[name.decode()]).n_fields()
        try:
            header = _payload_header(rest, n)
        except ValueError:
            return None
        return None if header is None else len(name) + 1 + header[3] + header[1]
    if command in MULTILINE_REPLIES:
        return None
    crlf_at = body.find(CRLF)
    return crlf_at if crlf_at >= 0 else None


def _partial_prefix(buf: bytes | bytearray) -> int:
    """Length of the longest tail of ``buf`` that could start ``+++AT``."""
    for n in range(min(4, len(buf)), 0, -1):
        if TIES.startswith(bytes(buf[-n:])):
            return n
    return 0


def _command_chars(raw: bytes) -> bool:
    return all(0x21 <= b <= 0x7E and b != 0x3A for b in raw)


_TRAILING_PARAM = re.compile(rb"[0-9.+-]+$")


def command_name(text: bytes) -> str:
    """The name a data-mode reply echoes for the command ``AT<text>``: its text without
    parameters (``*SENDIM,...`` -> ``*SENDIM``, ``!AL2`` -> ``!AL``, ``@ZX1`` -> ``@ZX``) [V]."""
    head = text.split(b",", 1)[0]
    stripped = _TRAILING_PARAM.sub(b"", head) or head
    return stripped.decode("latin-1")
