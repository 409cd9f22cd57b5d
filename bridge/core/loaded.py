"""A mission loaded to run: its validated model and its compiled channel table, every
mistake explained with file, line, column and field path.

:func:`bridge.mission.loader.read_mission` checks the YAML and the model; here come the checks
that need the layers above the model: the MAC's (:meth:`bridge.core.mac.Mac.problems`), the
channel table's (:class:`~bridge.wire.channels.ChannelTable`) and the frame's overhead.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from bridge.core.mac import mac_for
from bridge.mission.backends import backend_problems
from bridge.mission.loader import (
    Loc,
    Marks,
    cross_problems,
    located,
    read_mission,
    read_mission_file,
)
from bridge.mission.model import Mission
from bridge.mission.network import Network, modem_problems, network_problems
from bridge.wire.channels import ChannelTable, ChannelTableError
from bridge.wire.goby import frame_codec_for, goby_problems

__all__ = ["LoadedMission", "load_mission", "parse_mission"]


@dataclass(frozen=True)
class LoadedMission:
    """A validated mission with its compiled channel table."""

    path: Path
    mission: Mission
    table: ChannelTable
    marks: Marks = field(default_factory=dict, compare=False, repr=False)
    """Where each value of the file is written (line, column), to locate what is found later
    (``zab check``'s)."""

    @cached_property
    def network(self) -> Network:
        """The mission's links and routes."""
        return Network(self.mission)


def parse_mission(text: str, path: str | Path = "<mission>") -> LoadedMission:
    """Validate mission ``text``; raise :class:`~bridge.mission.loader.MissionProblems`
    listing every problem found."""
    mission, marks = read_mission(text, path)
    network = [*backend_problems(mission), *modem_problems(mission),
               *network_problems(mission)]
    problems = [*cross_problems(mission), *network]
    if not network:  # (each link's MAC sees the mission through its links, its modems'
        problems += _mac_problems(mission)  # timing through their presets)
    if not problems:
        try:
            table = ChannelTable.from_mission(mission)
        except ChannelTableError as exc:
            problems.append((exc.loc, str(exc)))
        else:
            problems.extend(_frame_problems(mission, table))
    if problems:
        raise located(str(path), marks, problems)
    return LoadedMission(Path(path), mission, table, marks)


def load_mission(path: str | Path) -> LoadedMission:
    """Read and validate the mission file at ``path``."""
    return parse_mission(read_mission_file(path), Path(path))


def _mac_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """Each link's MAC problems, located in its section."""
    if mission.links is None:
        yield from mac_for(mission).problems()
        return
    for link in Network(mission).links:
        for loc, message in mac_for(link.view).problems():
            yield (("links", link.name, *loc), message)


def _frame_problems(mission: Mission, table: ChannelTable) -> Iterable[tuple[Loc, str]]:
    """Frames too small for what every frame carries besides channels."""
    if table.wire_format == "goby":
        yield from goby_problems(table, mission)
    overhead = frame_codec_for(table).overhead_bytes() + table.net_header_bytes
    found: dict[Loc, int] = {}  # where each too-small size is set: once, at that line
    for link in Network(mission).links:
        where: Loc = () if mission.links is None else ("links", link.name)
        for name in link.members:
            frame_bytes = link.view.node_modem(name).frame_bytes
            if frame_bytes <= overhead:
                own = link.view.nodes[name].modem.frame_bytes is not None
                found[(*where, "nodes", name, "modem", "frame_bytes") if own
                      else (*where, "modem", "frame_bytes")] = frame_bytes
    for loc, frame_bytes in found.items():
        yield (loc, f"{frame_bytes} bytes cannot hold the {overhead}-byte frame overhead")
