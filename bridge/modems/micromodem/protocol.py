"""The host side of the Micro-Modem NMEA interface as a sans-I/O state machine.

Bytes from the serial port go in through :meth:`HostProtocol.receive_data`; events come out of
:meth:`HostProtocol.next_event`; commands are queued with :meth:`HostProtocol.configure`,
:meth:`~HostProtocol.start_transfer`, :meth:`~HostProtocol.ping` ... and the bytes to write
come out of :meth:`HostProtocol.data_to_send`. No I/O and no clock: the adapter
(:mod:`bridge.modems.micromodem.driver`) arms the timeouts and calls :meth:`~HostProtocol.abort`.

Rules (reference section 2):

* Lines end in ``\\r`` and/or ``\\n``; empty lines are ignored. A line is read from its last
  ``$`` (noise or a sentence cut off before it is one bad line). A line with a wrong checksum, a
  bad talker or unparsable fields becomes a :class:`BadSentence` event (counted in ``bad_lines``)
  and is otherwise dropped. Receiving never raises.
* A transfer is one data cycle: ``$CCCYC`` → echo ``$CACYC`` → (rate 0: cycle-init
  ``$CATXF`` first) → one ``$CADRQ`` per frame, answered with ``$CCTXD`` → ``$CATXD`` echo →
  ``$CATXF`` at the end of the packet → (ack) one ``$CAACK`` per frame. It ends with
  :class:`TransferDone` or :class:`TransferFailed` (``$CAERR``, a reboot, or :meth:`abort`).
* MM2's flexible data protocol (FDP) runs beside it: :meth:`HostProtocol.start_fdp` sends
  ``$CCTDP`` → echo ``$CATDP`` → ``$CATXF``, and an FDP packet received arrives whole in one
  ``$CARDP`` or ``$CARFP``, each frame with its own CRC flag.
* Incoming frames of one packet (``$CACYC`` from another node, then ``$CARXD`` 1..n), or one
  ``$CARDP``/``$CARFP`` whose frames all passed their CRC, become one :class:`Packet`; a
  ``$CAMSG,BAD_CRC``, a ``$CAMSG,PACKET_TIMEOUT``, a bad FDP frame or an incomplete packet
  gives :class:`PacketLost`.
* ``$CAUSB2`` (MM2 USBL: azimuth, elevation and one-way travel time of the last reception)
  becomes :class:`UsblFix`, attributed to the sender heard last (the line names no address).
* Pings: ``$CCMPC`` → ``$CAMPC``/``$CAMPR`` and MM2's FDP ping ``$CCCMD,PNG`` →
  ``$CACMD``/``$CACMR,PNR`` both give :class:`PingSent`/:class:`PingReply` (``$CAMPA`` and
  ``$CACMA`` :class:`Pinged`); an LBL interrogation (``$CCPDT``/``$CCPNT``) is answered by
  ``$SNTTA``, :class:`~bridge.modems.micromodem.nav.TravelTimes`. With ack, an FDP packet is
  done at its ``$CACDR`` (:class:`FdpAck`).
* ``$CAREV,…,INIT`` means the modem rebooted: any transfer fails and ``needs_init`` is set.
"""

from __future__ import annotations

import dataclasses
import enum
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from bridge.modems.micromodem.nav import TravelTimes, travel_times
from bridge.modems.micromodem.nmea import LineBuffer, NmeaError, Sentence, parse_sentence
from bridge.modems.micromodem.rates import FDP_RATES, get_rate
from bridge.modems.protocol import NEED_DATA, NeedData

__all__ = [
    "Ack",
    "ApiLevel",
    "BadSentence",
    "Clock",
    "ClockReply",
    "Config",
    "CycleInit",
    "DataRequest",
    "Event",
    "FdpAck",
    "FdpEcho",
    "FdpFrame",
    "FdpReceived",
    "HostProtocol",
    "MiniPacket",
    "ModemError",
    "ModemMessage",
    "Packet",
    "PacketLost",
    "PingReply",
    "PingSent",
    "Pinged",
    "Revision",
    "RxData",
    "RxStart",
    "RxStats",
    "Sleep",
    "TransferDone",
    "TransferFailed",
    "TransferState",
    "TxData",
    "TxFrame",
    "TxStart",
    "TxStats",
    "Unhandled",
    "UsblFix",
    "parse_event",
]

MAX_ADDRESS = 127
"""Addresses are 0..127 here. [U] The reference gives no range; seed 003 says 16 addresses are
in use, and 7 bits is the common description of the field."""


# -- events from the modem ---------------------------------------------------------------------


