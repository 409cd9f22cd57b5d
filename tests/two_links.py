"""A mission of two links for tests of the simulated water: an acoustic link (surface, rov1)
under TDMA and an RF link (rov1, rov2) polled by rov1, rov2 reaching the surface through rov1."""

from __future__ import annotations

TWO_LINKS = """\
mission: waters
wire: {{auth: off}}
links:
  acoustic:
    modem: {{backend: sim, options: {{preset: evologics-s2c-im{water_a}}}}}
    mac: {{type: tdma, slot_s: 1.5, guard_s: 0.2, order: [surface, rov1]}}
    nodes: [surface, rov1]
  rf:
    kind: rf
    modem: {{backend: sim, options: {{preset: {preset_rf}{water_rf}}}}}
    mac: {{type: polled, master: rov1}}
    nodes: [rov1, rov2]
nodes:
  surface: {{address: 1, role: surface, routes: {{rov2: rov1}}}}
  rov1: {{address: 2}}
  rov2: {{address: 3, routes: {{surface: rov1}}}}
channels:
  - {{name: n, from: rov2, to: surface, elements: [{{in: n, out: rov2/n, fields: [{{field: n,
      type: int, min: 0, max: 9}}]}}]}}
"""


def two_links(preset_rf: str = "s100-rf", water_a: str | None = "127.0.0.1:17620",
              water_rf: str | None = "127.0.0.1:17621") -> str:
    """The mission's text; a water of None: that link's modem names none (the default)."""
    return TWO_LINKS.format(preset_rf=preset_rf,
                            water_a="" if water_a is None else f", water: {water_a}",
                            water_rf="" if water_rf is None else f", water: {water_rf}")
