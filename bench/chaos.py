"""Restarts during a stream of reliable commands: nothing lost, nothing twice, one report each.

A surface node (``ops``) sends numbered commands to a vehicle (``auv``) on a reliable channel
over lossy water, while both are killed and restarted again and again. Two ways to run it:

- ``--virtual`` (default): the node cores on the virtual clock (:class:`FastFleet`), each
  restart a new core from the node's last saved state, as a ``kill -9`` leaves it on disk.
  Deterministic by ``--seed``; 10 000 commands and 100 restarts take seconds.
- ``--real``: the real processes: ``zab water``, one ``zab run`` per node with its own
  ``--state-dir``, and plain Zenoh applications (importing nothing of ours) that publish the
  commands, subscribe to the vehicle's output and to the delivery reports. The bridges are
  killed with SIGKILL at random moments and started again.

Printed per run: sent (commands the sending bridge accepted: any report, or a publication),
delivered once, duplicates, out of order, reported delivered, reported failed by reason,
without a terminal report, false ``delivered`` (reported delivered, never published), and
terminal reports given twice. The goal: duplicates, out of order, no terminal report and false
delivered all 0, and delivered + failed = sent.

    uv run python bench/chaos.py --virtual --commands 10000 --restarts 100 --loss 0.3
    uv run python bench/chaos.py --real --commands 300 --loss 0.4
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MISSION = """\
mission: chaos
modem: {backend: sim, frame_bytes: 64, options: {preset: evologics-s2c-im, loss: @LOSS@,
        water: "127.0.0.1:@WATER@"}}
mac: {type: tdma, slot_s: 2.0, guard_s: 0.2, order: [ops, auv]}
nodes:
  ops:
    address: 1
    role: surface
    position: {x: 0, y: 0, depth: 0}
    zenoh: {listen: ["tcp/127.0.0.1:@OPS@"]}
  auv:
    address: 2
    position: {x: 300, y: 0, depth: 20}
    zenoh: {listen: ["tcp/127.0.0.1:@AUV@"]}
channels:
  - name: command
    from: ops
    to: auv
    reliable: true
    queue: 256
    elements:
      - in: cmd
        out: ops/cmd
        fields: [{field: n, type: int, min: 0, max: 65535}]
  - name: status
    from: auv
    to: ops
    elements:
      - in: status
        out: auv/status
        fields: [{field: depth, type: float, min: 0, max: 100, bits: 10}]
