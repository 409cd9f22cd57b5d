"""The words of ``zab demo``: what each part of the tour is about to show, and the summary.

Pure formatting over the mission and the run's numbers; :mod:`bridge.cli.demo` runs the
fleet and calls these at the right moments. A new part (queries, authentication ...) is its
title in :data:`PARTS`, a method here for its words, and a step in ``demo._story``.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Mapping
from typing import Any

from rich.console import Console
from rich.table import Table
from rich.text import Text

from bridge.cli.rounding import number, significant
from bridge.cli.text import said
from bridge.core.loaded import LoadedMission
from bridge.report.check import check_mission
from bridge.wire.channels import ChannelCodec
from bridge.words import counted

PARTS = {
    "values": "Values crossing the water, quantised",
    "latest": "Latest value, not a queue",
    "command": "A reliable command over a lossy link",
    "fixes": "Position fixes from acoustic ranges",
    "queries": "A Zenoh get across the water",
    "surfacing": "A vehicle surfaces, then dives",
    "pictures": "A picture across the water, refining",
    "relay": "A vehicle reached through another",
    "summary": "Summary",
}


LOSS_WORDS = {
    "loss": "to the tour's random loss",
    "out_of_range": "out of range",
    "range_loss": "faded with distance",
    "half_duplex": "while the receiver was transmitting",
    "collision": "in collisions",
    "bit_errors": "to bit errors",
}
"""The simulated water's causes of a lost frame, in words (the summary's)."""


def get_path(value: Any, path: str) -> Any:
    """The value at dotted ``path`` of a nested mapping (None if absent)."""
    for part in path.split(".") if path else ():
        if not isinstance(value, Mapping):
            return None
        value = value.get(part)
    return value


def quantisation_lines(channel: ChannelCodec, element: int, sent: Any, got: Any) -> list[str]:
    """Per field of one element: the value published, the value delivered, and why they
    differ (the field's bits and step)."""
    lines = []
    for field in channel.elements[element].layout.fields:
        before, after = get_path(sent, field.path), get_path(got, field.path)
        step = getattr(field, "step", None)
        name = field.path or "(value)"
        if isinstance(before, int | float) and isinstance(after, int | float) \
                and not isinstance(before, bool):
            why = counted(field.bits, 'bit') + (f", step {significant(step)}" if step else "")
            lines.append(f"     {name:<10} {number(before, step):>10} → "
                         f"{number(after, step):<10} {why}")
        else:
            lines.append(f"     {name:<10} {before!s:>10} → {after!s:<10} "
                         f"{counted(field.bits, 'bit')}")
    return lines


def turn_waits(loaded: LoadedMission) -> dict[str, float | None]:
    """Each node's longest wait between transmit turns, seconds (from ``zab check``)."""
    return {n["name"]: n["mac"]["worst_interval_s"] for n in check_mission(loaded).data["nodes"]}


SHOWN_TURNS = 6
"""Turns of the slowest node a tour should last to show every part."""


def slow_turns(loaded: LoadedMission, duration: float) -> str | None:
    """What to say when the slowest node's turns come too seldom for a tour of ``duration``
    seconds to show much (a long relay line's 16 s turns in 70 s), else None."""
    waits = {n: w for n, w in turn_waits(loaded).items() if w}
    if not waits:
        return None
    node = max(waits, key=waits.__getitem__)
    enough = SHOWN_TURNS * waits[node]
    if duration >= enough:
        return None
    return (f"{node}'s turn to transmit comes every {waits[node]:g} s, so {duration:.0f} s "
            f"show only a few of its frames; --duration {math.ceil(enough / 60) * 60:.0f} "
            "shows more.")


def short(value: Any) -> str:
    """A value as compact JSON, floats to 3 decimals, cut at 90 characters."""
    def fmt(v: Any) -> Any:
        if isinstance(v, float):
            return round(v, 3)
        if isinstance(v, dict):
            return {k: fmt(x) for k, x in v.items()}
        return v

    text = json.dumps(fmt(value), separators=(", ", ": "), default=str)
    return text if len(text) < 90 else text[:87] + "..."


def range_error_lines(ranges: list[tuple[str, str, float]], still: set[str],
                      cycle_s: float | None) -> list[str]:
    """The summary's words on acoustic ranges, ``(observer, peer, |error|)`` each: a DLBL
    range is two-way, the distance averaged over an exchange that spans up to a TDMA cycle,
    so a pair whose distance changes meanwhile (a vehicle sailing away from a node that
    keeps ``still``) reads off against the distance at its end; a pair moving together is
    what the ranging bench measures."""
    if not ranges:
        return []
    def median(values: list[float]) -> float:
        return sorted(values)[len(values) // 2]

    lines = [f"{counted(len(ranges), 'acoustic range')} measured; median error against the "
             f"simulated distance when each completed {median([e for *_, e in ranges]):.2f} m."]
    moving = [e for a, b, e in ranges if a not in still and b not in still]
    fixed = [e for a, b, e in ranges if (a in still) != (b in still)]
    if moving and fixed:
        span = f"up to {cycle_s:g} s" if cycle_s else "a while"
        lines.append(
            f"  A range is two-way: it averages the distance over an exchange of frames "
            f"({span} apart). Between vehicles sailing in formation the distance changes "
            f"little meanwhile: median {median(moving):.2f} m ({len(moving)} ranges). To "
            f"{', '.join(sorted(still))}, which they sail away from, it changes: median "
            f"{median(fixed):.2f} m ({len(fixed)} ranges); the tracker models that, so "
            "positions do better. With nothing moving, bench/ranging_bench.py measures the "
            "ranging alone: centimetres.")
    return lines


class Tour:
    """Prints the tour's parts in order on ``console``: those of :data:`PARTS` the mission
    has something to show for (:meth:`plan`), numbered as shown."""

    def __init__(self, loaded: LoadedMission, console: Console, duration: float) -> None:
        self.loaded = loaded
        self.console = console
        self.duration = duration
        self.parts = list(PARTS)
        self.shown: list[str] = []

    def plan(self, parts: list[str]) -> None:
        """Show only ``parts`` (names of :data:`PARTS`, kept in its order)."""
        self.parts = [name for name in PARTS if name in parts or name == "summary"]

    def say(self, text: str | Text) -> None:
        """One line as it is (a str is never read as markup: styles come as Text)."""
        self.console.print(text, highlight=False, markup=False, emoji=False)

    def part(self, name: str) -> bool:
        """The heading of a part of the tour; False (and nothing printed) if the plan left
        it out."""
        if name not in self.parts:
            return False
        self.shown.append(name)
        number_ = self.parts.index(name) + 1
        self.console.rule(said((f"{number_}. {PARTS[name]}", "bold")), align="left")
        return True

    def intro(self, changes: list[str]) -> None:
        mission = self.loaded.mission
        self.say(said(("zab demo", "bold"), f": the {mission.mission} fleet, {len(mission.nodes)} "
                 f"vehicles over a simulated ocean, for {self.duration:.0f} s (Ctrl-C ends "
                 "it sooner). Each vehicle runs a Zenoh peer and the bridge; small programs on "
                 "the vehicles publish navigation and status, as yours would."))
        for change in changes:
            self.say(said("  ", (f"for the tour: {change}", "dim")))
        self.say("You will see, in order: " + "; ".join(
            f"{i}. {PARTS[name].lower()}" for i, name in enumerate(self.parts, start=1)) + ".")
        for name, node in mission.nodes.items():
            self.say(f"  {name:>4} ({node.role}) Zenoh endpoint {' '.join(node.zenoh.listen)}")
        slow = slow_turns(self.loaded, self.duration)
        if slow is not None:
            self.say(said("  ", (slow, "dim")))

    def gui(self, url: str | None, surface: str) -> None:
        if url is None:
            return
        self.say(said(("GUI:", "bold"), f" open {url} in a browser to watch the fleet move "
                      f"and send commands from {surface}"))

    def values_intro(self) -> None:
        self.say("A channel squeezes each field into a fixed number of bits, so what arrives "
                 "is the published value rounded to the field's step. First arrivals:")

    def quantised(self, src: str, dst: str, channel: ChannelCodec, element: int, sent: Any,
                  got: Any) -> None:
        key = channel.elements[element].output_key(src, dst)
        self.say(said(f"  {src} → {dst}: ", (key, "bold"),
                      f" ({channel.name}, {counted(channel.bits, 'bit')})"))
        for line in quantisation_lines(channel, element, sent, got):
            self.say(line)

    def families(self, members: Mapping[str, list[str]]) -> None:
        """Key families: the member keys that arrived, each with its own value."""
        if not members:
            return
        self.say("Key families: one channel, a wildcard input; each member crosses with its "
                 "own index and keeps its own key, value and age at the receiver:")
        for name, keys in members.items():
            shown = ", ".join(keys[:4]) + (", ..." if len(keys) > 4 else "")
            self.say(f"  {name}: {counted(len(keys), 'key')} so far: {shown}")

    def latest(self, channel: ChannelCodec, publish_s: float, sender: str,
               wait_s: float | None) -> None:
        turn = f"every {wait_s:g} s" if wait_s else "only now and then"
        if wait_s and wait_s <= publish_s:
            self.say(f"{channel.name} is published every {publish_s:g} s on {sender}, whose "
                     f"turn to transmit comes {turn}. Whenever a turn finds more than one new "
                     "value (its frame full of other channels, a turn missed), the frame "
                     "carries only the newest: the others are superseded, not lost (receivers "
                     "want the latest value, not a backlog).")
            return
        per_turn = f"about {max(1, round(wait_s / publish_s) - 1)}" if wait_s else "several"
        self.say(f"{channel.name} is published every {publish_s:g} s on {sender}, whose turn to "
                 f"transmit comes {turn}: each frame carries the newest value, and the "
                 f"{per_turn} published in between are superseded, not lost (receivers want "
                 "the latest value, not a backlog). So “sent” counts far fewer values than "
                 "were published, by design.")

    def command_sent(self, node: str, key: str, value: Any, destinations: tuple[str, ...],
                     loss: float, report_key: str) -> None:
        who = destinations[0] if len(destinations) == 1 else \
            f"each of {', '.join(destinations)}"
        self.say(said(f"The operator on {node} puts {value} on ", (key, "bold"),
                      f"; the channel is acknowledged, so {node}'s bridge resends it until "
                      f"{who} confirms (the water loses {loss:.0%} of frames). "
                      f"Delivery reports arrive on {report_key}:"))

    def delivery(self, report: Mapping[str, Any], elapsed_s: float) -> None:
        attempts = report.get("attempts")
        tries = f" after {attempts} transmission{'s' if attempts != 1 else ''}" \
            if isinstance(attempts, int) else ""
        reason = f" ({report['reason']})" if report.get("reason") else ""
        self.say(f"  {report.get('state')} to {report.get('dst')}{tries}, "
                 f"{elapsed_s:.1f} s after the put{reason}")

    def command_done(self, states: Mapping[str, str], waiting: list[str]) -> None:
        delivered = sorted(d for d, s in states.items() if s == "delivered")
        failed = sorted(d for d, s in states.items() if s == "failed")
        text = f"delivery report: {len(delivered)} delivered, {len(failed)} failed"
        if waiting:
            text += f", {', '.join(waiting)} still pending when the tour moved on"
        self.say(text)

    def no_command(self) -> None:
        self.say("This mission's surface node sends no acknowledged channel: nothing to show.")

    def fixes_intro(self, anchors: list[str]) -> None:
        self.say(f"Every frame carries DLBL timing, so each vehicle measures its range to the "
                 f"anchors ({', '.join(anchors)}) for free and its bridge publishes a position "
                 "fix on @zab/<mission>/<node>/position:")

    def query_intro(self, asker: str, selector: str, server: str, deadline: float,
                    why: str) -> None:
        self.say(f"An application on {asker} calls a plain Zenoh get({selector!r}); a queryable "
                 f"on {server} (an ordinary Zenoh app) answers it. {asker}'s bridge carries the "
                 f"request in a frame, {server}'s bridge runs the get there and sends the reply "
                 f"back, repeating the request if a frame is lost, for up to {deadline:g} s "
                 f"({why}, from zab check).")

    def query_answered(self, asker: str, selector: str, values: list[Any], errors: list[str],
                       took: float, sends: int | None = None) -> None:
        went = "" if sends is None else \
            f", the request sent {sends} time{'s' if sends != 1 else ''}"
        for value in values:
            self.say(f"  {asker} get {selector} → {short(value)} ({took:.1f} s round "
                     f"trip{went})")
        for error in errors:
            self.say(f"  {asker} get {selector} failed after {took:.1f} s: {error}")
        if not values and not errors:
            self.say(f"  {asker} get {selector}: no reply ({took:.1f} s)")

    def surfacing_intro(self, vehicle: str, surface: str, up_s: float, down_s: float) -> None:
        self.say(f"{vehicle}'s scripted path reaches the surface {up_s:.0f} s into the "
                 f"simulation and dives at {down_s:.0f} s. At the surface its Zenoh joins "
                 f"{surface}'s over WiFi: the bridges see each other's liveliness token and "
                 f"stop carrying {vehicle}'s channels to {surface} acoustically; its "
                 "programs' values reach the surface over IP, unquantised.")

    def switched(self, vehicle: str, surface: str, up: bool, at_s: float) -> None:
        what = ("joined over IP (its bridge token is visible at" if up
                else "dived: its bridge token is gone from")
        self.say(f"  {at_s:5.1f} s  {vehicle} {what} {surface}{')' if up else ''}")

    def over_ip(self, key: str, value: Any, count: int) -> None:
        self.say(f"          {counted(count, 'value')} arrived over IP, e.g. {key} = {value}")

    def acoustic_while_up(self, vehicle: str, sent: Mapping[str, int],
                          destinations: Mapping[str, tuple[str, ...]], published: int,
                          duplicates: int, surface: str) -> None:
        for name, n in sent.items():
            still = ", ".join(destinations[name]) or "nobody"
            self.say(f"          {name}: {counted(n, 'value')} sent acoustically while up "
                     f"(acoustic destinations left: {still})")
        self.say(f"          {counted(published, 'acoustic value')} of {vehicle} published at "
                 f"{surface} while up")
        if duplicates:
            self.say(f"          {surface} dropped "
                     f"{counted(duplicates, 'acoustic copy', 'acoustic copies')} heard anyway "
                     "(the IP copy wins)")

    def acoustic_again(self, key: str, value: Any, after_s: float) -> None:
        self.say(f"          back over the water {after_s:.1f} s after the dive: {key} = "
                 f"{value} (quantised, the latest value: no backlog)")

    def picture_intro(self, camera: str, key: str, receiver: str) -> None:
        self.say(f"As the tour began, a program on {camera} put one JPEG on {key}. {camera}'s "
                 "bridge recoded it into a progressive stream (wavelets, bit planes: every "
                 "prefix decodes) and sends it in fragments below every other channel, a lost "
                 f"one asked for again. {receiver}'s bridge publishes a sharper PNG on {key} "
                 "after each fragment (the GUI's Pictures panel shows it):")

    def picture_refined(self, after_s: float, got: int, budget: int, psnr_estimate: float,
                        final: bool, width: int, height: int) -> None:
        self.say(f"  {after_s:5.1f} s  {got:>4} / {budget} B  {width}×{height}, "
                 f"≈{psnr_estimate:.1f} dB by the stream's own estimate"
                 + (" · complete" if final else ""))

    def relay_intro(self, vehicle: str, surface: str, path: tuple[str, ...],
                    links: tuple[str, ...]) -> None:
        hops = " ".join(f"{a} –{link}→" for a, link in zip(path, links, strict=False))
        self.say(f"{vehicle}'s traffic to {surface} goes through others: {hops} "
                 f"{path[-1]}. Each relay carries {vehicle}'s frame on unchanged in its own "
                 f"turns (authenticated as {vehicle}'s, so it cannot alter it), and "
                 f"{surface}'s bridge takes it as {vehicle}'s.")

    def relayed(self, vehicle: str, surface: str, channel: str, value: Any, via: str,
                hops: int, age_s: int, carried: int) -> None:
        self.say(f"  {surface} got {channel} {value} from {vehicle} through {via} "
                 f"({hops + 1} hops, {age_s} s old on arrival by its header); {via} has "
                 f"carried {carried} frames of others so far")

    def not_seen(self, what: str) -> None:
        self.say(f"  ({what} not seen before the tour moved on)")

    def summary(self, report: Mapping[str, Any], published: Mapping[str, int],
                ranges: list[tuple[str, str, float]], still: set[str],
                cycle_s: float | None) -> None:
        """The run's figures; ``ranges``: (observer, peer, |error|) of each acoustic range,
        ``still``: nodes that do not move, ``cycle_s``: the TDMA cycle."""
        table = Table("channel", "published", "sent in frames", "received", "mean age",
                      "max age")
        for name, c in report["channels"].items():
            aoi = c.get("age_of_information") or {}
            table.add_row(name, str(published.get(name, 0)), str(c["sent"]),
                          str(c["delivered"]),
                          f"{aoi['mean_s']:.1f} s" if aoi else "—",
                          f"{aoi['max_s']:.1f} s" if aoi else "—")
        self.console.print(table)
        self.say("published: values the vehicles' programs put on Zenoh; sent in frames: "
                 "values a bridge carried (the newest at each turn; an acknowledged one "
                 "again until confirmed); received: arrivals at "
                 "all receivers together (one frame reaches several); age: how old the "
                 "latest value at a receiver was, on average and at worst.")
        links = report.get("links") or []
        sent = sum(link["sent"] for link in links)
        causes: Counter[str] = Counter()
        for link in links:
            causes.update(link["lost"])
        lost = sum(causes.values())
        if sent:
            why = ", ".join(f"{n} {LOSS_WORDS.get(cause, cause)}"
                            for cause, n in causes.most_common() if n)
            self.say(f"The water carried {sent} frame copies between vehicles and lost {lost} "
                     f"({lost / sent:.0%}" + (f": {why})." if why else ")."))
        for line in range_error_lines(ranges, still, cycle_s):
            self.say(line)

    def operators(self, asker: str, answered: int, failed: Mapping[str, int],
                  period_s: float) -> None:
        """What the operator's gets in the background came to (after the query part)."""
        if not answered and not failed:
            return
        why = "; ".join(f"{n} {reason}" for reason, n in failed.items())
        self.say(f"After part {self.parts.index('queries') + 1}, an operator on {asker} asked "
                 f"every vehicle every {period_s:g} s: {answered} answered, "
                 f"{sum(failed.values())} failed" + (f" ({why})" if why else "") + ".")

    def late_frames(self, late: Mapping[str, int]) -> None:
        """Frames the simulated modem refused because the bridge asked too late."""
        if not late:
            return
        who = ", ".join(f"{node} {n}" for node, n in sorted(late.items()))
        self.say(f"Frames not sent because this computer was busy ({who}): the bridge asked "
                 "the simulated modem to start them after their moment had passed, and a "
                 "timed modem refuses that, as EvoLogics modems do; their values waited for the "
                 "next turn. On a quieter machine there are none.")