@dataclass(frozen=True)
class Revision:
    """``$CAREV,uptime,ident,rev``; ident ``INIT`` means the modem just booted."""

    uptime: str
    ident: str
    revision: str

    @property
    def init(self) -> bool:
        return self.ident.upper() == "INIT"


@dataclass(frozen=True)
class Config:
    """``$CACFG,key,value``: reply to ``$CCCFG`` / ``$CCCFQ``."""

    key: str
    value: str


@dataclass(frozen=True)
class CycleInit:
    """``$CACYC,cmd,src,dest,rate,ack,frames``: our echo, a received cycle-init or a poll."""

    src: int
    dest: int
    rate: int
    ack: bool
    frames: int


@dataclass(frozen=True)
class DataRequest:
    """``$CADRQ,hhmmss,src,dest,ack,max_bytes,frame`` (frame counts from 1)."""

    time: str
    src: int
    dest: int
    ack: bool
    max_bytes: int
    frame: int


@dataclass(frozen=True)
class TxData:
    """``$CATXD,src,dest,ack,nbytes``: the modem took our ``$CCTXD``."""

    src: int
    dest: int
    ack: bool
    n_bytes: int


@dataclass(frozen=True)
class TxStart:
    """``$CATXP,nbytes``: acoustic transmission starts."""

    n_bytes: int


@dataclass(frozen=True)
class TxFrame:
    """``$CATXF,nbytes``: a transmission ended (2 = a mini-packet)."""

    n_bytes: int


@dataclass(frozen=True)
class RxStart:
    """``$CARXP,type``: an incoming packet was detected (0 FSK, 1 PSK)."""

    packet_type: int


@dataclass(frozen=True)
class RxData:
    """``$CARXD,src,dest,ack,frame,hex``: one received frame (every frame, any destination)."""

    src: int
    dest: int
    ack: bool
    frame: int
    data: bytes


@dataclass(frozen=True)
class Ack:
    """``$CAACK,src,dest,frame,ack``: node ``src`` acknowledged our frame ``frame``."""

    src: int
    dest: int
    frame: int
    ack: bool


@dataclass(frozen=True)
class ModemMessage:
    """``$CAMSG,type,value``, e.g. ``BAD_CRC`` or ``PACKET_TIMEOUT``."""

    type: str
    value: str

    @property
    def bad_crc(self) -> bool:
        return self.type.replace(" ", "_").upper() == "BAD_CRC"

    @property
    def packet_timeout(self) -> bool:
        """A cycle-init was heard but its data never came (within the modem's ``PTO``)."""
        return self.type.replace(" ", "_").upper() == "PACKET_TIMEOUT"


@dataclass(frozen=True)
class ModemError:
    """``$CAERR,hhmmss,module,number,message``."""

    time: str
    module: str
    number: str
    message: str


@dataclass(frozen=True)
class PingSent:
    """``$CAMPC,src,dest``: echo of our ``$CCMPC``."""

    src: int
    dest: int


@dataclass(frozen=True)
class Pinged:
    """``$CAMPA,src,dest``: node ``src`` pinged us; the modem answers by itself."""

    src: int
    dest: int


@dataclass(frozen=True)
class PingReply:
    """``$CAMPR,src,dest,owtt``: ``src`` answered the ping of ``dest``; one-way travel time."""

    src: int
    dest: int
    travel_time_s: float


@dataclass(frozen=True)
class MiniPacket:
    """``$CAMUC`` (echo), ``$CAMUA`` (received) or ``$CAMUR`` (reply): 13 user bits."""

    kind: str
    src: int
    dest: int
    value: int


@dataclass(frozen=True)
class Sleep:
    """``$CAMSC,src,dest,minutes``: echo of ``$CCMSC`` (0 minutes = reboot now)."""

    src: int
    dest: int
    minutes: int


@dataclass(frozen=True)
class Clock:
    """``$CACLK,...``: echo of ``$CCCLK`` (fields kept as text)."""

    fields: tuple[str, ...]


@dataclass(frozen=True)
class ClockReply:
    """``$CATMS,timed_out,time`` (clock set) or ``$CATMQ,time,clksrc,pps_src`` (clock read),
    MM2: ``time`` is ISO 8601 UTC as the modem printed it."""

    kind: str
    time: str
    timed_out: bool = False
    source: str = ""


@dataclass(frozen=True)
class ApiLevel:
    """``$CAALQ,app_name,level``: the NMEA API level (MM2)."""

    app: str
    level: int


@dataclass(frozen=True)
class FdpEcho:
    """``$CATDP,errflag,id,dest,rate,ack,reserved[,...]``: the modem took our ``$CCTDP``."""

    error: int
    ident: int
    dest: int
    rate: int
    ack: bool