"""

TERMINAL = ("delivered", "failed")


def mission_text(loss: float, ports: dict[str, int] | None = None, auth: bool = False,
                 template: str = MISSION) -> str:
    """``template`` with its @LOSS@ and @PORT@ names filled in (``auth``: frames
    authenticated)."""
    ports = ports or {"WATER": 7600, "OPS": 7501, "AUV": 7502}
    text = template.replace("@LOSS@", str(loss))
    if auth:  # authenticated frames: a forgetful sender's counter starts below its peer's mark
        text = "wire: {auth: {tag_bytes: 4}}\n" + text
    for name, port in ports.items():
        text = text.replace(f"@{name}@", str(port))
    return text


@dataclass
class Tally:
    """What the applications saw: publications in order, and every delivery report."""

    published: list[int] = field(default_factory=list)
    reports: dict[int, list[dict[str, Any]]] = field(default_factory=lambda: defaultdict(list))
    offered: int = 0

    def add_report(self, payload: dict[str, Any]) -> None:
        ref = payload.get("ref")
        if ref is not None and str(ref).isdigit():
            self.reports[int(ref)].append(payload)

    def summary(self) -> dict[str, Any]:
        counts = Counter(self.published)
        sent = set(self.reports) | set(counts)
        terminal = {n: [r for r in self.reports.get(n, ()) if r["state"] in TERMINAL]
                    for n in sent}
        failed = Counter(r["reason"].split(":")[0].split("=")[0].strip()
                         for rs in terminal.values() for r in rs if r["state"] == "failed")
        delivered_reported = {n for n, rs in terminal.items()
                              if any(r["state"] == "delivered" for r in rs)}
        out_of_order = sum(1 for a, b in zip(self.published, self.published[1:], strict=False)
                           if b < a)
        return {
            "offered": self.offered,
            "sent": len(sent),
            "delivered_once": sum(1 for c in counts.values() if c == 1),
            "duplicates": sum(c - 1 for c in counts.values() if c > 1),
            "out_of_order": out_of_order,
            "reported_delivered": len(delivered_reported),
            "reported_failed": dict(failed),
            "no_terminal_report": sum(1 for rs in terminal.values() if not rs),
            "false_delivered": len(delivered_reported - set(counts)),
            "terminal_twice": sum(1 for rs in terminal.values() if len(rs) > 1),
        }


def goal_met(s: dict[str, Any]) -> bool:
    return (s["duplicates"] == 0 and s["out_of_order"] == 0 and s["no_terminal_report"] == 0
            and s["false_delivered"] == 0 and s["terminal_twice"] == 0
            and s["reported_delivered"] + sum(s["reported_failed"].values()) == s["sent"])


# -- on the virtual clock ------------------------------------------------------------------------


def run_virtual(commands: int, restarts: int, loss: float, seed: int,
                interval_s: float = 1.0, downtime_s: float = 3.0,
                forgetful: str | None = None, auth: bool = False) -> dict[str, Any]:
    """``commands`` at ``interval_s``; ``restarts`` kills at random times, each node staying
    down ``downtime_s`` (the ``ops`` application's puts are lost meanwhile). ``forgetful``: a
    node that restarts without its saved state (a new epoch) each time."""
    from bridge.core.loaded import parse_mission
    from bridge.core.node import Publish, Status
    from bridge.runtime.virtual_fleet import FastFleet, Timed

    tally = Tally()

    def collect(timed: Timed) -> None:
        out = timed.output
        if isinstance(out, Publish) and timed.node == "auv" and out.key == "ops/cmd":
            tally.published.append(int(out.value["n"]))
        elif isinstance(out, Status) and out.topic == "delivery/command":
            tally.add_report(out.payload)

    fleet = FastFleet(parse_mission(mission_text(loss, auth=auth)), seed=seed,
                      keep_outputs=False, on_output=collect,
                      key=b"a chaos mission key, 32 bytes.." if auth else None)
    rng = random.Random(seed)
    end = 1.0 + commands * interval_s
    for i in range(commands):
        fleet.put("ops", "cmd", {"n": i}, at=1.0 + i * interval_s, ref=str(i))
    tally.offered = commands
    for t in sorted(rng.uniform(5.0, end) for _ in range(restarts)):
        node = rng.choice(["ops", "auv"])
        fleet.call_at(t, lambda n=node: fleet.stop(n))
        fleet.call_at(t + downtime_s,
                      lambda n=node: fleet.restart(n, keep_state=n != forgetful))
    fleet.run_until(end + 600.0)
    return {"mode": "virtual", "loss": loss, "restarts": restarts, "seed": seed,
            "forgetful": forgetful, "auth": auth, **tally.summary()}


# -- real processes ------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Processes:
    """``zab water`` and one ``zab run`` per node, each startable and killable."""

    def __init__(self, mission: Path, state: Path, log: Path) -> None:
        self.mission, self.state, self.log = mission, state, log
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def _zab(self, *args: str) -> list[str]:
        return [sys.executable, "-m", "bridge", *args]

    def start(self, name: str) -> None:
        args = (self._zab("water", str(self.mission)) if name == "water" else
                self._zab("run", str(self.mission), "--node", name, "--state-dir",
                          str(self.state / name)))
        with (self.log / f"{name}.log").open("ab") as out:
            self.procs[name] = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT)

    def kill(self, name: str) -> None:
        proc = self.procs.pop(name, None)
        if proc is not None:
            proc.send_signal(signal.SIGKILL)
            proc.wait()

    def stop_all(self) -> None:
        for name in list(self.procs):
            proc = self.procs.pop(name)
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def zenoh_client(endpoints: Iterable[str], timeout_s: float = 30.0) -> Any:
    """A plain Zenoh session (nothing of ours) connected to ``endpoints`` on loopback, retried
    until the bridge listening there is up."""
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/retry",  # back within a second of a bridge's restart
                        "{period_init_ms: 200, period_max_ms: 500, period_increase_factor: 2}")
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def run_real(commands: int, loss: float, seed: int, kill_every_s: float = 13.0,
             interval_s: float = 0.5, settle_s: float = 600.0) -> dict[str, Any]:
    """The real processes, killed with SIGKILL every ``kill_every_s`` (alternating nodes)."""
    ports = {"WATER": free_port(), "OPS": free_port(), "AUV": free_port()}
    with tempfile.TemporaryDirectory(prefix="zab-chaos-") as tmp:
        mission = Path(tmp) / "chaos.yaml"
        mission.write_text(mission_text(loss, ports))
        tally = drive_real(mission, ["water", "ops", "auv"], ports["OPS"], ports["AUV"],
                           "@zab/chaos/ops/delivery/command", ["auv", "ops"], commands,
                           seed, kill_every_s, interval_s, settle_s)
    return {"mode": "real", "loss": loss, "seed": seed, **tally.summary()}


def drive_real(mission: Path, starts: list[str], sender: int, receiver: int, reports: str,
               victims: list[str], commands: int, seed: int, kill_every_s: float,
               interval_s: float, settle_s: float) -> Tally:
    """Start ``starts`` (``water`` and nodes) for ``mission``; plain Zenoh applications at
    the ``sender`` and ``receiver`` nodes' ports put numbered commands on ``cmd`` and count
    them on ``ops/cmd`` and on the delivery key ``reports``; one of ``victims`` is killed
    with SIGKILL every ``kill_every_s`` and started again."""
    import msgpack
    import zenoh

    rng = random.Random(seed)
    tally = Tally()
    lock = threading.Lock()
    root = mission.parent
    procs = Processes(mission, root, root)
    for name in starts:
        procs.start(name)
    ops_app = zenoh_client([f"tcp/127.0.0.1:{sender}"])
    auv_app = zenoh_client([f"tcp/127.0.0.1:{receiver}"])

    def on_command(sample: zenoh.Sample) -> None:
        with lock:
            tally.published.append(int(msgpack.unpackb(sample.payload.to_bytes())["n"]))

    def on_report(sample: zenoh.Sample) -> None:
        with lock:
            tally.add_report(msgpack.unpackb(sample.payload.to_bytes()))

    subs = [auv_app.declare_subscriber("ops/cmd", on_command),
            ops_app.declare_subscriber(reports, on_report)]
    publisher = ops_app.declare_publisher("cmd", encoding=zenoh.Encoding("application/msgpack"))
    try:
        next_kill = time.time() + kill_every_s
        for i in range(commands):
            publisher.put(msgpack.packb({"n": i}), attachment=f"ref:{i}".encode())
            tally.offered += 1
            time.sleep(interval_s)
            if time.time() >= next_kill:
                victim = rng.choice(victims)
                procs.kill(victim)
                time.sleep(rng.uniform(0.5, 3.0))
                procs.start(victim)
                next_kill = time.time() + kill_every_s
        deadline = time.time() + settle_s
        while time.time() < deadline:
            time.sleep(2.0)
            with lock:
                summary = tally.summary()
            if summary["no_terminal_report"] == 0 and summary["sent"]:
                break
    finally:
        for sub in subs:
            sub.undeclare()
        ops_app.close()
        auv_app.close()
        procs.stop_all()
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--virtual", action="store_true", help="virtual clock (default)")
    mode.add_argument("--real", action="store_true", help="real zab processes")
    parser.add_argument("--commands", type=int, default=None)
    parser.add_argument("--restarts", type=int, default=100, help="virtual: kills in the run")
    parser.add_argument("--loss", type=float, nargs="+", default=[0.3, 0.4])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--forgetful", choices=["ops", "auv"], help="virtual: this node "
                        "restarts without its saved state (shows the epoch resync)")
    parser.add_argument("--auth", action="store_true", help="virtual: authenticated frames "
                        "(with --forgetful ops: a sender that lost its counter)")
    args = parser.parse_args()
    ok = True
    for loss in args.loss:
        if args.real:
            result = run_real(args.commands or 300, loss, args.seed)
        else:
            result = run_virtual(args.commands or 10_000, args.restarts, loss, args.seed,
                                 forgetful=args.forgetful, auth=args.auth)
        ok &= goal_met(result)
        print(json.dumps(result))
    print("goal met" if ok else "GOAL NOT MET")
    if os.environ.get("CHAOS_STRICT"):
        sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
