"""The ``zab`` command line. Each command wraps a typed function of the package."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Coroutine
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.logging import RichHandler
from rich.table import Table

from bridge.cli import helptext
from bridge.cli.text import said
from bridge.core.loaded import LoadedMission, load_mission
from bridge.errors import (
    BackendError,
    EncodeError,
    MissionError,
    NodeFailure,
    SessionError,
    WaterError,
)
from bridge.report.check import check_mission, silent_nodes
from bridge.runtime.keys import frame_key, throwaway_note
from bridge.words import counted

if TYPE_CHECKING:
    from bridge.report.model import MissionReport
    from bridge.ros2.element import Ros2Element

T = TypeVar("T")

helptext.install()
app = typer.Typer(
    help="zenoh-acoustic-bridge: one Zenoh pub/sub space across WiFi and water.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings=helptext.HELP_OPTIONS,
    rich_markup_mode="markdown",  # a docstring's paragraph reads as one paragraph
)
# Text printed is never read as rich markup or emoji: a user's or an exception's text ("[/]",
# ":100:") prints as it is; the CLI's own styles come as Text (bridge.cli.text.said).
console = Console(width=None if sys.stdout.isatty() else 120, markup=False, emoji=False)
# An error is one line a script or an editor can read (path:line:col: message): the terminal
# wraps it, rich does not cut it.
err = Console(stderr=True, width=None if sys.stderr.isatty() else 120, soft_wrap=True,
              markup=False, emoji=False)

def _error(label: str, message: object = "", style: str = "bold red") -> None:
    """Print on stderr ``label`` in ``style``, then ``message`` as it is."""
    message = str(message)
    err.print(said((label, style), " " if message and label else "", message), highlight=False)


def _endpoints(*, listen: bool) -> Any:
    """An option's callback refusing (exit 2) an endpoint Zenoh would not take, naming it."""
    def check(values: list[str] | None) -> list[str] | None:
        from bridge.mission.endpoints import endpoint_problem

        for value in values or ():
            if (why := endpoint_problem(value, listen=listen)) is not None:
                raise typer.BadParameter(why)
        return values
    return check


def _number(low: float, high: float, *, above: bool = False, zero: bool = False,
            unit: str = "") -> Any:
    """An option's callback refusing (exit 2, as click's range) a number that is not finite
    or not within ``low``..``high`` (``above``: > ``low``; ``zero``: 0 also taken)."""
    def check(value: float | None) -> float | None:
        if value is None or (zero and value == 0) or (
                (value > low if above else value >= low) and value <= high):
            return value  # (NaN fails each comparison)
        bound = f"{'>' if above else 'from'} {low:.12g}{unit}" + (
            f" up to {high:.12g}{unit}" if above else f" to {high:.12g}{unit}")
        raise typer.BadParameter(f"must be a finite number {bound}"
                                 + (" (or 0)" if zero else "") + f", not {value:g}")
    return check


SECONDS = _number(0, 366 * 86400.0, above=True, unit=" s")
"""A duration: finite, > 0 (up to a year)."""


def _water_address(value: str | None) -> str | None:
    """``--water``'s HOST:PORT checked at the option (exit 2, not each node's traceback)."""
    from bridge.modems.sim import parse_water_address

    if value is not None:
        try:
            parse_water_address(value)
        except BackendError:
            raise typer.BadParameter(f"must be HOST:PORT (e.g. 127.0.0.1:7600), not "
                                     f"{value!r}") from None
    return value


MissionArg = Annotated[Path, typer.Argument(help="Mission file (YAML).", show_default=False)]
VerboseOpt = Annotated[bool, typer.Option("--verbose", "-v", help="Log debug messages too.")]


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        console.print(f"zab {version('zenoh-acoustic-bridge')}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    show_version: Annotated[bool, typer.Option(
        "--version", "-V", help="Print the version and exit.", callback=_version,
        is_eager=True)] = False,
) -> None:
    """zenoh-acoustic-bridge: one Zenoh pub/sub space across WiFi and water."""


def _load(path: Path) -> LoadedMission:
    """Load a mission or exit 2 with the loader's message (never a traceback)."""
    try:
        return load_mission(path)
    except MissionError as exc:
        err.print(said(("invalid mission", "bold red"), f"\n{exc}"), highlight=False)
        raise typer.Exit(2) from None


def _run_or_exit(main: Coroutine[Any, Any, T]) -> T:
    """Run ``main``; a problem found at start (a missing key, a Zenoh or water port taken, a
    router that does not answer, a state directory that cannot be written) exits 2 with one
    line, never a traceback; a node that cannot go on (:class:`NodeFailure`) exits 1 with one
    line."""
    from bridge.runtime.state_file import StateError

    try:
        return asyncio.run(main)
    except (MissionError, SessionError, StateError, WaterError) as exc:
        _error("cannot start:", exc)
        raise typer.Exit(2) from None
    except NodeFailure as exc:
        _error("stopped:", exc)
        raise typer.Exit(1) from None


def _logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(message)s",
        handlers=[RichHandler(console=err, show_path=False, rich_tracebacks=False)],
        force=True,
    )


def _install_stop(stop: asyncio.Event) -> None:
    """SIGINT/SIGTERM set ``stop`` so everything closes cleanly."""
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)


