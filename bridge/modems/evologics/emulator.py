"""An emulated EvoLogics S2C modem: the AT host protocol on a pty (and TCP), frames in the water.

The host side follows ``modem-protocols.md`` §1 (checklist §1.11): command and data mode, the
``+++AT`` wrapping of every reply and notification in data mode, ``ATO``/``ATC``/``+++ATC`` and
the guard-time ``+++`` escape, length-framed ``AT*SEND*`` payloads, ``OK``/``ERROR``/``BUSY``
replies, ``@ZX1`` extended notifications (``SENDSTART``/``SENDEND``/``RECVSTART``/``RECVEND``),
``DELIVEREDIM``/``FAILEDIM`` after ``!RI`` retries of ``!RT`` ms, ``AT?T`` propagation time in µs,
``@ZU1`` USBL fixes from the mission's static positions, a 32-bit µs clock (``AT?CLOCK``), and
``AT*SENDIMS`` with a send time: the IM leaves exactly when the clock reads it, or
``EXPIREDIMS`` if that time has passed or the transmitter is busy then [U: the real modem's
tolerance and limits are not documented in the stored sources].

The acoustic side is a :class:`~bridge.modems.sim.SimBackend` in the simulated water, which
gives airtime, propagation, collisions, half-duplex and loss. Emulators mark their frames
through the water's ``dest`` metadata (bits 0-7 the destination address, :data:`AIR_ACK_REQUEST`,
:data:`AIR_ACK`, :data:`AIR_BURST`, :data:`AIR_PBM`, :data:`AIR_IMS`, a 4-bit sequence number from
:data:`AIR_SEQ_SHIFT`); payload bytes cross unchanged, so airtime is that of the payload.

``firmware`` is what ``ATI0`` reports and how the modem speaks: before 1.7, ``RECVIM`` and
``RECVPBM`` carry bitrate and propagation time in place of the duration [V DUNE for
``RECVIM``; C for ``RECVPBM``]; 1.7 and 1.8 spell ``IM Rerty Count`` in ``AT&V``, as the real
dump of BIR does, fixed from 1.9 [V BIR note]. ``AT&V`` lists the settings in the order of
that dump, with the three it shows that the emulator does not model (``Wake Up Active Time``,
``Wake Up Period``, ``Hold Timeout``) at the dump's values.

Simplifications (not modelled): ``RECVSTART`` is printed when the water reports the reception,
at its end, just before ``RECVEND``; a piggy-back message travels as its own frame; burst data
is sent in frames of up to 64 B without ``DELIVERED`` reports; the acoustic connection set-up
of burst mode, multipath (``AT?P`` is a fixed table) and the NET filter are not modelled.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.core.loaded import LoadedMission
from bridge.errors import BackendError
from bridge.mission.presets import UnknownPresetError, get_preset
from bridge.modems.base import ModemSetup, Reception
from bridge.modems.evologics.commands import CommandReader, HostBurst, HostCommand, SendRequest
from bridge.modems.evologics.protocol import BROADCAST, Mode, firmware_is_legacy, wrap
from bridge.modems.pty_host import PtyHost, TcpHost
from bridge.modems.setup import modem_setup
from bridge.modems.sim import SimBackend, water_options

__all__ = [
    "ACK_TURNAROUND_S",
    "AIR_ACK",
    "AIR_ACK_REQUEST",
    "EvologicsEmulator",
    "run_emulator",
]

log = logging.getLogger("zab.emulate.evologics")

AIR_ACK_REQUEST = 0x100
AIR_ACK = 0x200
AIR_BURST = 0x400
AIR_PBM = 0x800
AIR_IMS = 0x10000
AIR_SEQ_SHIFT = 12
ACK_PAYLOAD = b"\x06"

ACK_TURNAROUND_S = 0.110
"""From the end of an ack-IM's reception to the start of the ack [derived from the §1.9
transcript: 293.9 ms send-to-ack minus the 182.3 ms IM and 2 × 0.8 ms propagation]."""

FIRMWARE = "1.9"
"""What ``ATI0`` reports by default (the firmware of the real transcript, reference 1.9)."""
CLOCK_WRAP = 1 << 32
MAX_TX_QUEUE = 16  # IMs waiting for the transmitter; beyond this: ERROR BUFFER FULL [U]
IMS_MARGIN_S = 0.002
"""A timed IMS must reach the transmitter this long before its time, else it expires [U]."""
IMS_HANDOFF_S = 0.25
"""How long before its time the emulator hands a timed IMS to the water (which starts it at
that time exactly): the emulator's own wake-up may be late on a busy host, and its lateness
must not expire an IMS the host gave in time (a 20 ms hand-off expired IMSs timed 1 s ahead
while a test suite ran beside it)."""

HIGHEST_ADDRESSES = (2, 6, 14, 30, 62, 126, 254)

DEFAULT_SETTINGS: dict[str, int] = {
    "AL": 1, "AR": 0, "AM": 254, "L": 3, "LC": 0, "G": 0, "C": 1, "CA": 1500, "ZC": 10,
    "ZP": 750, "RC": 3, "RT": 1500, "RI": 1, "ZI": 120, "RP": 1, "ZS": 0, "ZL": 16384,
    "KO": 0, "ZU": 0,
}
"""Stored settings (``AT!``), kept across reboots. ``AM`` defaults to 254 so that 255 is the
broadcast address of any mission [U: the real factory value is 14 per the BIR dump]."""

SETTING_RANGES: dict[str, tuple[int, int]] = {
    "AL": (1, 254), "AR": (0, 254), "L": (0, 3), "LC": (0, 1), "G": (0, 1), "C": (0, 3),
    "CA": (1300, 1700), "ZC": (1, 31), "ZP": (50, 1200), "RC": (0, 255), "RT": (500, 12000),
    "RI": (0, 255), "ZI": (0, 3600), "RP": (0, 1), "ZS": (0, 7), "ZL": (8096, 2097152),
    "KO": (0, 255), "ZU": (0, 1),
}

SETTING_NAMES = {
    "L": "Source Level", "LC": "Source Level Control", "G": "Gain", "C": "Carrier Waveform ID",
    "AL": "Local Address", "AM": "Highest Address", "ZC": "Cluster Size", "ZP": "Packet Time",
    "RC": "Retry Count", "RT": "Retry Timeout", "Wake Up Active Time": "Wake Up Active Time",
    "Wake Up Period": "Wake Up Period", "RP": "Promiscuous Mode", "CA": "Sound Speed",
    "RI": "IM Retry Count", "ZL": "Pool Size", "Hold Timeout": "Hold Timeout",
    "ZI": "Idle Timeout",
}
"""``AT&V``'s lines in the order of the real dump (BIR); a key that is a label is shown at
:data:`DUMP_ONLY`'s value."""