@dataclass(frozen=True)
class FdpAck:
    """``$CACDR,time,seq,src,dest,minirate,mini_ack,data_ack``: node ``src`` acknowledged our
    FDP packet ``seq``; the acks are bit masks of its mini- and data frames (pyacomms' field
    names; hex [U])."""

    seq: int
    src: int
    dest: int
    mini_mask: int
    data_mask: int


@dataclass(frozen=True)
class FdpFrame:
    """One frame of an FDP packet: ``crc_ok;nbytes;hex``."""

    crc_ok: bool
    data: bytes


@dataclass(frozen=True)
class FdpReceived:
    """``$CARDP`` / ``$CARFP``: an FDP packet as received, its user mini- and data frames."""

    src: int
    dest: int
    rate: int
    ack: bool
    mini: tuple[FdpFrame, ...]
    frames: tuple[FdpFrame, ...]

    @property
    def good(self) -> bool:
        return all(f.crc_ok for f in (*self.mini, *self.frames))

    @property
    def data(self) -> bytes:
        return b"".join(f.data for f in (*self.mini, *self.frames))


@dataclass(frozen=True)
class UsblFix:
    """``$CAUSB2,df,time,azimuth_deg,elevation_deg,owtt_s,timing_mode,ire0_r,...,ndetects``
    (15 fields, pyacomms' layout); ``src`` is the node heard last (None: nobody yet)."""

    time: str
    azimuth_deg: float
    elevation_deg: float
    travel_time_s: float
    timing_mode: int
    detections: int
    src: int | None = None


@dataclass(frozen=True)
class TxStats:
    """``$CAXST,...``: transmit statistics (fields kept as text, layouts in reference 2.5)."""

    fields: tuple[str, ...]


@dataclass(frozen=True)
class RxStats:
    """``$CACST,...``: receive statistics (fields kept as text)."""

    fields: tuple[str, ...]


@dataclass(frozen=True)
class Unhandled:
    """A well-formed sentence this driver has no use for (``$SNTTA``, ``$CATMQ`` ...)."""

    sentence: Sentence


@dataclass(frozen=True)
class BadSentence:
    """A line that was dropped: bad checksum, bad syntax or bad fields."""

    line: bytes
    reason: str


# -- events of the state machine -----------------------------------------------------------


@dataclass(frozen=True)
class TransferDone:
    """Our packet left the modem (and every frame was acknowledged when ``acked``)."""

    dest: int
    frames: int
    acked: bool


@dataclass(frozen=True)
class TransferFailed:
    """Our packet did not go out (or was not acknowledged); ``reason`` says why."""

    reason: str


@dataclass(frozen=True)
class Packet:
    """All frames of one received packet, joined: what the bridge calls a frame."""

    src: int
    dest: int
    ack: bool
    rate: int | None
    frames: int
    data: bytes


@dataclass(frozen=True)
class PacketLost:
    """An incoming packet from ``src`` could not be completed."""

    src: int | None
    reason: str


Event = (
    Revision | Config | CycleInit | DataRequest | TxData | TxStart | TxFrame | RxStart | RxData
    | Ack | ModemMessage | ModemError | PingSent | Pinged | PingReply | MiniPacket | Sleep | Clock
    | ClockReply | ApiLevel | FdpEcho | FdpAck | FdpReceived | UsblFix | TravelTimes | TxStats
    | RxStats | Unhandled | BadSentence | TransferDone | TransferFailed | Packet | PacketLost
)


# -- sentence -> event ---------------------------------------------------------------------


def _addr(text: str) -> int:
    value = int(text)
    if not 0 <= value <= MAX_ADDRESS:
        raise ValueError(f"address {value} outside 0..{MAX_ADDRESS}")
    return value


def _count(text: str, low: int = 0, high: int = 1 << 16) -> int:
    value = int(text)
    if not low <= value <= high:
        raise ValueError(f"{value} outside {low}..{high}")
    return value


def _flag(text: str) -> bool:
    if text not in ("0", "1"):
        raise ValueError(f"flag must be 0 or 1, got {text!r}")
    return text == "1"


def _need(fields: tuple[str, ...], n: int, at_least: bool = False) -> None:
    if len(fields) < n or (not at_least and len(fields) > n):
        raise ValueError(f"expected {'at least ' if at_least else ''}{n} fields, got {len(fields)}")


def _cyc(f: tuple[str, ...]) -> CycleInit:
    _need(f, 6)
    rate = _count(f[3], 0, 6)
    return CycleInit(_addr(f[1]), _addr(f[2]), rate, _flag(f[4]), _count(f[5], 1, 8))