@app.command()
def check(
    mission: MissionArg,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    no_key: Annotated[bool, typer.Option("--no-key", help="Check the file alone: do not look "
                                         "for the frame key (CI, a design laptop).")] = False,
) -> None:
    """Validate a mission; show channel sizes, frame fill and airtime.

    Exit 1 if something can never be sent (an entry too large for a frame even in
    fragments, a frame larger than the modem sends; a value larger than a frame travels in
    fragments and is only a warning), 2 if the file is invalid (with --json: a JSON object
    with the errors on stdout), a node has something to send but never a turn under the MAC
    (a sender, or a reliable channel's receiver that must acknowledge: --json lists them
    under "silent") or a frame key here disagrees with its wire.auth (a key too
    short, or a key present and wire.auth not said). No key at all is fine: checking a file
    is not running a vehicle, and it says that `zab run` will need one.
    """
    if as_json:
        try:
            loaded = load_mission(mission)
        except MissionError as exc:
            print(json.dumps({"ok": False, "errors": _problems(exc)}, indent=2))
            raise typer.Exit(2) from None
    else:
        loaded = _load(mission)
    report = check_mission(loaded)
    key = frame_key(loaded.mission, look=not no_key)
    note = _run_needs_key(loaded) if key.throwaway else None
    problem = None if note else key.problem  # no key here at all: zab run's concern
    code = 2 if problem or report.invalid else 0 if report.ok else 1
    if as_json:
        errors = [*report.errors, *([problem] if problem else [])]
        print(json.dumps({**report.data, "errors": errors, "ok": code == 0,
                          "frame_key": {**key.as_json(), "problem": problem, "note": note}},
                         indent=2))
        raise typer.Exit(code)
    data = report.data
    console.print(said(
        (data["mission"], "bold"), f": {len(data['nodes'])} nodes, {len(data['channels'])} "
        f"channels, backend {data['backend']}, mac {data['mac']}, "
        f"frame overhead {data['overhead_bytes']} B + {data['count_bits']}-bit count"
        + (" (DLBL on)" if data["dlbl"] else "")))
    channels = Table("index", "channel", "bits", "keys", "from", "to", "interval", "latching",
                     "priority", title="channels")
    for c in data["channels"]:
        channels.add_row(str(c["index"]), c["name"], str(c["bits"]), _keys_text(c.get("keys")),
                         ", ".join(c["from"]), ", ".join(c["to"]), f"{c['interval_s']:g} s",
                         str(c["latching"]).lower(), str(c["priority"]))
    console.print(channels)
    if data.get("queries"):
        queries = Table("query", "key", "servers", "askers", "request bits", "reply bits",
                        "deadline", title=f"queries (at most {data['max_open_queries']} open "
                        "per node)")
        for q in data["queries"]:
            deadlines = q["deadline_s"].values()
            queries.add_row(q["name"], q["key"], ", ".join(q["servers"]), ", ".join(q["askers"]),
                            str(q["request_bits"]), str(q["reply_bits"]),
                            f"≤ {max(deadlines):g} s" if deadlines else "—")
        console.print(queries)
    if data.get("images"):
        images = Table("image", "from", "to", "size", "budget", "fragment", "fragments",
                       "a picture takes", title="image channels (progressive pictures)")
        for i in data["images"]:
            took = i["seconds_per_picture"]
            images.add_row(i["name"], ", ".join(i["from"]), ", ".join(i["to"]),
                           f"{i['size'][0]}×{i['size'][1]}" + (" colour" if i["colour"] else ""),
                           f"{i['budget_bytes']} B (≤ {i['max_budget_bytes']} B)",
                           f"{i['fragment_bytes']} B", str(i["fragments_per_picture"]),
                           "?" if took is None else f"≤ {took:g} s" + (
                               f" (turns shared with {', '.join(i['shares_turns_with'])})"
                               if i["shares_turns_with"] else ""))
        console.print(images)
    if data.get("demand"):
        always = [c["name"] for c in data["channels"] if c.get("always")]
        want = counted(data["demand"]["want_entry_bits"], "bit")
        console.print(f"demand: @want entry {want}, re-sent "
                      f"every {data['demand']['refresh_s']:g} s; always sent: "
                      f"{', '.join(always) or 'none'}", highlight=False)
    if data.get("key_entry_bits"):
        console.print("@key entry (names a learned member): "
                      f"{counted(data['key_entry_bits'], 'bit')}", highlight=False)
    if data["dccl"]:
        numeric = data["dccl_numeric"]
        console.print(f"DCCL numeric rule: {numeric['rule']}, as {numeric['libdccl']}",
                      highlight=False)
    for d in data["dccl"]:  # like dccl --analyze
        console.print(f"DCCL message of channel {d['channel']!r}:\n{d['analysis']}",
                      highlight=False, markup=False)
    nodes = Table("node", "address", "role", "worst-case bits", "frame", "fill", "airtime",
                  "listen", title="nodes")
    for n in data["nodes"]:
        airtime = "?" if n["airtime_s"] is None else f"{n['airtime_s']:.3f} s"
        nodes.add_row(n["name"], str(n["address"]), n["role"], str(n["worst_case_bits"]),
                      f"{n['frame_bytes']} B", f"{n['fill']:.0%}", airtime, " ".join(n["listen"]))
    console.print(nodes)
    _print_mac(data)
    if (ranging := data.get("ranging")) is not None:
        anchors = ", ".join(a["node"] + (f" (live on {a['live_key']})" if a["live_key"] else "")
                            for a in ranging["anchors"])
        water = ranging["water_sound_speed_mps"]
        console.print(
            f"ranging ({' and '.join(ranging['by'])}): anchors "
            f"{anchors or 'none (ranges only, no positions)'}; sound speed "
            f"{ranging['sound_speed_mps']:g} m/s ({ranging['sound_speed_from']}"
            + (f"; ranging.water gives {water:g} m/s, which zab sim's water uses" if water
               else "") + (", then each node's live CTD" if ranging["live_ctd"] else "") + ")",
            highlight=False)
    if data.get("network"):
        from bridge.cli.check_network import print_network

        print_network(console, data["network"])
    for s in data["streams"]:
        retries = "no retry limit" if s["retries"] is None else f"{s['retries']} retries"
        console.print(
            f"channel {s['channel']!r}: {retries}, the first after "
            + ("at most " if s.get("learned") else "")
            + f"{s['retry_s']:g} s, ttl {s['ttl_s']:g} s"
            + (" (default)" if s["ttl_default"] else "")
            + f": every value is reported delivered or failed within {s['report_within_s']:g} s",
            highlight=False)
        for way in s.get("learned", ()):
            if way["hops"] < 2:
                continue
            crosses = ", ".join(f"{float(loss):.0%} lost a hop: {share:.0%}"
                                for loss, share in way["both_cross"].items())
            repaired = way.get("repaired", [])
            repair = (f"a copy lost on {', '.join(repaired)} is sent again by that hop's "
                      "sender until it hears the next hop carry it on or "
                      f"{way['to']} acknowledge it" + (
                          f", on its other hops by {way['from']} only"
                          if len(repaired) < way["hops"] else "")
                      if repaired else f"a lost copy is sent again by {way['from']} only")
            console.print(
                f"  {way['from']} -> {way['to']} ({way['hops']} hops): the first retry waits "
                f"the worst-case round trip, {way['first_retry_s']:g} s, until round trips "
                f"are measured (then their mean and 4 deviations, at least "
                f"{way['floor_s']:g} s; doubling only while {way['to']} is not heard); a "
                "value whose acknowledgement shows a later one arrived goes again at once. "
                f"Retried end to end, a copy and its acknowledgement both cross with "
                f"{crosses}; {repair}. Values are delivered in order, so each loss holds "
                "those behind it (docs/concepts.md: reliable values over lossy hops)",
                highlight=False)
    for warning in report.warnings:
        console.print(said(("warning:", "yellow"), f" {warning}"), highlight=False)
    console.print(key.describe() + (f": {note}" if note else ""), highlight=False)
    if (auth := data.get("auth")) is not None:
        console.print(
            f"{'sealed' if auth['encrypted'] else 'authenticated'} frames ({auth['cipher']}): "
            f"+{auth['bits_per_frame']} bits a frame ({auth['counter_bits']}-bit counter + "
            f"{auth['tag_bits']}-bit tag)" + (f"; the next key takes over at "
                                             f"{auth['next_key_at']} (both accepted "
                                             f"±{auth['overlap_s']:g} s)"
                                             if auth["next_key_at"] else ""), highlight=False)
    for error in report.errors:
        console.print(said(("error:", "red"), f" {error}"), highlight=False)
    if problem:
        _error("error:", problem)
    raise typer.Exit(code)