DUMP_ONLY = {"Wake Up Active Time": 12, "Wake Up Period": 12, "Hold Timeout": 0}
"""Lines of the real ``AT&V`` dump (BIR) whose settings the emulator does not model."""


@dataclass
class _Tx:
    kind: str  # im, ims, pbm, burst, ack
    dst: int
    data: bytes
    flag: str = "noack"
    seq: int = 0
    retries_left: int = 0


@dataclass
class _Outstanding:
    """The one ack-IM waiting for its ack."""

    tx: _Tx
    acked: asyncio.Event = field(default_factory=asyncio.Event)
    ptime_s: float | None = None


class _Session:
    """One host interface (the pty or a TCP client): its own reader and mode."""

    def __init__(self, emulator: EvologicsEmulator, write: Callable[[bytes], None], name: str):
        self.emulator = emulator
        self.write = write
        self.name = name
        self.reader = CommandReader(Mode.DATA)  # power-up mode [V BIR]
        self._last_data = 0.0
        self._escape: asyncio.TimerHandle | None = None

    @property
    def mode(self) -> Mode:
        return self.reader.mode

    @mode.setter
    def mode(self, mode: Mode) -> None:
        self.reader.mode = mode

    def reset(self) -> None:
        self.reader = CommandReader(Mode.DATA)
        if self._escape is not None:
            self._escape.cancel()
            self._escape = None

    def reply(self, name: str, body: bytes) -> None:
        self.write(wrap(body, self.mode, name))

    def notify(self, body: bytes) -> None:
        self.write(wrap(body, self.mode, ""))

    def on_data(self, data: bytes) -> None:
        emu = self.emulator
        if emu.deaf:
            return
        loop = asyncio.get_running_loop()
        now = loop.time()
        quiet_before = now - self._last_data >= emu.guard_s and data.startswith(b"+")
        self._last_data = now
        if self._escape is not None:
            self._escape.cancel()
            self._escape = None
        self.reader.receive_data(data)
        for item in self.reader.inputs():
            if isinstance(item, HostCommand):
                emu.execute(self, item)
            elif isinstance(item, HostBurst):
                emu.burst(item.data)
            else:
                self.write(wrap(b"ERROR WRONG FORMAT", self.mode))
        if self.reader.holding_escape and quiet_before:
            self._escape = loop.call_later(emu.guard_s, self._guard_escape)

    def _guard_escape(self) -> None:
        """``+++`` alone between two guard times: to command mode, ``OK`` [V BIR]."""
        self._escape = None
        if self.reader.holding_escape:
            self.reader.take_escape()
            self.mode = Mode.COMMAND
            self.write(wrap(b"OK", Mode.COMMAND))