def _frame(text: str) -> int:
    return _count(text, 1, 8)


def _msg(f: tuple[str, ...]) -> ModemMessage:
    _need(f, 1, at_least=True)
    return ModemMessage(f[0], ",".join(f[1:]))


def _drq(f: tuple[str, ...]) -> DataRequest:
    _need(f, 6)
    return DataRequest(
        f[0], _addr(f[1]), _addr(f[2]), _flag(f[3]), _count(f[4], 0, 4096), _count(f[5], 1, 8)
    )


def _rxd(f: tuple[str, ...]) -> RxData:
    _need(f, 5)
    if len(f[4]) % 2:
        raise ValueError("odd number of hex digits")
    return RxData(_addr(f[0]), _addr(f[1]), _flag(f[2]), _count(f[3], 1, 8), bytes.fromhex(f[4]))


def _err(f: tuple[str, ...]) -> ModemError:
    _need(f, 2, at_least=True)
    number = f[2] if len(f) > 2 else ""
    return ModemError(f[0], f[1], number, ",".join(f[3:]))


def _mini(kind: str) -> Callable[[tuple[str, ...]], MiniPacket]:
    def build(f: tuple[str, ...]) -> MiniPacket:
        _need(f, 3)
        value = int(f[2], 16)
        if not 0 <= value <= 0x1FFF:
            raise ValueError("mini-packet data is 13 bits")
        return MiniPacket(kind, _addr(f[0]), _addr(f[1]), value)

    return build


def _fdp_frames(text: str) -> tuple[FdpFrame, ...]:
    """``crc_ok;nbytes;hex;crc_ok;nbytes;hex...`` (empty: no frames)."""
    if not text:
        return ()
    parts = text.split(";")
    if len(parts) % 3:
        raise ValueError(f"FDP frames need crc;nbytes;hex triples, got {len(parts)} parts")
    frames = []
    for i in range(0, len(parts), 3):
        crc, n, hexdata = parts[i : i + 3]
        data = bytes.fromhex(hexdata)
        if _count(n, 0, 4096) != len(data) and _flag(crc):
            raise ValueError(f"FDP frame says {n} B, holds {len(data)}")
        frames.append(FdpFrame(_flag(crc), data))
    return tuple(frames)


def _rdp(f: tuple[str, ...]) -> FdpReceived:
    """``src,dest,rate,ack,reserved,minidata,data`` (goby's layout); pyacomms reads the sixth
    field as the data, so a six-field line is taken that way."""
    _need(f, 6, at_least=True)
    if len(f) > 7:
        raise ValueError(f"expected 6 or 7 fields, got {len(f)}")
    mini, data = (f[5], f[6]) if len(f) == 7 else ("", f[5])
    return FdpReceived(_addr(f[0]), _addr(f[1]), _count(f[2], 0, 6), _flag(f[3]),
                       _fdp_frames(mini), _fdp_frames(data))


def _rfp(f: tuple[str, ...]) -> FdpReceived:
    """``time,seq,src,dest,minirate,datarate,ack,reserved,modem_mini,user_mini,data[,...]``
    (the real MM2 line of the reference, as pyacomms reads it); the modem's own mini-frames
    (field 9) are not user data."""
    _need(f, 11, at_least=True)
    return FdpReceived(_addr(f[2]), _addr(f[3]), _count(f[5], -1, 6), _flag(f[6]),
                       _fdp_frames(f[9]), _fdp_frames(f[10]))


def _tdp(f: tuple[str, ...]) -> FdpEcho:
    _need(f, 6, at_least=True)
    return FdpEcho(int(f[0]), int(f[1]), _addr(f[2]), _count(f[3], 0, 6), _flag(f[4]))


def _cdr(f: tuple[str, ...]) -> FdpAck:
    _need(f, 7)
    return FdpAck(_count(f[1], 0, 255), _addr(f[2]), _addr(f[3]), int(f[5], 16), int(f[6], 16))


def _cmd(f: tuple[str, ...]) -> PingSent | PingReply | None:
    """``$CACMD,PNG,src,dest,rate,cdr,nbytes``: the echo of an FDP ping (a real MM2's line);
    ``$CACMD,time,PNR,src,dest,owtt,…``: its reply on firmware before 3.0 (pyacomms)."""
    if f and f[0] == "PNG":
        _need(f, 6)
        return PingSent(_addr(f[1]), _addr(f[2]))
    if len(f) > 1 and f[1] == "PNR":
        return _owtt(f[2:])
    return None