def _run_needs_key(loaded: LoadedMission) -> str | None:
    """What ``zab check`` says when an authenticated mission finds no key here (None: a key
    file is there but unreadable or empty, a problem of this machine's key)."""
    auth = loaded.mission.wire.auth
    if auth is None or (auth.key_file is not None and auth.key_file.exists()):
        return None
    where = f"${auth.key_env}" + (f" or {auth.key_file}" if auth.key_file else "")
    return f"`zab run` and `zab doctor` will need the mission key in {where}"


def _problems(exc: MissionError) -> list[dict[str, Any]]:
    """A mission error as data: file, line, column, path and message of each problem."""
    from dataclasses import asdict

    from bridge.mission.loader import MissionProblems

    if isinstance(exc, MissionProblems):
        return [asdict(p) for p in exc.problems]
    return [{"file": str(exc).split(":", 1)[0], "line": None, "column": None, "path": "",
             "message": str(exc)}]


def _keys_text(keys: dict[str, Any] | None) -> str:
    """A key family in the channel table: its index bits and members."""
    if keys is None:
        return "—"
    members = f"learned ≤ {keys['bound']}" if keys["learned"] else f"{keys['bound']} keys"
    return f"+{counted(keys['index_bits'], 'bit')} ({members})"


def _print_mac(data: dict[str, Any]) -> None:
    """Per node: the longest wait between transmit turns and the airtime share it implies."""
    def shown(v: Any) -> str:
        return f"{v:g}" if isinstance(v, float) else " ".join(v) if isinstance(v, list) else str(v)

    def said(timing: dict[str, Any]) -> str:  # (a mission of several links: one per link)
        return ", ".join(f"{k} ({said(v)})" if isinstance(v, dict) else f"{k} {shown(v)}"
                         for k, v in timing.items() if v != {})

    timing = said(data.get("mac_timing", {}))
    console.print(f"mac {data['mac']}" + (f": {timing}" if timing else ""), highlight=False)
    table = Table("node", "worst interval", "airtime share", "note", title="transmit turns")
    for n in data["nodes"]:
        mac = n["mac"]
        interval, share = mac["worst_interval_s"], mac["airtime_share"]
        table.add_row(n["name"], "—" if interval is None else f"{interval:.3f} s",
                      "?" if share is None else f"{share:.1%}", mac["note"])
    console.print(table)