class EvologicsEmulator:
    """One emulated S2C modem: host sessions on a pty (and optionally TCP), a sim modem in the
    water. Fault injection: :meth:`unplug`/:meth:`replug`, :meth:`drop_tcp`, :meth:`reboot`,
    :meth:`inject_busy` and :attr:`deaf` (a hung modem that answers nothing)."""

    def __init__(
        self,
        setup: ModemSetup,
        *,
        link: Path | None = None,
        tcp_port: int | None = None,
        positions: Mapping[int, tuple[float, float, float]] | None = None,
        guard_s: float = 1.0,
        usbl: bool = False,
        firmware: str = FIRMWARE,
    ) -> None:
        self.setup = setup
        self.firmware = firmware
        # the water's dest carries the emulators' flags beside the address: no broadcast there
        setup = dataclasses.replace(setup, options=water_options(setup.options))
        self.legacy = firmware_is_legacy(firmware)  # ValueError for a non-version
        self.sim = SimBackend(setup)
        self.pty = PtyHost(self._pty_data, link=link)
        self.tcp: TcpHost | None = None
        if tcp_port is not None:
            self.tcp = TcpHost(self._tcp_data, port=tcp_port, on_connect=self._tcp_connect)
        self.positions = dict(positions or {})
        self.guard_s = guard_s
        self.usbl = usbl
        self.deaf = False
        self.settings = dict(DEFAULT_SETTINGS, AL=setup.address)
        self.flags = {"ZX": 0, "ZU": 0, "ZF": 0, "ZA": 0}
        self.stats = {"commands": 0, "sent": 0, "received": 0, "busy": 0, "errors": 0,
                      "burst_dropped": 0}
        self._pty_session = _Session(self, self.pty.write, "pty")
        self._tcp_session: _Session | None = None
        self._txq: asyncio.PriorityQueue[tuple[int, int, _Tx]] = asyncio.PriorityQueue()
        self._tx_counter = 0
        self._seq = 0
        self._outstanding: _Outstanding | None = None
        self._pbm_pending = False
        self._busy: list[str] = []
        self._seen: dict[tuple[int, int], float] = {}
        self._boot_wall = time.time()
        self._last_rx: dict[str, float] = {"ptime_us": 0, "rssi": 0, "integrity": 0,
                                           "velocity": 0.0}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loops: list[asyncio.Task[None]] = []
        self._airtime: Callable[[int], float] | None = None
        self._air = asyncio.Lock()  # one transmission at a time: queued, acks and timed IMS
        self.failure: asyncio.Future[None] | None = None

    # -- lifecycle -----------------------------------------------------------------------------

    async def start(self) -> dict[str, Any]:
        """Join the water, open the TCP port (if any), then the pty (and its link, last: once
        the modem is up); returns ``{"device", "tcp"}``."""
        self.failure = asyncio.get_running_loop().create_future()
        await self.sim.open()
        with contextlib.suppress(UnknownPresetError, TypeError):
            preset = get_preset(self.sim.preset_name)  # type: ignore[arg-type]
            self._airtime = preset.airtime
        port = await self._open_tcp()
        device = await self.pty.open()
        self._loops = [asyncio.create_task(self._rx_loop(), name="emu-rx"),
                       asyncio.create_task(self._tx_loop(), name="emu-tx")]
        log.info("evologics emulator %s@%s on %s%s", self.setup.node, self.setup.address,
                 device, "" if port is None else f" and TCP port {port}")
        return {"device": device, "tcp": port}

    async def _open_tcp(self) -> int | None:
        """Listen on the modem's TCP port, if it has one; :class:`BackendError` if taken."""
        if self.tcp is None:
            return None
        try:
            return await self.tcp.open()
        except (OSError, OverflowError) as exc:
            reason = os.strerror(exc.errno) if isinstance(exc, OSError) and exc.errno else exc
            raise BackendError(f"evologics emulator of {self.setup.node!r}: cannot listen on "
                               f"TCP port {self.tcp.port}: {reason}") from None

    async def stop(self) -> None:
        """Close everything (idempotent)."""
        tasks = [*self._loops, *self._tasks]
        self._loops, self._tasks = [], set()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._pty_session.reset()
        if self._tcp_session is not None:
            self._tcp_session.reset()
        if self.tcp is not None:
            await self.tcp.close()
        await self.pty.close()
        await self.sim.close()
        if self.failure is not None and not self.failure.done():
            self.failure.set_result(None)

    async def __aenter__(self) -> EvologicsEmulator:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- fault injection -----------------------------------------------------------------------

    async def unplug(self) -> None:
        """Pull the serial cable (the modem keeps running)."""
        await self.pty.unplug()
        self._pty_session.reset()

    async def replug(self) -> str:
        """Plug the cable back in; returns the device path (the link, if any)."""
        device = await self.pty.replug()
        self._pty_session.reset()
        self._pty_session.mode = self._pty_mode_after_replug
        return device

    _pty_mode_after_replug = Mode.DATA  # the modem's mode survives a cable pull [U]

    def drop_tcp(self) -> None:
        """Cut the TCP client's connection."""
        if self.tcp is not None:
            self.tcp.drop()

    def inject_busy(self, count: int = 1, reason: str = "BACKOFF STATE") -> None:
        """Answer the next ``count`` send commands with ``BUSY <reason>``."""
        self._busy.extend([reason] * count)

    async def reboot(self, boot_s: float = 0.3) -> None:
        """Power-cycle: queues and runtime flags are lost, both sessions return to data mode,
        TCP drops, the clock restarts; deaf for ``boot_s`` (``ATZ0`` does the same) [V BIR]."""
        self.deaf = True
        me = asyncio.current_task()
        for task in [*self._tasks, *self._loops[1:]]:
            if task is not me:
                task.cancel()
        self._tasks = set()
        while not self._txq.empty():
            self._txq.get_nowait()
        self._outstanding = None
        self._pbm_pending = False
        self.flags = dict.fromkeys(self.flags, 0)
        self._pty_session.reset()
        self.drop_tcp()
        self._boot_wall = time.time()
        await asyncio.sleep(boot_s)
        if self._loops:
            self._loops[1:] = [asyncio.create_task(self._tx_loop(), name="emu-tx")]
        self.deaf = False

    # -- host side -----------------------------------------------------------------------------

    def _pty_data(self, data: bytes) -> None:
        self._pty_session.on_data(data)

    def _tcp_data(self, data: bytes) -> None:
        if self._tcp_session is not None:
            self._tcp_session.on_data(data)

    def _tcp_connect(self) -> None:
        assert self.tcp is not None
        self._tcp_session = _Session(self, self.tcp.write, "tcp")

    def _sessions(self) -> list[_Session]:
        out = [self._pty_session]
        if self._tcp_session is not None and self.tcp is not None and self.tcp.connected:
            out.append(self._tcp_session)
        return out

    def notify(self, body: bytes) -> None:
        """Print an asynchronous notification on every host interface."""
        for session in self._sessions():
            session.notify(body)

    def modem_us(self, wall: float) -> int:
        """The modem's 32-bit µs clock at wall-clock time ``wall``."""
        return int((wall - self._boot_wall) * 1e6) % CLOCK_WRAP

    def burst(self, data: bytes) -> None:
        """Transparent data in data mode: burst data to the remote address ``AR``."""
        dst = self.settings["AR"]
        if dst == 0:  # 0 = accept any, cannot initiate [V BIR]
            self.stats["burst_dropped"] += len(data)
            return
        for i in range(0, len(data), 64):
            self._queue(_Tx("burst", dst, data[i : i + 64]))

    def execute(self, session: _Session, cmd: HostCommand) -> None:
        """Carry out one host command and reply on ``session``."""
        self.stats["commands"] += 1
        name, text = cmd.name, cmd.text

        def reply(body: bytes | str) -> None:
            session.reply(name, body.encode("latin-1") if isinstance(body, str) else body)

        if cmd.error:
            self.stats["errors"] += 1
            reply("ERROR WRONG FORMAT")
            return
        if cmd.send is not None:
            reply(self._send(cmd.send))
            return
        upper = text.decode("latin-1")
        if upper == "O":
            session.mode = Mode.DATA  # no reply [V BIR]
        elif upper == "C":
            reply("OK")
            session.mode = Mode.COMMAND
        elif upper == "Z0":
            self._spawn(self.reboot())  # no reply; TCP drops [V]
        elif upper in ("Z1", "Z3", "Z4"):
            self._clear(upper)
            reply("OK")
        elif upper in ("H", "A", "N", "S"):
            reply("OK")
        elif upper.startswith("I") and upper[1:].isdigit():
            reply({"0": self.firmware, "1": "phy: emulated, mac: emulated",
                   "7": "EvoLogics GmbH (emulated)"}.get(upper[1:], "ERROR WRONG FORMAT"))
        elif upper.startswith("?"):
            reply(self._query(upper[1:]))
        elif upper.startswith("!"):
            reply(self._set(upper[1:]))
        elif upper.startswith("@"):
            reply(self._runtime(upper[1:]))
        elif upper == "&V":
            reply(self._settings_dump())
        elif upper in ("&W", "&F"):
            if upper == "&F":
                self.settings = dict(DEFAULT_SETTINGS, AL=self.settings["AL"])
            reply("OK")
        else:
            self.stats["errors"] += 1
            reply("ERROR WRONG FORMAT")

    def _query(self, what: str) -> str:
        s = self.settings
        simple: dict[str, Any] = {
            "MODE": "AT",
            "PID": s["ZS"],
            "ZF": self.flags["ZF"],
            "T": int(self._last_rx["ptime_us"]),
            "E": self._last_rx["rssi"],
            "I": self._last_rx["integrity"],
            "V": f"{self._last_rx['velocity']:.4f}",
            "BL": 976, "BR": 976,
            "DI": self._delivery_state(),
            "DP": "EMPTY",
            "S": "ONLINE" if self._outstanding is not None else "INITIATION LISTEN",
            "CLOCK": self.modem_us(self.sim.clock()),
            "UT": f"{time.time() - self._boot_wall:.6f}",
            "BV": "24.0",
            "ZD": 0, "ZO": 0, "ZE": 0,
            "P": "10    10   \n11    12   \n100   240  \n",
        }
        if what in s:
            return str(s[what])
        if what in simple:
            return str(simple[what])
        return "ERROR WRONG FORMAT"

    def _delivery_state(self) -> str:
        return "DELIVERING" if self._outstanding is not None else "EMPTY"

    def _set(self, text: str) -> str:
        key = text.rstrip("0123456789")
        digits = text[len(key):]
        if key not in self.settings or (key == "AM" and not digits):
            return "ERROR WRONG FORMAT"
        if not digits:
            return "ERROR WRONG FORMAT"
        value = int(digits)
        if key == "AM":
            if value not in HIGHEST_ADDRESSES:
                return "ERROR WRONG FORMAT"
        else:
            low, high = SETTING_RANGES[key]
            if not low <= value <= high:
                return "ERROR WRONG FORMAT"
        if key == "AL" and value > self.settings["AM"]:
            return "ERROR WRONG FORMAT"
        self.settings[key] = value
        return "OK"

    def _runtime(self, text: str) -> str:
        if text in ("ZD", "ZO", "CTRL"):
            return "OK"
        key, value = text[:2], text[2:]
        if key == "ZL" and value.isdigit():
            return self._set(text)
        if key in self.flags and value in ("0", "1"):
            self.flags[key] = int(value)
            return "OK"
        return "ERROR WRONG FORMAT"

    def _settings_dump(self) -> str:
        def label(text: str) -> str:
            early = self.firmware.split(".")[:2] in (["1", "7"], ["1", "8"])
            return "IM Rerty Count" if text == "IM Retry Count" and early else text

        lines = [f"{label(name)}: {DUMP_ONLY[key] if key in DUMP_ONLY else self.settings[key]}"
                 for key, name in SETTING_NAMES.items()]
        return "\r\n".join(lines) + "\r\n"

    def _clear(self, which: str) -> None:
        keep: list[tuple[int, int, _Tx]] = []
        while not self._txq.empty():
            item = self._txq.get_nowait()
            drop = (which == "Z4" or (which == "Z1" and item[2].kind == "burst")
                    or (which == "Z3" and item[2].kind in ("im", "ims", "pbm")))
            if not drop or item[2].kind == "ack":
                keep.append(item)
        for item in keep:
            self._txq.put_nowait(item)

    def _send(self, request: SendRequest) -> str:
        if self._busy:
            self.stats["busy"] += 1
            return f"BUSY {self._busy.pop(0)}"
        if request.pid is not None and not self.flags["ZF"]:
            return "ERROR WRONG FORMAT"  # p<pid> only with extended networking [V evins]
        if not 0 <= request.dst <= BROADCAST:
            return "ERROR WRONG FORMAT"
        if self._txq.qsize() >= MAX_TX_QUEUE:
            return "ERROR BUFFER FULL"  # [U] named in common descriptions only
        kind = request.kind.lower() or "burst"
        if kind == "pbm":
            if self._pbm_pending:
                return "BUSY DELIVERING"  # [V DESERT]
            self._pbm_pending = True
        # broadcast IMs go without ack (driver practice [V]; the firmware's rule is [U])
        wants_ack = kind == "im" and request.flag == "ack" and request.dst != BROADCAST
        if wants_ack and self._outstanding is not None:
            return "BUSY DELIVERING"  # one outstanding ack-IM [V checklist; reply text U]
        tx = _Tx(kind, request.dst, request.data, "ack" if wants_ack else request.flag or "noack")
        if kind == "ims" and request.usec is not None:
            self._spawn(self._timed_ims(tx, request.usec))
            return "OK"
        if wants_ack:
            self._seq = (self._seq + 1) % 16
            tx.seq = self._seq
            tx.retries_left = self.settings["RI"]
            self._outstanding = _Outstanding(tx)
        self._queue(tx)
        return "OK"

    def _queue(self, tx: _Tx, priority: int = 1) -> None:
        self._tx_counter += 1
        self._txq.put_nowait((priority, self._tx_counter, tx))

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # -- acoustic side -------------------------------------------------------------------------

    def _estimate(self, n: int) -> float:
        if self._airtime is not None:
            return self._airtime(n)
        return 0.13 + 0.012 * n  # the §1.9 model [C]

    async def _tx_loop(self) -> None:
        while True:
            _, _, tx = await self._txq.get()
            try:
                await self._transmit(tx)
            except BackendError as exc:
                self._fail(exc)
                return

    async def _timed_ims(self, tx: _Tx, usec: int) -> None:
        """``AT*SENDIMS`` with a time: wait for the clock to read ``usec``, then transmit."""
        now = self.sim.clock()
        ahead = (usec - self.modem_us(now)) % CLOCK_WRAP
        if ahead < CLOCK_WRAP // 2:  # otherwise the time has passed (modulo the wrap)
            at = now + ahead * 1e-6
            await asyncio.sleep(max(0.0, at - self.sim.clock() - IMS_HANDOFF_S))
            try:
                if await self._transmit(tx, at=at):
                    return
            except BackendError as exc:
                self._fail(exc)
                return
        self.notify(f"EXPIREDIMS,{tx.dst}".encode())

    async def _transmit(self, tx: _Tx, at: float | None = None) -> bool:
        """Put ``tx`` in the water (at modem-clock seconds ``at`` if given); False if ``at``
        could no longer be met."""
        async with self._air:
            if at is not None and at - self.sim.clock() < IMS_MARGIN_S:
                return False
            await self._emit(tx, at)
            return True

    async def _emit(self, tx: _Tx, at: float | None) -> None:
        dest = tx.dst | tx.seq << AIR_SEQ_SHIFT
        dest |= {"ack": AIR_ACK, "burst": AIR_BURST, "pbm": AIR_PBM, "ims": AIR_IMS}.get(tx.kind, 0)
        if tx.flag == "ack":
            dest |= AIR_ACK_REQUEST
        show = self.flags["ZX"] and tx.kind != "ack"
        if show:  # when the emission starts: a timed IMS is handed to the water before then
            dur = round(self._estimate(len(tx.data)) * 1e6)
            line = f"SENDSTART,{tx.dst},{tx.kind},{dur},0".encode()
            asyncio.get_running_loop().call_later(
                0.0 if at is None else max(0.0, at - self.sim.clock()), self.notify, line)
        called = time.time()
        await self.sim.send(tx.data, dest, at=at)
        now = time.time()
        airtime = self._airtime(len(tx.data)) if self._airtime else now - called
        self.stats["sent"] += 1
        if show:
            start = self.modem_us(now - airtime) if at is None else self.modem_us(at)
            self.notify(f"SENDEND,{tx.dst},{tx.kind},{start},{round(airtime * 1e6)}".encode())
        if tx.kind == "pbm":
            self._pbm_pending = False
        if tx.flag == "ack" and tx.kind == "im":
            self._spawn(self._await_ack(tx))

    async def _await_ack(self, tx: _Tx) -> None:
        outstanding = self._outstanding
        if outstanding is None or outstanding.tx is not tx:
            return
        # !RT is the retry timeout [V]; counted from the end of our transmission here [U]
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(self.settings["RT"] / 1000):
                await outstanding.acked.wait()
        if self._outstanding is not outstanding:
            return  # a reboot or Z3/Z4 dropped it
        if outstanding.acked.is_set():
            self._outstanding = None
            self.notify(f"DELIVEREDIM,{tx.dst}".encode())
            return
        if tx.retries_left > 0:
            tx.retries_left -= 1
            self._queue(tx, priority=0)
            return
        self._outstanding = None
        self.notify(f"FAILEDIM,{tx.dst}".encode())

    async def _rx_loop(self) -> None:
        while True:
            try:
                rx = await self.sim.recv()
            except BackendError as exc:
                self._fail(exc)
                return
            if not self.deaf:
                self._on_air(rx)

    def _fail(self, exc: BackendError) -> None:
        log.error("evologics emulator %s: %s", self.setup.node, exc)
        if self.failure is not None and not self.failure.done():
            self.failure.set_exception(exc)

    def _on_air(self, rx: Reception) -> None:
        dest = int(rx.meta.get("dest") or 0)
        addr, seq = dest & 0xFF, (dest >> AIR_SEQ_SHIFT) & 0xF
        me = self.settings["AL"]
        travel = float(rx.meta.get("travel_time_s", 0.0))
        distance = float(rx.meta.get("distance_m", travel * 1500.0))
        duration = float(rx.meta.get("airtime_s", 0.0))
        start = float(rx.meta.get("start", rx.time - duration))
        rssi = round(-20.0 - 20.0 * math.log10(max(distance, 1.0)))  # a plausible model
        integrity = max(20, round(200.0 - 40.0 * math.log10(max(distance, 1.0))))
        if dest & AIR_ACK:
            out = self._outstanding
            if addr != me or out is None or out.tx.dst != rx.src or out.tx.seq != seq:
                return
            self._heard(start, duration, rssi, integrity, travel)
            out.ptime_s = travel
            out.acked.set()
            self._usbl(rx.src, travel, rssi, integrity)
            return
        for_me = addr in (me, BROADCAST)
        if not for_me and not self.settings["RP"]:
            return
        self.stats["received"] += 1
        if dest & AIR_BURST:
            if addr == me:
                self._heard(start, duration, rssi, integrity, travel)
                for session in self._sessions():
                    if session.mode is Mode.DATA:
                        session.write(rx.data)  # raw, unwrapped [V BIR]
                    else:
                        session.notify(b"RECV,%d,%d,%d,976,%d,%d,%d,0.0,%s" % (
                            len(rx.data), rx.src, addr, rssi, integrity, round(travel * 1e6),
                            rx.data))
            return
        duplicate = False
        if dest & AIR_ACK_REQUEST and addr == me:
            key = (rx.src, seq)
            now = time.time()
            duplicate = now - self._seen.get(key, -1e9) < self.settings["RT"] / 1000 * 3
            self._seen[key] = now
            self._spawn(self._send_ack(rx.src, seq))
        if duplicate:
            return  # a retry of an IM already printed; acked again above
        self._heard(start, duration, rssi, integrity, travel)
        dur_us = round(duration * 1e6)
        pid = f"p{self.settings['ZS']}," if self.flags["ZF"] else ""
        head = f"{len(rx.data)},{rx.src},{addr},"
        # firmware 1.6: bitrate and propagation time in place of the duration
        old = f"976,{rssi},{integrity},{round(travel * 1e6)},0.0000,"
        if dest & AIR_PBM:
            line = f"RECVPBM,{pid}{head}" + (old if self.legacy else
                                             f"{dur_us},{rssi},{integrity},0.0000,")
        elif dest & AIR_IMS:
            line = (f"RECVIMS,{pid}{head}{self.modem_us(start)},{dur_us},{rssi},{integrity},"
                    "0.0000,")
        else:
            flag = "ack" if dest & AIR_ACK_REQUEST else "noack"
            line = f"RECVIM,{pid}{head}{flag}," + (old if self.legacy else
                                                   f"{dur_us},{rssi},{integrity},0.0000,")
        self.notify(line.encode() + rx.data)
        self._usbl(rx.src, travel, rssi, integrity)

    def _heard(self, start: float, duration: float, rssi: int, integrity: int,
               travel: float) -> None:
        self._last_rx.update(rssi=rssi, integrity=integrity, ptime_us=round(travel * 1e6))
        if self.flags["ZX"]:
            self.notify(b"RECVSTART")
            self.notify(f"RECVEND,{self.modem_us(start)},{round(duration * 1e6)},{rssi},"
                        f"{integrity}".encode())

    async def _send_ack(self, dst: int, seq: int) -> None:
        await asyncio.sleep(ACK_TURNAROUND_S)
        self._queue(_Tx("ack", dst, ACK_PAYLOAD, seq=seq), priority=0)

    def _usbl(self, src: int, travel: float, rssi: int, integrity: int) -> None:
        """``USBLLONG`` toward ``src`` from the static positions (USBL heads with ``@ZU1``)."""
        if not (self.usbl and self.flags["ZU"]):
            return
        own, other = self.setup.position, self.positions.get(src)
        if own is None or other is None:
            return
        e, n, u = other[0] - own[0], other[1] - own[1], own[2] - other[2]
        now = time.time() - self._boot_wall
        fields = [f"{now:.6f}", f"{now - 0.45:.6f}", str(src),
                  *(f"{v:.4f}" for v in (e, n, u, e, n, u, 0.0, 0.0, 0.0)),
                  str(round(travel * 1e6)), str(rssi), str(integrity), "0.1000"]
        self.notify(("USBLLONG," + ",".join(fields)).encode())


async def run_emulator(
    loaded: LoadedMission,
    node: str,
    *,
    water: str,
    link: Path | None = None,
    tcp_port: int | None = None,
    ready: Callable[[dict[str, Any]], None] | None = None,
    usbl: bool = False,
    firmware: str = FIRMWARE,
) -> None:
    """Emulate ``node``'s S2C modem in the water at ``water`` until cancelled (as ``firmware``,
    e.g. ``1.6`` for the older ``RECVIM`` layout).

    Calls ``ready({"device": pty_path, "tcp": port_or_None})`` once listening. Raises
    :class:`BackendError` if the water cannot be joined or is lost.
    """
    mission = loaded.mission
    setup = modem_setup(mission, node, extra={"water": water})
    positions = {
        n.address: (n.position.x, n.position.y, n.position.depth)
        for n in mission.nodes.values()
        if n.position is not None
    }
    emulator = EvologicsEmulator(setup, link=link, tcp_port=tcp_port, positions=positions,
                                 usbl=usbl, firmware=firmware)
    try:
        info = await emulator.start()
        if ready is not None:
            ready(info)
        assert emulator.failure is not None
        await emulator.failure
    finally:
        await emulator.stop()