def _cma(f: tuple[str, ...]) -> Pinged | None:
    """``$CACMA,time,PNG,src,dest,…`` (a real MM2's line; pyacomms reads time and type the
    other way round from firmware 3.0 on): an FDP ping heard, to us or not."""
    if "PNG" not in f[:2]:
        return None
    _need(f, 4, at_least=True)
    return Pinged(_addr(f[2]), _addr(f[3]))


def _cmr(f: tuple[str, ...]) -> PingReply | None:
    """``$CACMR,PNR,time,src,dest,owtt,snr_in,snr_out,tx_level,reserved,timing`` (a real
    MM2's line): ``src`` answered the FDP ping of ``dest``."""
    if not f or f[0] != "PNR":
        return None
    _need(f, 10)
    return _owtt(f[2:])


def _owtt(f: tuple[str, ...], at_least: bool = True) -> PingReply:
    """``src,dest,owtt,…`` as a :class:`PingReply`."""
    _need(f, 3, at_least)
    owtt = float(f[2])
    if not 0.0 <= owtt < 1e4:
        raise ValueError(f"travel time {owtt} out of range")
    return PingReply(_addr(f[0]), _addr(f[1]), owtt)


def _usb2(f: tuple[str, ...]) -> UsblFix:
    _need(f, 15, at_least=True)
    owtt = float(f[4])
    azimuth, elevation = float(f[2]), float(f[3])
    if not (0.0 <= owtt < 100.0 and -360.0 <= azimuth <= 360.0 and -90.0 <= elevation <= 90.0):
        raise ValueError("azimuth, elevation or travel time out of range")
    return UsblFix(f[1], azimuth, elevation, owtt, int(f[5]), int(f[14]))


def _fixed(n: int, build: Callable[..., Event], *kinds: Callable[[str], object],
           at_least: bool = False) -> Callable[[tuple[str, ...]], Event]:
    """A parser for ``n`` fields converted by ``kinds`` (text when missing), then ``build``."""

    def parse(f: tuple[str, ...]) -> Event:
        _need(f, n, at_least)
        return build(*(kind(v) for kind, v in zip(kinds, f, strict=False)), *f[len(kinds):])

    return parse


_PARSERS: dict[str, Callable[[tuple[str, ...]], Event | None]] = {
    "CAREV": _fixed(3, Revision),
    "CACFG": _fixed(2, Config),
    "CACYC": _cyc,
    "CADRQ": _drq,
    "CATXD": _fixed(4, TxData, _addr, _addr, _flag, _count),
    "CATXP": _fixed(1, TxStart, _count),
    "CATXF": _fixed(1, TxFrame, _count),
    "CARXP": _fixed(1, RxStart, _count),
    "CARXD": _rxd,
    "CAACK": _fixed(4, Ack, _addr, _addr, _frame, _flag),
    "CAMSG": _msg,
    "CAERR": _err,
    "CAMPC": _fixed(2, PingSent, _addr, _addr),
    "CAMPA": _fixed(2, Pinged, _addr, _addr),
    "CAMPR": lambda f: _owtt(f, at_least=False),
    "CAMUC": _mini("echo"),
    "CAMUA": _mini("received"),
    "CAMUR": _mini("reply"),
    "CAMSC": _fixed(3, Sleep, _addr, _addr, _count),
    "CACLK": Clock,
    "CATMS": lambda f: ClockReply("TMS", f[1] if len(f) > 1 else "", _flag(f[0])),
    "CATMQ": lambda f: ClockReply("TMQ", f[0], source=",".join(f[1:3])),
    "CAALQ": _fixed(2, ApiLevel, str, int),
    "CATDP": _tdp,
    "CARDP": _rdp,
    "CARFP": _rfp,
    "CAUSB2": _usb2,
    "CACDR": _cdr,
    "CACMD": _cmd,
    "CACMA": _cma,
    "CACMR": _cmr,
    "SNTTA": travel_times,
    "CAXST": TxStats,
    "CACST": RxStats,
}


def parse_event(sentence: Sentence) -> Event:
    """The event for one sentence (:class:`Unhandled` for one of no use here, such as a
    ``$CACMD`` of another mode); ``ValueError`` if its fields do not fit its type."""
    parser = _PARSERS.get(sentence.name)
    event = parser(sentence.fields) if parser is not None else None
    return Unhandled(sentence) if event is None else event


# -- the state machine ---------------------------------------------------------------------