@app.command()
def schema(
    out: Annotated[Path | None, typer.Option(help="Where to write (default: schemas/; with "
                                             "--payloads, schemas/payloads/MISSION/).")] = None,
    payloads: Annotated[Path | None, typer.Option(
        "--payloads", help="Instead: write the JSON Schema of every bridged key's payload of "
        "this mission.", show_default=False)] = None,
) -> None:
    """Write the mission file's JSON Schema (for editors), or a mission's payload schemas.

    With --payloads MISSION: the JSON Schema of every bridged key's payload of that mission.
    """
    from bridge.mission.schema import default_schema_path, schema_text

    if payloads is not None:
        from bridge.wire.payload_schema import write_payload_schemas

        loaded = _load(payloads)
        folder = out or Path("schemas") / "payloads" / loaded.mission.mission
        try:
            written = write_payload_schemas(loaded.table, loaded.mission.mission, folder)
        except (OSError, ValueError) as exc:
            _error("cannot write payload schemas:", exc, "red")
            raise typer.Exit(1) from None
        console.print(f"wrote {len(written) - 1} payload schemas and index.json to {folder}")
        return
    path = out or default_schema_path()
    try:
        path.write_text(schema_text(), encoding="utf-8")
    except OSError as exc:
        _error("cannot write the schema:", exc, "red")
        raise typer.Exit(1) from None
    console.print(f"wrote {path}")


@app.command()
def run(
    mission: MissionArg,
    node: Annotated[str, typer.Option("--node", "-n", help="This vehicle's name in the mission.")],
    verbose: VerboseOpt = False,
    log: Annotated[Path | None, typer.Option("--log", help="Record every frame and event to "
                                             "this MCAP file; {time} in the name becomes the "
                                             "start time (UTC).")] = None,
    state_dir: Annotated[Path | None, typer.Option(
        "--state-dir", help="Where the node keeps what a restart must resume (reliable "
        "values, delivered windows, frame counters). Default: $STATE_DIRECTORY (systemd), "
        "else ~/.local/state/zab.")] = None,
) -> None:
    """Run the bridge of one node (what each vehicle runs)."""
    from bridge.modems.setup import node_backends
    from bridge.runtime.state_file import StateError, StateFile, default_state_dir
    from bridge.runtime.zenoh_node import BridgeNode

    loaded = _load(mission)
    if node not in loaded.mission.nodes:
        err.print(f"no node {node!r} in {mission}; nodes: {', '.join(loaded.mission.nodes)}")
        raise typer.Exit(2)
    key = frame_key(loaded.mission)
    if key.problem:
        _error("cannot start:", f"{node}: {key.problem}")
        raise typer.Exit(2)
    _logging(verbose)
    try:
        factory = node_backends(loaded.network, node)
    except BackendError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(2) from None
    try:
        state = StateFile(state_dir or default_state_dir(), loaded.mission.mission, node)
    except StateError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(2) from None
    try:  # one bridge of the node at a time on this state (held until the process ends)
        state.hold()
    except StateError as exc:
        _error("cannot start:", f"{node}: {exc}")
        raise typer.Exit(2) from None

    async def main() -> None:
        stop = asyncio.Event()
        _install_stop(stop)
        recorder = None if log is None else _mission_log(log, loaded, node)
        bridge = BridgeNode(loaded, node, factory, on_event=recorder, state_file=state)
        threading.excepthook = lambda hook: bridge.fail(  # no thread dies silently
            f"the thread {hook.thread.name if hook.thread else '?'} failed: "
            f"{hook.exc_type.__name__}: {hook.exc_value}")

        async def announce() -> None:  # once the Zenoh session is open
            await bridge.started.wait()
            zab_log = logging.getLogger("zab")
            zab_log.log(logging.WARNING if key.state == "unsaid" else logging.INFO, "%s: %s",
                        node, key.describe())
            for silent in silent_nodes(loaded):  # (zab check refuses it: said here too)
                if silent["node"] == node:
                    zab_log.warning("%s: %s", node, silent["message"])
            zab_log.info("%s: bridge running (Ctrl-C to stop)", node)

        announced = asyncio.create_task(announce())
        try:
            await bridge.run(stop)
        finally:
            announced.cancel()
            if recorder is not None:
                recorder.close()
                logging.getLogger("zab").info("%s: mission log %s", node, recorder.path)

    try:
        _run_or_exit(main())
    finally:
        state.release()  # (however the bridge ended)


@app.command()
def water(
    mission: MissionArg,
    port: Annotated[int | None, typer.Option(help="TCP port (default: the mission's water).",
                                             min=0, max=65535)] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed of the ocean.")] = None,
) -> None:
    """Run the simulated ocean that `zab run` nodes with `backend: sim` join over loopback
    (with several links, one water per link, each at its modem's `water` address)."""
    from bridge.modems.sim import parse_water_address
    from bridge.runtime.fleet import waters_for

    loaded = _load(mission)
    links = {link.name: parse_water_address(link.view.modem.options.get("water",
                                                                       "127.0.0.1:7600"))
             for link in loaded.network.links}  # (checked at load)
    if port is not None and len(links) > 1:
        err.print("--port names one water; this mission has one per link (their modems' "
                  "`water` options say where)")
        raise typer.Exit(2)
    shared = _shared_water(links)
    if shared is not None:
        _error("cannot start:", shared)
        raise typer.Exit(2)

    async def main() -> None:
        stop = asyncio.Event()
        _install_stop(stop)
        services = waters_for(loaded, seed)
        started = []
        try:
            for (link, service), (host, default_port) in zip(services.items(), links.values(),
                                                             strict=True):
                bound = await service.start(host, port if port is not None else default_port)
                started.append(service)
                console.print(f"water ({service.preset.name}{f', link {link}' if link else ''})"
                              f" on {host}:{bound}; Ctrl-C to stop")
            await stop.wait()
        finally:
            for service in started:
                await service.stop()
                console.print_json(data=service.stats())

    _run_or_exit(main())


