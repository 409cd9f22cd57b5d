"""The ``modem.options`` each built-in backend takes, as models, and the check of a mission's.

A node's modem options are the mission's ``modem.options`` merged with its own (a link's and
its member's, with ``links``); :func:`backend_problems` validates them against the model of
the node's backend, and says where each wrong or misspelt key is written. The drivers in
:mod:`bridge.modems` take their options from the same models (one way in), and the backend
pages of the docs print their tables (:mod:`bridge.mission.reference`). A backend from the
``zab.backends`` entry points is known by name here; its options are its own to check.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping
from importlib.metadata import entry_points
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, ValidationError, ValidationInfo, field_validator

from bridge.mission.base import MissionModel
from bridge.mission.model import Mission, Modem, ModemOverride

__all__ = ["BACKEND_OPTIONS", "ENTRY_POINT_GROUP", "STANDARD_BAUDS", "AnyOptions",
           "EvologicsOptions", "MicromodemOptions", "ModemOptions", "SimOptions", "UdpOptions",
           "backend_names", "backend_problems", "option_errors"]

ENTRY_POINT_GROUP = "zab.backends"
"""Where installed packages register backends of their own."""

STANDARD_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
"""Serial rates a ``baud`` option may name."""

Seconds = Annotated[float, Field(gt=0)]


class ModemOptions(MissionModel):
    """Options every backend takes: those of the simulated water (``zab sim``, ``zab water``
    and the emulators read them whatever the backend) and of the modem interface."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    preset: Any = Field(None, description="The modem kind (a preset of ``zab presets``): "
                        "the MAC's timing and the simulated water's.")
    water: Any = Field(None, description="``host:port`` of the simulated water (``zab "
                       "water``); a bare port means 127.0.0.1.")
    seed: Any = Field(0, description="The simulated water's random seed, a whole number.")
    loss: Any = Field(0.0, description="The share of frames the simulated water loses at "
                      "random, 0 to 1.")
    broadcast: int | None = Field(None, ge=0, le=65535, description="The address meaning "
                                  "every node; the mission's ``modem.broadcast`` sets it.")
    ack: bool = Field(False, description="Ask the destination to acknowledge each frame with "
                      "one destination (where the modem can).")
    tx_lead_s: float = Field(0.01, ge=0, description="How far ahead of the modem clock a "
                             "timed frame is scheduled, seconds.")


class AnyOptions(ModemOptions):
    """A backend of another package: the common options, and any of its own."""

    model_config = ConfigDict(extra="allow", strict=False)


class SimOptions(ModemOptions):
    """``sim``: a modem in the simulated water."""

    tx_lead_s: float = Field(0.05, description="How far ahead each frame's start is "
                             "scheduled, seconds (negative: a host that asks late, each frame "
                             "refused by the water as expired: for tests of refusals).")
    connect_timeout: Seconds = Field(3.0, description="Wait for the water, seconds.")
    rx_queue: int = Field(256, ge=0, description="Receptions kept while nobody reads them "
                          "(0: no limit); the oldest are dropped.")
    clock_offset_s: float = Field(0.0, description="The modem clock's offset from the host's.")
    clock_drift_ppm: float = Field(0.0, description="The modem clock's drift, ppm.")
    timestamp_jitter_s: float = Field(0.0, ge=0, description="Random error of the reception "
                                      "timestamps, seconds.")


class UdpOptions(ModemOptions):
    """``udp``: frames as UDP datagrams."""

    port: int | None = Field(None, ge=0, le=65535, description="This node's UDP port "
                             "(required; 0: any free port).")
    host: str = Field("127.0.0.1", description="This node's address.")
    allow_remote: bool = Field(False, description="Accept addresses other than loopback.")
    rx_queue: int = Field(256, ge=0, description="Receptions kept while nobody reads them.")


class SerialOptions(ModemOptions):
    """A modem on a serial port."""

    device: str | None = Field(None, min_length=1, description="Serial path or pyserial URL "
                               "(required).")
    baud: int = Field(19200, description="Serial rate, one of "
                      f"{', '.join(map(str, STANDARD_BAUDS))}.")

    @field_validator("baud")
    @classmethod
    def _standard_baud(cls, baud: int) -> int:
        if baud not in STANDARD_BAUDS:
            rates = ", ".join(map(str, STANDARD_BAUDS))
            raise ValueError(f"must be a standard serial rate ({rates}), got {baud}")
        return baud


class EvologicsOptions(SerialOptions):
    """``evologics``: an EvoLogics S2C modem."""

    mode: Literal["data", "command"] = Field("data", description="The modem's interface mode.")
    eol: str | None = Field(None, description="Line end; default ``\\r`` on serial, ``\\n`` "
                            "over TCP.")
    timeout_s: Seconds = Field(2.0, description="Wait for a synchronous reply, seconds.")
    probe_retries: int = Field(3, ge=1, description="Start-up probes.")
    busy_retries: int = Field(5, ge=0, description="Retries after a ``BUSY`` reply.")
    busy_backoff_s: float = Field(0.2, ge=0, description="First wait after ``BUSY`` (doubled "
                                  "each time), seconds.")
    send_timeout_s: Seconds = Field(10.0, description="Wait for ``SENDEND``, seconds.")
    ack_timeout_s: Seconds = Field(15.0, description="Wait for the delivery report, seconds.")
    keepalive_s: float = Field(10.0, ge=0, description="Query ``AT?AL`` when idle this often "
                               "(0: never), seconds.")
    promiscuous: bool = Field(True, description="Hear every IM (``AT!RP1``).")
    usbl: bool = Field(False, description="Report USBL fixes (``AT@ZU1``).")
    timed_send: bool = Field(True, description="Schedule frames on the modem clock "
                             "(``AT*SENDIMS``) when the modem can.")
    tx_lead_s: float = Field(0.1, ge=0, description="How far ahead of the modem clock a frame "
                             "is scheduled, seconds.")
    clock_sync_s: Seconds = Field(30.0, description="Read ``AT?CLOCK`` again this often, "
                                  "seconds.")