class TransferState(enum.Enum):
    """Where our outgoing data cycle is."""

    IDLE = "idle"
    WAIT_ECHO = "wait_echo"  # $CCCYC sent, waiting for $CACYC
    WAIT_CYCLE_INIT = "wait_cycle_init"  # rate 0: the cycle-init mini-packet is on the air
    WAIT_REQUEST = "wait_request"  # waiting for $CADRQ
    WAIT_SENT = "wait_sent"  # data handed over, waiting for $CATXF
    WAIT_ACKS = "wait_acks"  # waiting for $CAACK of every frame


@dataclass
class _Transfer:
    dest: int
    rate: int
    ack: bool
    frames: list[bytes]
    state: TransferState = TransferState.WAIT_ECHO
    fdp: bool = False
    handed: set[int] = field(default_factory=set)
    acked: set[int] = field(default_factory=set)


@dataclass
class _Incoming:
    src: int
    dest: int
    ack: bool
    rate: int | None
    frames: int
    parts: dict[int, bytes] = field(default_factory=dict)


class HostProtocol:
    """The host's view of one Micro-Modem: feed bytes, read events, send commands."""

    def __init__(self, address: int) -> None:
        self.address = _addr(str(address))
        self.bad_lines = 0
        self.needs_init = False
        self._lines = LineBuffer()
        self._events: deque[Event] = deque()
        self._out = bytearray()
        self._transfer: _Transfer | None = None
        self._incoming: _Incoming | None = None
        self._last_src: int | None = None  # the node heard last, whom a $CAUSB2 locates

    # -- input ---------------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Feed bytes from the modem (any fragment). Never raises."""
        lines, overflow = self._lines.feed(data)
        for line in lines:
            self._line(line)
        if overflow is not None:
            self._bad(overflow, "line too long; dropped up to the next line end")

    def reset_input(self) -> None:
        """Forget a partial line (the port was reopened)."""
        self._lines.clear()

    def next_event(self) -> Event | NeedData:
        """The next event, or :data:`~bridge.modems.protocol.NEED_DATA` when more bytes are
        needed."""
        return self._events.popleft() if self._events else NEED_DATA

    def events(self) -> Iterator[Event]:
        """Every pending event."""
        while (event := self.next_event()) is not NEED_DATA:
            yield event

    # -- output --------------------------------------------------------------------------------

    def data_to_send(self) -> bytes:
        """Bytes to write to the modem (and forget)."""
        out, self._out = bytes(self._out), bytearray()
        return out

    def send(self, sentence: Sentence) -> None:
        """Queue any host sentence."""
        self._out += sentence.encode()

    def configure(self, key: str, value: object) -> None:
        """``$CCCFG,key,value``; the modem answers :class:`Config`."""
        self.send(Sentence("CC", "CFG", (key, _text(value))))

    def query(self, key: str) -> None:
        """``$CCCFQ,key``; answered by one :class:`Config` per key."""
        self.send(Sentence("CC", "CFQ", (key,)))

    def ping(self, dest: int, fdp: bool = False) -> None:
        """A two-way ping, ``$CCMPC,us,dest`` or with ``fdp`` MM2's ``$CCCMD,PNG,us,dest,1,0``
        (rate 1, no data: the form pyacomms sends to firmware before 3.0); the answer is
        :class:`PingReply`."""
        me, to = str(self.address), str(_addr(str(dest)))
        if fdp:
            self.send(Sentence("CC", "CMD", ("PNG", me, to, "1", "0")))
        else:
            self.send(Sentence("CC", "MPC", (me, to)))

    def reboot(self) -> None:
        """``$CCMSC,us,us,0``: reboot now (the modem then prints ``$CAREV,…,INIT``)."""
        me = str(self.address)
        self.send(Sentence("CC", "MSC", (me, me, "0")))

    @property
    def transfer_state(self) -> TransferState:
        return self._transfer.state if self._transfer else TransferState.IDLE

    def start_transfer(self, dest: int, data: bytes, rate: int, ack: bool) -> None:
        """Begin a data cycle carrying ``data`` (split over the rate's frames) to ``dest``.

        ``ValueError`` if a transfer is running or ``data`` does not fit one packet.
        """
        if self._transfer is not None:
            raise ValueError("a transfer is already in progress")
        spec = get_rate(rate)
        if not data or len(data) > spec.max_bytes:
            raise ValueError(f"{len(data)} B does not fit a rate-{rate} packet "
                             f"(1..{spec.max_bytes} B)")
        dest = _addr(str(dest))
        frames = [data[i:i + spec.frame_bytes] for i in range(0, len(data), spec.frame_bytes)]
        self._transfer = _Transfer(dest, rate, ack, frames)
        fields = ("0", str(self.address), str(dest), str(rate), _text(ack), str(len(frames)))
        self.send(Sentence("CC", "CYC", fields))

    def start_fdp(self, dest: int, data: bytes, rate: int, ack: bool) -> None:
        """Send ``data`` to ``dest`` as one MM2 FDP packet: ``$CCTDP,dest,rate,ack,0,hex``.

        ``ValueError`` if a transfer is running, ``rate`` has no FDP or ``data`` does not fit.
        """
        if self._transfer is not None:
            raise ValueError("a transfer is already in progress")
        if rate not in FDP_RATES:
            raise ValueError(f"FDP runs at rates {sorted(FDP_RATES)}, not {rate}")
        spec = get_rate(rate)
        if not data or len(data) > spec.max_bytes:
            raise ValueError(f"{len(data)} B does not fit a rate-{rate} FDP packet "
                             f"(1..{spec.max_bytes} B)")
        dest = _addr(str(dest))
        self._transfer = _Transfer(dest, rate, ack, [data], fdp=True)
        self.send(Sentence("CC", "TDP", (str(dest), str(rate), _text(ack), "0",
                                         data.hex().upper())))

    def abort(self, reason: str) -> None:
        """Give up the running transfer (the adapter's timeout); emits :class:`TransferFailed`.
        A ``$CADRQ`` of its cycle that comes after is answered with a blank ``$CCTXD``."""
        if self._transfer is not None:
            self._transfer = None
            self._events.append(TransferFailed(reason))

    def cancel(self, reason: str) -> bool:
        """Call the running transfer back if the modem holds none of its data yet: a legacy
        cycle before its first ``$CCTXD``. It is given up (:meth:`abort`), and each ``$CADRQ``
        of its cycle then gets a blank ``$CCTXD``, which stops the modem asking (reference 2.3
        [V]): its packet never goes out. The reference has no verified command that stops a
        cycle the modem holds data for, nor an FDP packet (its data goes with ``$CCTDP``): for
        those, False, and the transfer runs on. (At rate 0 the cycle-init mini-packet goes out
        before the first ``$CADRQ``: a cycle the modem takes late still sends that.)"""
        t = self._transfer
        if t is None or t.fdp or t.handed:
            return False
        self.abort(reason)
        return True

    # -- internals -----------------------------------------------------------------------------

    def _bad(self, line: bytes, reason: str) -> None:
        self.bad_lines += 1
        self._events.append(BadSentence(line, reason))

    def _line(self, line: bytes) -> None:
        # resynchronise on the last '$': what comes before it is noise or a sentence cut off
        # without its line end (a modem rebooting mid-line), one bad line; keep the sentence
        start = line.rfind(b"$")
        if start > 0:
            cut = b"$" in line[:start]
            self._bad(line[:start], "sentence cut off by a new '$'" if cut else "noise before '$'")
            line = line[start:]
        try:
            sentence = parse_sentence(line)
            event = parse_event(sentence)
        except NmeaError as exc:
            self._bad(line, str(exc))
            return
        except (ValueError, IndexError) as exc:
            self._bad(line, f"bad fields: {exc}")
            return
        if isinstance(event, UsblFix):
            event = dataclasses.replace(event, src=self._last_src)
        elif isinstance(event, CycleInit | RxData | FdpReceived | PingReply | Pinged
                        | MiniPacket) and event.src != self.address:
            self._last_src = event.src
        self._events.append(event)
        self._react(event)

    def _react(self, event: Event) -> None:
        t = self._transfer
        if isinstance(event, Revision) and event.init:
            self.needs_init = True
            self._incoming = None
            self.abort("modem rebooted ($CAREV INIT)")
        elif isinstance(event, ModemError):
            self.abort(f"modem error: {event.module} {event.number} {event.message}".strip())
        elif isinstance(event, CycleInit):
            self._on_cycle(event)
        elif isinstance(event, DataRequest):
            self._on_request(event)
        elif isinstance(event, FdpEcho) and t is not None and t.fdp:
            if event.error:
                self.abort(f"modem refused the FDP packet ($CATDP error {event.error})")
            elif t.state is TransferState.WAIT_ECHO:
                t.state = TransferState.WAIT_SENT
        elif isinstance(event, FdpReceived):
            self._on_fdp(event)
        elif isinstance(event, TxFrame) and t is not None and t.fdp:
            if t.state is TransferState.WAIT_SENT:  # an FDP packet ends at its $CATXF
                if t.ack:
                    t.state = TransferState.WAIT_ACKS
                else:
                    self._finish(acked=False)
        elif isinstance(event, FdpAck) and t is not None and t.fdp:
            # every data frame acknowledged, by the packet's destination, to us
            every = (1 << get_rate(t.rate).frames_for(len(t.frames[0]))) - 1
            if (t.state is TransferState.WAIT_ACKS and event.src == t.dest
                    and event.dest == self.address and event.data_mask & every == every):
                self._finish(acked=True)
        elif isinstance(event, TxFrame) and t is not None:
            if t.state is TransferState.WAIT_CYCLE_INIT:
                t.state = TransferState.WAIT_REQUEST
            elif t.state is TransferState.WAIT_SENT:
                if t.ack:
                    t.state = TransferState.WAIT_ACKS
                else:
                    self._finish(acked=False)
        elif isinstance(event, Ack) and t is not None and t.state in (
            TransferState.WAIT_SENT, TransferState.WAIT_ACKS
        ):
            # goby's test: the ack comes from the data's destination, addressed to us
            if event.src == t.dest and event.dest == self.address and event.ack:
                t.acked.add(event.frame)
                if t.state is TransferState.WAIT_ACKS and len(t.acked) >= len(t.frames):
                    self._finish(acked=True)
        elif isinstance(event, RxData):
            self._on_frame(event)
        elif isinstance(event, ModemMessage) and event.bad_crc and self._incoming is not None:
            lost, self._incoming = self._incoming, None
            self._events.append(PacketLost(lost.src, f"bad CRC ({event.value})"))
        elif isinstance(event, ModemMessage) and event.packet_timeout:
            timed_out, self._incoming = self._incoming, None
            self._events.append(PacketLost(timed_out.src if timed_out else None,
                                           f"packet timeout ({event.value})"))

    def _finish(self, acked: bool) -> None:
        t = self._transfer
        assert t is not None
        self._transfer = None
        self._events.append(TransferDone(t.dest, len(t.frames), acked))

    def _on_fdp(self, event: FdpReceived) -> None:
        if event.src == self.address:
            return
        n = len(event.mini) + len(event.frames)
        if not n:
            return  # only the modem's own mini-frames (an FDP ping): nothing for the host
        if not event.good:
            bad = [i for i, f in enumerate((*event.mini, *event.frames), 1) if not f.crc_ok]
            self._events.append(PacketLost(event.src, f"FDP packet with bad CRC in frames {bad}"))
            return
        self._events.append(Packet(event.src, event.dest, event.ack, event.rate, n, event.data))

    def _on_cycle(self, event: CycleInit) -> None:
        t = self._transfer
        if event.src == self.address:
            if t is not None and t.state is TransferState.WAIT_ECHO and event.dest == t.dest:
                t.state = (TransferState.WAIT_CYCLE_INIT if get_rate(t.rate).fsk
                           else TransferState.WAIT_REQUEST)
            return  # a second CACYC of our own cycle, or a poll: the DRQ follows
        if self._incoming is not None:
            lost = self._incoming
            self._events.append(PacketLost(lost.src, "incomplete packet (new cycle-init)"))
        self._incoming = _Incoming(event.src, event.dest, event.ack, event.rate, event.frames)

    def _on_request(self, event: DataRequest) -> None:
        t = self._transfer
        me = str(self.address)
        if (t is None or event.src != self.address or event.dest != t.dest
                or not 1 <= event.frame <= len(t.frames) or event.frame in t.handed
                or t.state is TransferState.WAIT_ACKS):
            # someone polled us, or a DRQ beyond our frames: a blank TXD stops further DRQs
            dest = str(event.dest)
            self.send(Sentence("CC", "TXD", (me, dest, _text(event.ack), "")))
            return
        data = t.frames[event.frame - 1][: event.max_bytes or None]
        t.handed.add(event.frame)
        t.state = TransferState.WAIT_SENT
        self.send(Sentence("CC", "TXD", (me, str(t.dest), _text(t.ack), data.hex().upper())))

    def _on_frame(self, event: RxData) -> None:
        if event.src == self.address:
            return
        inc = self._incoming
        if inc is None or inc.src != event.src:
            if inc is not None:
                self._events.append(PacketLost(inc.src, "incomplete packet (other sender)"))
            # no cycle-init seen for this packet: take the frames as they come
            inc = self._incoming = _Incoming(event.src, event.dest, event.ack, None,
                                             max(event.frame, 1))
        inc.parts[event.frame] = event.data
        if len(inc.parts) >= inc.frames:
            self._incoming = None
            if set(inc.parts) != set(range(1, inc.frames + 1)):
                self._events.append(PacketLost(inc.src, "frames out of order"))
                return
            data = b"".join(inc.parts[i] for i in range(1, inc.frames + 1))
            self._events.append(Packet(inc.src, inc.dest, inc.ack, inc.rate, inc.frames, data))


def _text(value: object) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    return str(value)