def _shared_water(links: dict[str, tuple[str, int]]) -> str | None:
    """Two links whose waters would listen at one address (theirs by default: a mission
    check refuses two that give the same), said in one line; None when each has its own."""
    seen: dict[tuple[str, int], str] = {}
    for link, address in links.items():
        if address in seen:
            return (f"links {seen[address]} and {link} both have their water at "
                    f"{address[0]}:{address[1]} (give each link's modem its own `water` option)")
        seen[address] = link
    return None


class ModemKind(StrEnum):
    evologics = "evologics"
    micromodem = "micromodem"


@app.command()
def emulate(
    kind: Annotated[ModemKind, typer.Argument(help="Which modem to emulate.")],
    mission: MissionArg,
    node: Annotated[str, typer.Option("--node", "-n", help="The node whose modem it is.")],
    link: Annotated[Path | None, typer.Option(help="Stable symlink to the pty (default: the "
                                              "device in the node's modem options).")] = None,
    tcp_port: Annotated[int | None, typer.Option(help="EvoLogics only: also listen on this "
                                                 "loopback TCP port.")] = None,
    water: Annotated[str | None, typer.Option(help="host:port of `zab water` (default: the "
                                              "mission's).")] = None,
    firmware: Annotated[str | None, typer.Option(help="EvoLogics only: the firmware it "
                                                 "reports and speaks (1.6 prints the older "
                                                 "RECVIM/RECVPBM layout; default 1.9).")] = None,
    crc32: Annotated[bool, typer.Option("--crc32", help="Micro-Modem only: end every line "
                                        "with MM2's 8-digit CRC-32 checksum.")] = False,
) -> None:
    """Emulate a node's modem on a pseudo-terminal, its frames crossing `zab water`."""
    loaded = _load(mission)
    if node not in loaded.mission.nodes:
        err.print(f"no node {node!r} in {mission}; nodes: {', '.join(loaded.mission.nodes)}")
        raise typer.Exit(2)
    if firmware is not None:
        from bridge.modems.evologics.protocol import firmware_is_legacy

        try:
            firmware_is_legacy(firmware)
        except ValueError as exc:
            err.print(f"--firmware: {exc}")
            raise typer.Exit(2) from None
    options = loaded.mission.node_modem(node).options
    device = options.get("device")
    if link is None and isinstance(device, str) and not device.startswith("socket://"):
        link = Path(device)
    address = water or str(options.get("water", "127.0.0.1:7600"))
    _logging(False)

    def ready(info: dict[str, object]) -> None:
        shown = ", ".join(f"{k} {v}" for k, v in info.items() if v is not None)
        console.print(f"{kind.value} modem of {node}: {shown}; water {address}; Ctrl-C to stop")

    async def main() -> None:
        stop = asyncio.Event()
        _install_stop(stop)
        if kind is ModemKind.evologics:
            from bridge.modems.evologics.emulator import FIRMWARE as EVOLOGICS_FIRMWARE
            from bridge.modems.evologics.emulator import run_emulator as evologics

            task = asyncio.create_task(evologics(loaded, node, water=address, link=link,
                                                 tcp_port=tcp_port, ready=ready,
                                                 firmware=firmware or EVOLOGICS_FIRMWARE))
        else:
            from bridge.modems.micromodem.emulator import run_emulator as micromodem

            task = asyncio.create_task(micromodem(loaded, node, water=address, link=link,
                                                  ready=ready, crc32=crc32))
        await asyncio.wait([task, asyncio.create_task(stop.wait())],
                           return_when=asyncio.FIRST_COMPLETED)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task

    try:
        _run_or_exit(main())
    except BackendError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(1) from None


@app.command()
def sim(
    mission: MissionArg,
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds.",
                                                   callback=SECONDS)] = None,
    report: Annotated[Path | None, typer.Option(
        help="Write a report here: .html a mission report with plots (one file, opens "
        "offline), anything else the numbers as JSON.")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed of the ocean.")] = None,
    live: Annotated[bool, typer.Option(help="Live terminal view.")] = True,
    verbose: VerboseOpt = False,
    log: Annotated[Path | None, typer.Option("--log", metavar="DIR", help="Record each node's "
                                             "frames and events, one MCAP file per node in "
                                             "this folder.")] = None,
    fast: Annotated[bool, typer.Option("--fast", help="Virtual clock, flat out: every node's "
                                       "bridge core over the simulated ocean, no Zenoh; inputs "
                                       "get synthetic values (default duration 3600 s).")]
    = False,
    speed: Annotated[float | None, typer.Option(help="Like --fast, with the virtual clock at "
                                                "this many times real time.",
                                                callback=_number(1e-3, 1e6))] = None,
    water: Annotated[str | None, typer.Option(metavar="HOST:PORT", help="Join a water already "
                                              "running there (zab water: emulated modems, a "
                                              "hydrophone) instead of starting one; without "
                                              "it, real modems are simulated.",
                                              callback=_water_address)] = None,
) -> None:
    """Run every node of the mission plus the simulated ocean, each node on its own endpoint."""
    loaded = _load(mission)
    _logging(verbose)
    if fast and speed is not None:
        err.print("--fast and --speed exclude each other (--fast: as fast as possible)")
        raise typer.Exit(2)
    logs = None if log is None else _fleet_logs(log, loaded)
    recorder = _recorder_for(report)
    try:
        if fast or speed is not None:
            result = _run_or_exit(_run_fast(loaded, duration or 3600.0, seed, speed, logs,
                                            recorder))
        else:
            from bridge.cli.sim import run_sim, simulated  # (Zenoh and modems: not --fast)

            if water is None:  # no emulators on a water of ours: real modems are simulated
                loaded, note = simulated(loaded)
                if note is not None:
                    console.print(note, highlight=False)
            result = _run_or_exit(run_sim(loaded, duration=duration, seed=seed, live=live,
                                          console=console, record=logs, recorder=recorder,
                                          water=water))
    finally:
        if logs is not None:
            logs.close()
    if logs is not None:
        console.print(f"mission logs: {', '.join(str(p.path) for p in logs.logs.values())}")
    if report is not None:
        _write_report(report, result, recorder, loaded)


