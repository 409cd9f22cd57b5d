"""A small, quick fleet for the GUI tests, and applications publishing on its vehicles."""

from __future__ import annotations

import threading
import time

import yaml

from bridge.core.loaded import LoadedMission
from tests.harness import outside_session, put

# A small, quick fleet: a 2.1 s TDMA cycle, links down after 5 s of silence.
MISSION = """
mission: guitest
wire: {dlbl: true}
modem:
  backend: sim
  frame_bytes: 32
  options: {preset: evologics-s2c-im, seed: 3}
mac: {type: tdma, slot_s: 0.7, guard_s: 0.1, order: [ssv, auv1, auv2]}
link: {degraded_after_s: 5, down_after_s: 7}  # (a cycle is 2.1 s: one frame lost is no silence)
nodes:
  ssv: {address: 1, role: surface, position: {x: 0, y: 0, depth: 0.5}}
  auv1: {address: 2, position: {x: 40, y: 30, depth: 8}, nav_key: nav}
  auv2: {address: 3, position: {x: -30, y: 50, depth: 12}, nav_key: nav}
channels:
  - name: nav
    from: "auv[12]"
    to: ssv
    elements:
      - in: nav
        out: "{src}/nav"
        fields:
          - {field: x, resolution: 0.1, min: -500, max: 500}
          - {field: y, resolution: 0.1, min: -500, max: 500}
          - {field: depth, resolution: 0.1, min: 0, max: 100}
  - name: status
    from: "auv[12]"
    to: ssv
    elements:
      - in: status
        out: "{src}/status"
        fields:
          - {field: battery, type: int, min: 0, max: 100}
  - name: command
    from: ssv
    to: "auv[12]"
    elements:
      - in: command
        out: ssv/command
        fields:
          - {field: action, type: enum, values: [none, start, hold, surface]}
          - {field: leg, type: int, min: 0, max: 63}
"""

START = {"auv1": (40.0, 30.0, 8.0), "auv2": (-30.0, 50.0, 12.0)}


class VehicleApps:
    """On each vehicle, an application publishing navigation and status a few times a second
    (a new battery value each time), until stopped."""

    def __init__(self, loaded: LoadedMission) -> None:
        self.sessions = {name: outside_session(loaded, name) for name in START}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="vehicle-apps", daemon=True)

    def _run(self) -> None:
        t0 = time.time()
        while not self.stop.wait(0.3):
            t = time.time() - t0
            for name, session in self.sessions.items():
                x, y, depth = START[name]
                put(session, "nav", {"x": x + 0.5 * t, "y": y + 0.3 * t, "depth": depth})
                put(session, "status", {"battery": 100 - int(t * 3) % 100})

    def __enter__(self) -> VehicleApps:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5)
        for session in self.sessions.values():
            session.close()


def mission_text(text: str, loaded: LoadedMission) -> str:
    """Mission ``text`` with the free ports ``loaded`` was given (for a subprocess)."""
    data = yaml.safe_load(text)
    for name, node in loaded.mission.nodes.items():
        data["nodes"][name]["zenoh"] = {"listen": node.zenoh.listen}
    return yaml.safe_dump(data, sort_keys=False)
