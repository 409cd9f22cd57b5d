"""EvoLogics AT commands: builders for the host, and the modem's command reader (sans-I/O).

Builders return the text after ``AT`` (bytes) for :meth:`HostProtocol.send
<bridge.modems.evologics.protocol.HostProtocol.send>`. :class:`CommandReader` is the other
direction,
what an emulated modem does with the host's bytes: in command mode it reads ``AT...`` lines, in
data mode it finds ``+++AT`` commands among transparent burst data; in both, ``AT*SEND*``
payloads are framed by their declared length (they may hold CR, LF, commas or ``+++AT``) [V].
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from bridge.modems.evologics.protocol import (
    IM_MAX_BYTES,
    MAX_INCOMPLETE,
    TIES,
    LocalProtocolError,
    Mode,
    _partial_prefix,
    command_name,
)
from bridge.modems.protocol import NEED_DATA

__all__ = [
    "CommandReader",
    "HostBurst",
    "HostCommand",
    "HostGarbage",
    "SendRequest",
    "send_im",
    "send_ims",
    "set_value",
]

ACK_FLAGS = ("ack", "noack", "force")


def send_im(data: bytes, dst: int, *, ack: bool = False, pid: int | None = None) -> bytes:
    """``*SENDIM,[p<pid>,]<len>,<dst>,ack|noack,<data>`` (≤ 64 B) [V]."""
    if not 1 <= len(data) <= IM_MAX_BYTES:
        raise LocalProtocolError(f"an instant message holds 1..{IM_MAX_BYTES} B, not {len(data)}")
    if not 0 <= dst <= 255:
        raise LocalProtocolError(f"destination {dst} outside 0..255")
    head = f"*SENDIM,{'' if pid is None else f'p{pid},'}{len(data)},{dst},"
    return head.encode() + (b"ack," if ack else b"noack,") + bytes(data)


def send_ims(data: bytes, dst: int, usec: int | None, *, pid: int | None = None) -> bytes:
    """``*SENDIMS,[p<pid>,]<len>,<dst>,[<usec>],<data>``: a synchronous IM (≤ 64 B, no ack),
    sent when the modem clock reads ``usec`` (µs, 32 bits), or at once if None [V syntax].

    [U] Which instant ``usec`` marks (the start of the emission, as ``SENDEND`` timestamps are
    taken to) and how far ahead it may lie are not confirmed by any stored source.
    """
    if not 1 <= len(data) <= IM_MAX_BYTES:
        raise LocalProtocolError(f"an instant message holds 1..{IM_MAX_BYTES} B, not {len(data)}")
    if not 0 <= dst <= 255:
        raise LocalProtocolError(f"destination {dst} outside 0..255")
    if usec is not None and not 0 <= usec < 1 << 32:
        raise LocalProtocolError(f"send time {usec} µs outside the 32-bit modem clock")
    head = (f"*SENDIMS,{'' if pid is None else f'p{pid},'}{len(data)},{dst},"
            f"{'' if usec is None else usec},")
    return head.encode() + bytes(data)


def set_value(name: str, value: int | str) -> bytes:
    """``!<name><value>`` or ``@<name><value>`` (``name`` includes its ``!``/``@``)."""
    if name[:1] not in ("!", "@"):
        raise LocalProtocolError(f"a setting starts with ! or @, not {name!r}")
    return f"{name}{value}".encode()


# -- modem side --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SendRequest:
    """The parsed head of an ``AT*SEND*`` command: ``kind`` is ``IM``, ``IMS``, ``PBM`` or ``""``
    (burst). ``flag`` is ``ack``/``noack``/``force`` for IMs, ``usec`` the IMS send time."""

    kind: str
    dst: int
    data: bytes
    flag: str = ""
    usec: int | None = None
    pid: int | None = None


@dataclass(frozen=True)
class HostCommand:
    """One command from the host: ``text`` after ``AT`` (without EOL), its reply ``name``, and
    for sends the parsed :class:`SendRequest` (``None`` if the send was malformed: ``error``)."""

    text: bytes
    name: str
    send: SendRequest | None = None
    error: str = ""


@dataclass(frozen=True)
class HostBurst:
    """Transparent data the host wrote in data mode (burst data for the remote ``AR``)."""

    data: bytes


@dataclass(frozen=True)
class HostGarbage:
    """A command-mode line that is not an AT command (the modem answers ERROR WRONG FORMAT)."""

    data: bytes


HostInput = HostCommand | HostBurst | HostGarbage

_SEND = re.compile(rb"\*SEND(IMS|IM|PBM|)(?=,)")
_SEND_FIELDS = {b"IM": 3, b"IMS": 3, b"PBM": 2, b"": 2}
"""Fields before the payload, ``len`` included: ``len,dst,flag``, ``len,dst,usec``, ``len,dst``."""


@dataclass
class CommandReader:
    """The modem's reading of host bytes (EOL ``\\r``, ``\\n`` or ``\\r\\n`` all accepted)."""

    mode: Mode = Mode.DATA
    _buffer: bytearray = field(default_factory=bytearray)

    def receive_data(self, data: bytes) -> None:
        self._buffer += data

    def clear(self) -> None:
        """Forget buffered bytes (a reboot)."""
        self._buffer.clear()

    @property
    def holding_escape(self) -> bool:
        """The buffer is exactly ``+++`` (a guard-time escape if silence follows) [V BIR]."""
        return self.mode is Mode.DATA and bytes(self._buffer) == b"+++"

    def take_escape(self) -> None:
        """Consume a held ``+++`` as the guard-time escape."""
        if self.holding_escape:
            self._buffer.clear()

    def inputs(self) -> Iterator[HostInput]:
        while (item := self.next_input()) is not NEED_DATA:
            yield item

    def next_input(self) -> Any:
        """The next :class:`HostCommand`, :class:`HostBurst`, :class:`HostGarbage`, or NEED_DATA."""
        buf = self._buffer
        while True:
            if not buf:
                return NEED_DATA
            if self.mode is Mode.DATA:
                at = buf.find(TIES)
                if at < 0:
                    keep = _partial_prefix(buf)
                    if keep == len(buf):
                        return NEED_DATA
                    raw = bytes(buf[: len(buf) - keep])
                    del buf[: len(raw)]
                    return HostBurst(raw)
                if at > 0:
                    raw = bytes(buf[:at])
                    del buf[:at]
                    return HostBurst(raw)
                item = self._command(3)
            else:
                while buf.startswith((b"\r", b"\n")):
                    del buf[:1]
                if not buf:
                    return NEED_DATA
                if not buf.startswith(b"AT") and not (len(buf) < 2 and b"AT".startswith(buf)):
                    end = _eol(buf)
                    if end < 0:
                        if len(buf) > MAX_INCOMPLETE:
                            raw = bytes(buf)
                            buf.clear()
                            return HostGarbage(raw)
                        return NEED_DATA
                    raw = bytes(buf[:end])
                    del buf[: end + 1]
                    return HostGarbage(raw)
                if len(buf) < 2:
                    return NEED_DATA
                item = self._command(0)
            if item is not None:
                return item

    def _command(self, skip: int) -> Any:
        """A command starting at ``buf[skip:]`` (``AT...``); framed sends by length."""
        buf = self._buffer
        body_at = skip + 2
        match = _SEND.match(buf, body_at)
        if match:
            return self._send(body_at, match)
        end = _eol(buf, body_at)
        if end < 0:
            if len(buf) > MAX_INCOMPLETE:
                raw = bytes(buf)
                buf.clear()
                return HostGarbage(raw)
            return NEED_DATA
        text = bytes(buf[body_at:end])
        del buf[: _after_eol(buf, end)]
        if not text:
            return HostCommand(b"", "", error="empty command")
        return HostCommand(text, command_name(text))

    def _send(self, body_at: int, match: re.Match[bytes]) -> Any:
        buf = self._buffer
        kind = match.group(1)
        pos = match.end() + 1
        values: list[bytes] = []
        pid: int | None = None
        while len(values) < _SEND_FIELDS[kind]:
            comma = buf.find(b",", pos, pos + 24)
            if comma < 0:
                chunk = bytes(buf[pos : pos + 24])
                if len(chunk) < 24 and b"\r" not in chunk and b"\n" not in chunk:
                    return NEED_DATA
                return self._bad_send(body_at, kind, "send header malformed")
            value = bytes(buf[pos:comma])
            if not values and pid is None and value.startswith(b"p") and value[1:].isdigit():
                pid = int(value[1:])
            else:
                values.append(value)
            pos = comma + 1
        if not values[0].isdigit() or not values[1].isdigit():
            return self._bad_send(body_at, kind, "bad length or destination")
        length, dst = int(values[0]), int(values[1])
        limit = 1024 if kind == b"" else IM_MAX_BYTES
        if not 1 <= length <= limit:
            # the modem's exact reply to an oversize IM is [U]; ours is ERROR WRONG FORMAT
            return self._bad_send(body_at, kind, f"length {length} outside 1..{limit}")
        if len(buf) < pos + length + 1:
            return NEED_DATA
        data = bytes(buf[pos : pos + length])
        end = pos + length
        if bytes(buf[end : end + 1]) not in (b"\r", b"\n"):
            return self._bad_send(body_at, kind, "payload not followed by EOL")
        text = bytes(buf[body_at:end])
        del buf[: _after_eol(buf, end)]
        flag, usec = "", None
        if kind in (b"IM",):
            flag = values[2].decode("latin-1")
            if flag not in ACK_FLAGS:
                return HostCommand(text, f"*SEND{kind.decode()}", error=f"bad flag {flag!r}")
        elif kind == b"IMS":
            if values[2] and not values[2].isdigit():
                return HostCommand(text, "*SENDIMS", error="bad time")
            usec = int(values[2]) if values[2] else None
        request = SendRequest(kind.decode(), dst, data, flag, usec, pid)
        return HostCommand(text, f"*SEND{kind.decode()}", send=request)

    def _bad_send(self, body_at: int, kind: bytes, reason: str) -> HostCommand:
        """Skip to the next EOL (the modem resynchronises on line ends)."""
        buf = self._buffer
        end = _eol(buf, body_at)
        stop = _after_eol(buf, end) if end >= 0 else len(buf)
        text = bytes(buf[body_at : end if end >= 0 else len(buf)])
        del buf[:stop]
        return HostCommand(text, f"*SEND{kind.decode()}", error=reason)


def _eol(buf: bytearray, start: int = 0) -> int:
    """Index of the first CR or LF at or after ``start`` (-1 if none)."""
    cr, lf = buf.find(b"\r", start), buf.find(b"\n", start)
    found = [i for i in (cr, lf) if i >= 0]
    return min(found) if found else -1


def _after_eol(buf: bytearray, end: int) -> int:
    """Index after the EOL at ``end`` (a CRLF pair counts as one EOL)."""
    return end + 2 if buf[end : end + 2] == b"\r\n" else end + 1