def _fleet_logs(folder: Path, loaded: LoadedMission) -> Any:
    """The fleet's MCAP logbooks in ``folder`` (imported only when asked for); a folder that
    cannot be made (a file there) exits 2 before the run, as ``zab run --log``."""
    from bridge.runtime.logbook import FleetLogs

    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _error("cannot write the mission logs:", exc, "red")
        raise typer.Exit(2) from None
    return FleetLogs(folder, loaded)


def _recorder_for(report: Path | None) -> Any:
    """A recorder of the run's time series when the report is an HTML page."""
    if report is None or report.suffix.lower() not in (".html", ".htm"):
        return None
    from bridge.report import MissionRecorder

    return MissionRecorder()


def _write_report(path: Path, result: MissionReport, recorder: Any,
                  loaded: LoadedMission) -> None:
    """The HTML mission report if ``recorder`` ran, else the numbers as JSON."""
    try:
        if recorder is None:
            path.write_text(json.dumps(result.to_dict(), indent=2, default=str),
                            encoding="utf-8")
        else:
            from bridge.report import write_report

            write_report(path, result, recorder.recording, loaded)
    except OSError as exc:
        _error("cannot write the report:", exc, "red")
        raise typer.Exit(1) from None
    console.print(f"report written to {path}", highlight=False)


async def _run_fast(loaded: LoadedMission, duration: float, seed: int | None,
                    speed: float | None, record: Any, recorder: Any = None) -> MissionReport:
    """``zab sim --fast/--speed``: the virtual-clock run, its report printed."""
    from bridge.cli.sim_fast import run_fast
    from bridge.report.model import print_report

    stop = asyncio.Event()
    _install_stop(stop)
    pace = "as fast as possible" if speed is None else f"at {speed:g}× real time"
    console.print(said("simulating ", (loaded.mission.mission, "bold"),
                       f" on a virtual clock, {pace}: {duration:g} s, no Zenoh, synthetic "
                       "inputs"))
    if (note := throwaway_note(loaded.mission)) is not None:
        console.print(note, highlight=False)
    result = await run_fast(loaded, duration=duration, seed=seed, speed=speed, record=record,
                            stop=stop, recorder=recorder)
    print_report(console, result)
    if result.queries is not None:
        q = result.queries
        console.print(f"queries: {q['asked']} gets by synthetic operators, {q['answered']} "
                      f"answered (mean round trip {q['mean_round_trip_s']} s), "
                      f"{sum(q['errors'].values())} ended with an error, {q['open']} open")
    return result


@app.command()
def demo(
    duration: Annotated[float, typer.Option(help="Seconds before it ends by itself.",
                                            callback=SECONDS)] = 70.0,
    mission: Annotated[Path | None, typer.Option(help="Mission (default: the MORPH fleet).")]
    = None,
    live: Annotated[bool, typer.Option(help="Live terminal view of counters (under the "
                                       "tour's lines).")] = False,
    gui: Annotated[bool, typer.Option(help="Serve the browser GUI (zab gui) during the demo.")]
    = True,
    gui_port: Annotated[int, typer.Option(help="Port of the GUI (any free one if taken).",
                                          min=0, max=65535)] = 8080,
    report: Annotated[Path, typer.Option(help="Where to write the mission report (HTML).")]
    = Path("zab-demo-report.html"),
    loss: Annotated[float, typer.Option(help="Share of frames the simulated water loses.",
                                        min=0, max=0.9)] = 0.1,
) -> None:
    """A guided tour of a simulated fleet, end to end, in about a minute.

    It shows values crossing the water and their quantisation, latest-value semantics, an
    acknowledged command over a lossy link, position fixes from acoustic ranges and the GUI,
    a Zenoh get answered across the water, a vehicle surfacing (its data over IP) and diving,
    a camera's picture sharpening as its fragments arrive, then a summary and a mission
    report with plots.
    """
    from bridge.cli.demo import default_demo_mission, run_demo, tour_mission

    path = mission or default_demo_mission()
    _load(path)  # a mistake in the file itself is reported as such
    try:
        loaded, changes = tour_mission(path, loss, duration)
    except MissionError as exc:
        err.print(said((f"cannot make the tour's variant of {path}", "bold red"), f"\n{exc}"),
                  highlight=False)
        raise typer.Exit(2) from None
    _logging(False)
    logging.getLogger().setLevel(logging.WARNING)  # the tour's lines, not the nodes' chatter
    _run_or_exit(run_demo(loaded, duration=duration, console=console, live=live, gui=gui,
                          gui_port=gui_port, report=report, changes=changes, loss=loss))