class MicromodemOptions(SerialOptions):
    """``micromodem``: a WHOI Micro-Modem."""

    rate: Literal[0, 1, 2, 3, 4, 5, 6] = Field(0, description="Packet rate, from 0 (FH-FSK, "
                                               "32 B) to 6.")
    fdp: bool = Field(False, description="Send by MM2's flexible data protocol (rates 1-6).")
    timeout_s: Seconds = Field(5.0, description="Wait for a command's echo, seconds.")
    retries: int = Field(3, ge=0, description="Resends of a command.")
    tx_timeout_s: Seconds | None = Field(None, description="One whole data cycle, seconds; "
                                         "default: from the rate.")
    send_retries: int = Field(2, ge=0, description="Cycles retried after a failure.")
    ping_timeout_s: Seconds = Field(10.0, description="Wait for a ping's reply, seconds.")
    ping: Literal["mpc", "fdp"] = Field("mpc", description="How a ping ranges.")
    lbl: dict[str, Any] | None = Field(None, description="LBL transponders among the nodes.")
    set_clock: Literal["none", "clk", "tms"] = Field("none", description="Set the modem's "
                                                     "clock from the host's at start-up.")
    sound_speed_mps: float = Field(1500.0, gt=0, description="Turns a USBL travel time into "
                                   "a range, m/s.")
    config: dict[str, Any] = Field(default_factory=dict, description="Extra ``$CCCFG`` keys "
                                   "set at start-up.")
    transponder: str | None = Field(None, pattern="^[A-Da-d]$", description="The emulated "
                                    "modem answers LBL interrogations as this beacon (A-D).")

    @field_validator("fdp")
    @classmethod
    def _fdp_rate(cls, fdp: bool, info: ValidationInfo) -> bool:
        if fdp and info.data.get("rate") == 0:
            raise ValueError("FDP sends at rates 1-6, not rate 0")
        return fdp


BACKEND_OPTIONS: dict[str, type[ModemOptions]] = {
    "sim": SimOptions, "udp": UdpOptions, "evologics": EvologicsOptions,
    "micromodem": MicromodemOptions}
"""The options of each built-in backend."""


def backend_names() -> list[str]:
    """Every backend a mission may name: the built-ins and the ``zab.backends`` entry points."""
    names = set(BACKEND_OPTIONS)
    with contextlib.suppress(Exception):  # a broken distribution must not hide the built-ins
        names.update(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))
    return sorted(names)


def option_errors(model: type[ModemOptions], options: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Each problem of ``options`` for ``model``: (key, or "" for the whole, message); none
    when they are valid."""
    try:
        model.model_validate(dict(options))
    except ValidationError as exc:
        return [(str(e["loc"][0]) if e["loc"] else "", _message(model, e)) for e in exc.errors()]
    return []


def _message(model: type[ModemOptions], error: Any) -> str:
    if error["type"] == "extra_forbidden":
        known = ", ".join(sorted(model.model_fields))
        return f"unknown option (check its spelling; known: {known})"
    message = str(error["msg"]).removeprefix("Value error, ")
    if error["type"] != "value_error" and "input" in error:
        message += f" (got {error['input']!r})"
    return message


Loc = tuple[str | int, ...]


def backend_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """Each node's modem backend, known or not, and its options, valid for it or not, with the
    place where the wrong value (or the backend) is written."""
    known = backend_names()
    for where, shared, own in _node_modems(mission):
        backend = own.backend or shared.backend
        if backend not in known:
            yield ((*where[own.backend is None], "backend"),
                   f"unknown backend {backend!r} (known: {', '.join(known)})")
            continue
        model = BACKEND_OPTIONS.get(backend, AnyOptions)
        for key, message in option_errors(model, {**shared.options, **own.options}):
            at = where[key not in own.options] if key else where[not own.options]
            yield ((*at, "options", *([key] if key else [])), f"{backend} backend: {message}")


def _node_modems(mission: Mission) -> Iterable[tuple[tuple[Loc, Loc], Modem, ModemOverride]]:
    """Each node's modem sections on each link: (where its own and the shared one are
    written, the shared one, its own)."""
    if mission.links is None:
        for name, node in mission.nodes.items():
            yield (("nodes", name, "modem"), ("modem",)), mission.modem, node.modem
        return
    for link, spec in mission.links.items():
        for name in spec.nodes or mission.nodes:
            if name in mission.nodes:
                yield ((("links", link, "nodes", name, "modem"), ("links", link, "modem")),
                       spec.modem, spec.member(name).modem)
