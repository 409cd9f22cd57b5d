"""The one report of a fleet run: ``zab sim``, ``zab sim --fast``/``--speed`` and the demo build
it the same way (:meth:`MissionReport.build`) and render it as text
(:func:`print_report`), JSON (:meth:`MissionReport.to_dict`) or HTML
(:func:`bridge.report.html.write_report`).

Definitions, one each:

- a channel's *sent*: values the bridges put in frames (the newest at each turn; an
  acknowledged one again until confirmed), summed over the senders; *delivered*: arrivals at
  all receivers together (one frame reaches several);
- its age of information: :mod:`bridge.report.age`, exact from the arrivals, up to the end of
  the run;
- the run's end: when it was told to stop (or now, while it runs); its duration from the start
  (the fleet ready, or virtual time 0);
- frames: each node's counters (``NodeStats``) summed; per link: the water's counters (only
  when the run has a simulated water of its own).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.table import Table

from bridge.frozen import direct_init
from bridge.report.age import AgeOfInformation

if TYPE_CHECKING:
    from bridge.core.loaded import LoadedMission
    from bridge.core.node import NodeCore

LINK_ROWS = 60
"""Links listed in the printed report at most: a fleet of n nodes has n × (n − 1) of them
(62 250 at 250 nodes, minutes of terminal rendering); beyond this the worst are listed and
the rest summed in one row. The JSON and HTML reports keep every link."""


@dataclass(frozen=True, slots=True)
class Age:
    """Age of information of a channel over its receivers, seconds."""

    mean_s: float
    max_s: float


@dataclass(frozen=True, slots=True)
class ChannelFigures:
    """One channel: its bit length, values sent and delivered, and its age."""

    name: str
    bits: int
    sent: int
    delivered: int
    age: Age | None


@direct_init
@dataclass(frozen=True, slots=True)
class LinkFigures:
    """One directed link ``src -> dst`` of the simulated water (addresses, ``name`` with node
    names): frames sent, delivered, and lost per cause."""

    name: str
    src: int
    dst: int
    sent: int
    delivered: int
    lost: dict[str, int]

    @property
    def ratio(self) -> float:
        """Share of the frames sent that were delivered (1 when none were sent)."""
        return self.delivered / self.sent if self.sent else 1.0

    @property
    def in_flight(self) -> int:
        """Frames sent but neither delivered nor lost yet when the run ended (in the water)."""
        return max(0, self.sent - self.delivered - sum(self.lost.values()))


@dataclass(frozen=True, repr=False)
class MissionReport:
    """What a fleet run achieved; see the module docstring for each figure's definition.

    Its repr is a line of sizes, not every figure: ``asyncio.run`` builds the repr of the
    value its coroutine returns when it restores its own Ctrl-C handler (through the task's
    repr), and the whole repr of a 250-node report (62,250 links, every node's snapshot)
    took 0.3-0.5 s after each ``asyncio.run(run_fast(...))`` at 250 × 64 (``zab sim`` was
    spared: its own Ctrl-C handler replaces asyncio's)."""

    mission: str
    clock: str  # "wall" (zab sim) or "virtual" (--fast, --speed)
    duration_s: float
    channels: dict[str, ChannelFigures]
    nodes: dict[str, dict[str, Any]]  # each node's NodeCore.snapshot at the end
    links: list[LinkFigures]
    frames_sent: int
    frames_received: int
    wall_s: float | None = None  # virtual clock: the wall seconds the run took (unrounded)
    queries: dict[str, Any] | None = field(default=None)  # synthetic gets (--fast)
    surfacing: dict[str, list[dict[str, Any]]] | None = field(default=None)
    """Scripted surfacings (--fast): per vehicle, its switches to IP and back."""

    @classmethod
    def build(cls, loaded: LoadedMission, cores: Mapping[str, NodeCore],
              ages: AgeOfInformation, start: float, end: float,
              water: Mapping[str, Any] | None = None, *, clock: str = "wall",
              wall_s: float | None = None) -> MissionReport:
        """The report of ``cores`` run from ``start`` to ``end`` (their clock); ``water``: the
        simulated water's ``stats()`` when the run has one."""
        channels = channel_figures(loaded, cores, ages.summary(end))
        found = (water or {}).get("links", ())
        name = {a: loaded.mission.name_of(a)  # each address once, not twice per link
                for a in {link["src"] for link in found} | {link["dst"] for link in found}}
        links = [LinkFigures(f"{name[link['src']]}->{name[link['dst']]}"
                             + (f" ({link['link']})" if "link" in link else ""), link["src"],
                             link["dst"], link["sent"], link["delivered"], dict(link["lost"]))
                 for link in found]
        return cls(
            mission=loaded.mission.mission, clock=clock, duration_s=round(end - start, 3),
            channels=channels, nodes={n: core.snapshot(end) for n, core in cores.items()},
            links=links,
            frames_sent=sum(core.stats.frames_sent for core in cores.values()),
            frames_received=sum(core.stats.frames_received for core in cores.values()),
            wall_s=wall_s)

    def __repr__(self) -> str:
        return (f"MissionReport(mission={self.mission!r}, clock={self.clock!r}, "
                f"duration_s={self.duration_s}, channels={len(self.channels)}, "
                f"nodes={len(self.nodes)}, links={len(self.links)}, "
                f"frames_sent={self.frames_sent}, frames_received={self.frames_received})")

    @property
    def speedup(self) -> float | None:
        """Virtual seconds per wall second (virtual clock only)."""
        if self.wall_s is None:
            return None
        return round(self.duration_s / self.wall_s, 1) if self.wall_s > 0 else math.inf

    @property
    def frames_per_wall_s(self) -> float | None:
        """Frames sent and received per wall second (virtual clock only)."""
        if self.wall_s is None or self.wall_s <= 0:
            return None
        return round((self.frames_sent + self.frames_received) / self.wall_s, 1)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-able data (``--report x.json``)."""
        out: dict[str, Any] = {"mission": self.mission, "clock": self.clock,
                               "duration_s": self.duration_s}
        if self.wall_s is not None:
            out |= {"wall_s": round(self.wall_s, 3), "speedup": self.speedup}
        out |= {"frames_sent": self.frames_sent, "frames_received": self.frames_received}
        if self.wall_s is not None:
            out["frames_per_wall_s"] = self.frames_per_wall_s
        out["channels"] = {
            c.name: {"bits": c.bits, "sent": c.sent, "delivered": c.delivered,
                     "age_of_information": None if c.age is None else
                     {"mean_s": c.age.mean_s, "max_s": c.age.max_s}}
            for c in self.channels.values()}
        out["nodes"] = self.nodes
        out["links"] = [{"link": link.name, "src": link.src, "dst": link.dst,
                         "sent": link.sent, "delivered": link.delivered,
                         "lost": dict(link.lost), "in_flight": link.in_flight}
                        for link in self.links]
        if self.queries is not None:
            out["queries"] = self.queries
        if self.surfacing is not None:
            out["surfacing"] = self.surfacing
        return out


def channel_figures(loaded: LoadedMission, cores: Mapping[str, NodeCore],
                    ages: Mapping[str, Mapping[str, float]] | None = None,
                    ) -> dict[str, ChannelFigures]:
    """Each channel's figures so far (``ages``: :meth:`AgeOfInformation.summary`)."""
    out = {}
    for c in loaded.table.channels:
        age = (ages or {}).get(c.name)
        out[c.name] = ChannelFigures(
            c.name, c.bits, sum(core.stats.sent_per_channel[c.name] for core in cores.values()),
            sum(core.stats.received_per_channel[c.name] for core in cores.values()),
            Age(age["mean_s"], age["max_s"]) if age is not None else None)
    return out


def print_report(console: Console, report: MissionReport) -> None:
    """The report as text: channels, acoustic links and, on a virtual clock, the pace."""
    table = Table("channel", "bits", "sent", "delivered", "mean age", "max age",
                  title=f"{report.mission}: {report.duration_s:.0f} s")
    for c in report.channels.values():
        table.add_row(c.name, str(c.bits), str(c.sent), str(c.delivered),
                      f"{c.age.mean_s:.1f} s" if c.age else "—",
                      f"{c.age.max_s:.1f} s" if c.age else "—")
    console.print(table)
    links = report.links
    if links:
        shown = links if len(links) <= LINK_ROWS else worst_links(links, LINK_ROWS - 1)
        title = "links in the water" if shown is links else \
            f"links in the water: the {len(shown)} worst of {len(links)}"
        flying = any(link.in_flight for link in links)  # sent = delivered + lost + this
        lt = Table("link", "sent", "delivered", "lost", *(["in flight at the end"] * flying),
                   title=title)
        for link in shown:
            lt.add_row(link.name, str(link.sent), str(link.delivered), _lost(link.lost),
                       *([str(link.in_flight)] * flying))
        if shown is not links:
            ids = {id(link) for link in shown}
            rest = [link for link in links if id(link) not in ids]
            lost: dict[str, int] = {}
            for link in rest:
                for k, v in link.lost.items():
                    lost[k] = lost.get(k, 0) + v
            lt.add_row(f"{len(rest)} others", str(sum(link.sent for link in rest)),
                       str(sum(link.delivered for link in rest)), _lost(lost),
                       *([str(sum(link.in_flight for link in rest))] * flying))
        console.print(lt)
    if report.wall_s is not None:
        console.print(f"{report.duration_s:g} s simulated in {round(report.wall_s, 3):g} s wall "
                      f"({report.speedup:g}× real time); {report.frames_sent} frames sent, "
                      f"{report.frames_received} received ({report.frames_per_wall_s:g} "
                      "frames per wall second)")


def worst_links(links: list[LinkFigures], n: int) -> list[LinkFigures]:
    """The ``n`` links delivering the smallest share of what was sent, in report order."""
    order = heapq.nsmallest(n, range(len(links)), key=lambda i: (links[i].ratio, i))
    return [links[i] for i in sorted(order)]


def _lost(lost: Mapping[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in lost.items() if v) or "0"