@app.command()
def gui(
    mission: MissionArg,
    connect: Annotated[list[str] | None, typer.Option(
        "--connect", "-c", help="Zenoh endpoint of the node (default: its zenoh.listen in the "
        "mission); repeat for several.")] = None,
    node: Annotated[str | None, typer.Option(
        "--node", "-n", help="The node the GUI joins (default: the surface node).")] = None,
    host: Annotated[str, typer.Option(
        help="Address to serve the page on; 0.0.0.0 for tablets on the WiFi.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port of the page (0: any free port).",
                                      min=0, max=65535)] = 8080,
    verbose: VerboseOpt = False,
) -> None:
    """The fleet in a browser: map, channels and links per vehicle, commands, events."""
    from bridge.gui.server import GuiServer, serve_gui

    loaded = _load(mission)
    _logging(verbose)

    def ready(server: GuiServer) -> None:
        console.print(f"GUI of {loaded.mission.mission} at {server.url} (joins {server.node} "
                      f"at {' '.join(server.endpoints)}); Ctrl-C to stop", highlight=False)

    async def main() -> None:
        stop = asyncio.Event()
        _install_stop(stop)
        await serve_gui(loaded, stop, node=node, endpoints=connect or (), host=host, port=port,
                        ready=ready)

    try:
        _run_or_exit(main())
    except ValueError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(2) from None
    except OSError as exc:
        _error(f"cannot serve on {host}:{port}: {exc.strerror or exc}", style="red")
        raise typer.Exit(1) from None


EndpointArg = Annotated[str, typer.Argument(
    help="Zenoh endpoint of a vehicle, e.g. tcp/127.0.0.1:7502 (see zab demo).",
    show_default=False)]


@app.command()
def listen(
    endpoint: EndpointArg,
    keyexpr: Annotated[str, typer.Argument(help="Key expression to subscribe to.")] = "**",
    count: Annotated[int | None, typer.Option(help="Stop after this many values.", min=1)]
    = None,
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds.",
                                                   min=0)] = None,
    mission: Annotated[Path | None, typer.Option(
        "--mission", "-m", help="The fleet's mission: bridged values print to their "
        "channel's step (3.252 at a 0.0246 step, not 3.25242824).", show_default=False)]
    = None,
) -> None:
    """Print the values arriving at a Zenoh endpoint, decoded, one line each (Ctrl-C stops)."""
    from bridge.cli.poke import PokeError
    from bridge.cli.poke import listen as run_listen
    from bridge.cli.rounding import Steps

    steps = None if mission is None else Steps(_load(mission))

    def ready() -> None:
        err.print(f"listening on {keyexpr} at {endpoint}; Ctrl-C to stop", highlight=False)

    # Ctrl-C ends the process at once, the kernel's default: each line is out as it comes and
    # nothing is left to save. (Python's KeyboardInterrupt first waited for Zenoh's close,
    # and fresh-clone CI saw a Ctrl-C'd zab listen outlive 30 s, three times.)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        run_listen(endpoint, keyexpr, lambda line: print(line, flush=True), count=count,
                   duration=duration, ready=ready, steps=steps)
    except PokeError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(exc.code) from None


@app.command()
def put(
    endpoint: EndpointArg,
    key: Annotated[str, typer.Argument(help="Key to publish on, e.g. target_reference.",
                                       show_default=False)],
    value: Annotated[str, typer.Argument(
        help='The value as JSON, e.g. \'{"vector": {"x": 1.5, "y": 0.01}}\'.',
        show_default=False)],
    mission: Annotated[Path | None, typer.Option(
        "--mission", "-m", help="The fleet's mission: a value that the channels reading the "
        "key cannot take (a field they have not, a missing DCCL field, a number for a map, "
        "an image control the camera would not follow, anything on a camera's picture key) "
        "is refused, not sent.", show_default=False)] = None,
) -> None:
    """Publish one value (JSON on the command line, msgpack on Zenoh) at a Zenoh endpoint.

    On a ROS 2 topic's rmw_zenoh key the value goes as the CDR message of the type the key
    names (a field the type has not is refused). It goes as an operator's command, as the
    GUI's do: with a reference (`ref:put-…`) that an acknowledged channel's delivery reports
    echo.
    """
    import secrets

    from bridge.cli.poke import PokeError
    from bridge.cli.poke import put as run_put

    ref = f"put-{secrets.token_hex(4)}"
    loaded = None if mission is None else _load(mission)
    try:
        payload, encoding = run_put(endpoint, key, value, ref, loaded)
    except PokeError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(exc.code) from None
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    kind = "msgpack" if encoding else "CDR"
    console.print(f"put {key} ({len(payload)} B {kind}, ref {ref}) at {endpoint}",
                  highlight=False)


@app.command()
def doctor(
    mission: MissionArg,
    node: Annotated[str, typer.Option("--node", "-n", help="This vehicle's name in the mission.")],
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the modem.", min=0.1)]
    = 15.0,
    state_dir: Annotated[Path | None, typer.Option(
        "--state-dir", help="Where the node keeps its state (as `zab run`).")] = None,
) -> None:
    """Check that this vehicle can run its bridge, and print what to fix.

    Checks the mission, the modem port and its answer, the Zenoh endpoints, the state
    directory and the clock; exit 1 if something must be fixed.
    """
    from bridge.cli.doctor import run_doctor
    from bridge.runtime.state_file import default_state_dir

    loaded = _load(mission)
    findings = asyncio.run(run_doctor(loaded, node, timeout_s=timeout,
                                      state_dir=state_dir or default_state_dir()))
    marks = {"ok": ("ok  ", "green"), "warn": ("warn", "yellow"), "fail": ("FAIL", "red")}
    for f in findings:
        console.print(said(marks[f.status], f" {f.check:<8} {f.message}"), highlight=False)
        if f.fix and f.status != "ok":
            console.print(said(f"     {'':<8} ", ("fix:", "bold"), f" {f.fix}"), highlight=False)
    failed = sum(f.status == "fail" for f in findings)
    warned = sum(f.status == "warn" for f in findings)
    console.print(f"{node}: {failed} to fix, {counted(warned, 'warning')}" if failed or warned
                  else f"{node}: ready")
    raise typer.Exit(1 if failed else 0)


