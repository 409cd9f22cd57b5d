"""What ``none`` and ``aloha`` share (pure): collisions are possible, so ``zab check`` weighs
the load every node offers; and seed 001's ranging rounds may be reserved inside them."""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Iterable
from typing import Any

from bridge.core.mac.base import Loc, Mac, MacReport, Schedule, airtime_share
from bridge.core.mac.ranging import RangingSchedule, ranging_tmax_s
from bridge.core.mac.timing import busy_s
from bridge.mission.model import AlohaMac, NoMac

__all__ = ["RandomAccess"]


class RandomAccess(Mac):
    """A MAC under which nodes send when they have data, ranging rounds reserved inside."""

    model: NoMac | AlohaMac

    @abstractmethod
    def _schedule(self, node: str, seed: int | None) -> Schedule:
        """The schedule without ranging rounds."""

    @abstractmethod
    def _report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        """The report of a node that takes no part in ranging rounds."""

    def schedule(self, node: str, seed: int | None = None) -> Schedule:
        schedule = self._schedule(node, seed)
        slots = self.model.ranging
        if slots is None:
            return schedule
        tmax_s = ranging_tmax_s(self.mission, slots)
        if tmax_s is None:
            raise ValueError("ranging: tmax_s is needed (no modem preset to compute it)")
        return RangingSchedule(schedule, node, slots, tmax_s)

    def problems(self) -> Iterable[tuple[Loc, str]]:
        slots, nodes = self.model.ranging, self.mission.nodes
        if slots is None:
            return
        if slots.requester not in nodes:
            yield (("mac", "ranging", "requester"), f"unknown node {slots.requester!r}")
        for i, anchor in enumerate(slots.anchors):
            if anchor not in nodes:
                yield (("mac", "ranging", "anchors", i), f"unknown node {anchor!r}")
            elif anchor == slots.requester:
                yield (("mac", "ranging", "anchors", i), "the requester cannot answer itself")
            elif anchor in slots.anchors[:i]:
                yield (("mac", "ranging", "anchors", i), f"{anchor!r} is listed twice")
        if all(a in nodes for a in slots.anchors) and \
                ranging_tmax_s(self.mission, slots) is None:
            yield (("mac", "ranging", "tmax_s"), "required: an anchor's modem has no preset to "
                   "compute it from")

    def report(self, node: str, airtime_s: float | None, data_per_s: float) -> MacReport:
        slots = self.model.ranging
        if slots is not None and node in (slots.requester, *slots.anchors):
            role = "ranging requester" if node == slots.requester else "ranging anchor"
            return MacReport(slots.interval_s, airtime_share(airtime_s, 1 / slots.interval_s),
                             f"{role}: one frame per round", turns_per_s=1 / slots.interval_s)
        return self._report(node, airtime_s, data_per_s)

    def check(self, nodes: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
        data: dict[str, Any] = {}
        warnings: list[str] = []
        shares = [n["mac"]["airtime_share"] for n in nodes if n["mac"]["random_access"]]
        if shares and all(x is not None for x in shares):
            load = sum(shares)
            data["offered_load"] = round(load, 4)
            if load > 0.18 and len(shares) > 1:
                warnings.append(
                    f"{self.model.type}: every node at full rate offers a load G = {load:.2f} "
                    "of the channel; pure ALOHA delivers at most G·e^(-2G) "
                    f"({load * math.exp(-2 * load):.0%} of the time carries a good frame)")
        slots = self.model.ranging
        if slots is None:
            return data, warnings
        tmax_s = ranging_tmax_s(self.mission, slots)
        data["ranging_tmax_s"] = None if tmax_s is None else round(tmax_s, 4)
        if tmax_s is not None:
            round_s = (len(slots.anchors) + 1) * tmax_s
            data["ranging_round_s"] = round(round_s, 4)
            if round_s > slots.interval_s:
                warnings.append(
                    f"ranging: a round lasts up to {round_s:.2f} s, longer than "
                    f"interval_s {slots.interval_s:g} s: requests follow rounds")
            for anchor in slots.anchors:
                busy = busy_s(self.mission, anchor)
                if busy is not None and busy > tmax_s:
                    warnings.append(
                        f"ranging: {anchor}'s largest frame keeps its modem busy "
                        f"{busy:.3f} s, more than one turn (tmax_s {tmax_s:.3f} s)")
        return data, warnings