def _mission_log(path: Path, loaded: LoadedMission, node: str) -> Any:
    from bridge.runtime.logbook import MissionLog

    path = Path(str(path).replace("{time}", time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())))
    try:
        return MissionLog(path, loaded, node)
    except OSError as exc:
        _error("cannot write the mission log:", exc, "red")
        raise typer.Exit(2) from None


@app.command("help")
def help_(
    ctx: typer.Context,
    command: Annotated[list[str] | None, typer.Argument(
        help="A command (and a subcommand: log summary).", show_default=False)] = None,
) -> None:
    """Show this help, or a command's: `zab help sim` is `zab sim -h`."""
    typer.main.get_command(app).main([*(command or []), "--help"],
                                     prog_name=ctx.find_root().info_name)


log_app = typer.Typer(help="Read mission logs (MCAP) written with --log.", no_args_is_help=True,
                      context_settings=helptext.HELP_OPTIONS, rich_markup_mode="markdown")
app.add_typer(log_app, name="log")
LogArg = Annotated[Path, typer.Argument(help="Mission log (.mcap).", show_default=False)]


def _read_log(path: Path) -> Any:
    from bridge.runtime.logbook import LogError, read_log

    try:
        log = read_log(path)
    except LogError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(2) from None
    if log.note is not None:
        err.print(said((log.note, "yellow")), highlight=False)
    return log


@log_app.command("summary")
def log_summary(
    file: LogArg,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Per-channel counts and ages, and event counts, of a mission log."""
    from bridge.runtime.logbook import summarise

    data = summarise(_read_log(file))
    if as_json:
        print(json.dumps(data, indent=2))
        return
    console.print(said((str(data.get("mission") or "?"), "bold"), " node ",
                       (str(data["node"]), "bold"), f": {data['duration_s']:g} s logged"))
    table = Table("channel", "sent", "received", "from", "age at end", "longest gap",
                  title="channels")
    for name, c in data["channels"].items():
        table.add_row(name, str(c["sent"]), str(c["received"]), ", ".join(c["from"]),
                      "—" if c["age_s"] is None else f"{c['age_s']:.1f} s",
                      "—" if c["max_gap_s"] is None else f"{c['max_gap_s']:.1f} s")
    console.print(table)
    events = Table("event", "count", title="events")
    for kind, count in sorted(data["events"].items()):
        events.add_row(kind, str(count))
    console.print(events)


@log_app.command("replay")
def log_replay(
    file: LogArg,
    speed: Annotated[float, typer.Option(help="1 = as recorded, 10 = ten times faster, "
                                         "0 = as fast as possible.",
                                         callback=_number(1e-3, 1e6, zero=True))] = 1.0,
    connect: Annotated[list[str] | None, typer.Option(help="Zenoh endpoint to connect to "
                                                      "(repeatable).",
                                                      callback=_endpoints(listen=False))] = None,
    listen: Annotated[list[str] | None, typer.Option(help="Zenoh endpoint to listen on "
                                                     "(repeatable).",
                                                     callback=_endpoints(listen=True))] = None,
    wait: Annotated[float, typer.Option(help="Seconds to let subscribers connect before the "
                                        "first value.", callback=_number(0, 3600, unit=" s"))]
    = 1.0,
) -> None:
    """Publish the decoded data of a mission log on Zenoh again.

    Values go to the channels' output keys (msgpack or JSON as the mission says; a ROS 2
    topic's as CDR, the way a bridge publishes it; pictures as their files). Without
    --connect/--listen it listens on tcp/127.0.0.1:7447.
    """
    import zenoh

    from bridge.mission.model import ZenohSettings
    from bridge.runtime.logbook import LogError, replay
    from bridge.runtime.ros2_graph import Ros2Graph
    from bridge.runtime.session import close_quietly, open_session, origin_tag

    data = _read_log(file)
    if not connect and not listen:
        listen = ["tcp/127.0.0.1:7447"]
    try:
        session = open_session(ZenohSettings(listen=listen or [], connect=connect or []),
                               "replay")
    except SessionError as exc:
        _error("cannot start:", exc)
        raise typer.Exit(2) from None
    mission = data.loaded.mission.mission if data.loaded is not None else "?"
    origin = origin_tag(mission, f"{data.node}-replay")  # never re-bridged by a live node
    publishers: dict[str, Any] = {}

    def publish(key: str, payload: bytes, encoding: str) -> None:
        publisher = publishers.get(key)
        if publisher is None:
            publisher = publishers[key] = session.declare_publisher(
                key, encoding=zenoh.Encoding(encoding))
        publisher.put(payload, attachment=origin)

    # ROS 2 topics as a bridge publishes them (CDR, rmw_zenoh's attachment naming a bridge
    # publisher, which no live bridge takes as input), under a ROS 2 node of their own
    ros2 = Ros2Graph(session, mission, f"{data.node}-replay")
    unpublishable: set[str] = set()

    def publish_ros2(key: str, value: Any, element: Ros2Element, at: float) -> None:
        try:
            ros2.publish(key, value, element, at)
        except EncodeError as exc:
            if key not in unpublishable:  # said once a key
                unpublishable.add(key)
                err.print(said((f"{key}: not published: {exc}", "yellow")), highlight=False)

    console.print(f"replaying {file} ({data.node}) at "
                  f"{'full speed' if speed == 0 else f'{speed:g}x'} on "
                  f"{' '.join(listen or connect or [])}")
    try:
        time.sleep(wait)
        count = replay(data, publish, publish_ros2=publish_ros2, speed=speed)
    except LogError as exc:
        _error(str(exc), style="red")
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    finally:
        ros2.close()
        close_quietly(session)
    console.print(f"published {counted(count, 'value')}")


def main() -> None:
    app()
