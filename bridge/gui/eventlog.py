"""Lines of the GUI's event log, from the bridge's events and counters (pure).

A node publishes notable events on ``@zab/<mission>/<node>/events``. A node that does not (an
older bridge) still publishes counters on ``.../stats`` every second; their increases become
log lines too, so dropped frames and driver errors show either way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.words import counted

# What a dropped frame's reason means to an operator.
DROP_REASONS = {
    "check": "frame check failed: do the two vehicles load the same mission file?",
    "forged": "authentication tag wrong: another key, or not one of ours",
    "replayed": "replayed frame (old counter)",
    "malformed": "malformed frame",
    "unknown_source": "frame from an unknown modem address",
    "unexpected_sender": "channel from a node that does not send it",
}


@dataclass(frozen=True)
class LogLine:
    """One line of the log: ``level`` is info, warn or error."""

    level: str
    category: str
    text: str


def _drop_text(reason: str) -> str:
    base = reason.split(":", 1)[0].strip()
    meaning = DROP_REASONS.get(base)
    return f"{meaning} ({reason})" if meaning and meaning != reason else meaning or reason


def describe_event(node: str, event: Mapping[str, Any]) -> LogLine | None:
    """The log line of one event published by ``node``; None for kinds shown elsewhere."""
    kind = str(event.get("kind"))
    if kind in ("link", "delivery", "transfer", "range", "position"):
        return None  # the GUI logs these from their own keys, once per change
    if kind == "frame_dropped":
        src = event.get("src")
        origin = f" from {src}" if src else ""
        return LogLine("warn", "frame", f"{node} dropped a frame{origin}: "
                       f"{_drop_text(str(event.get('reason', '?')))}")
    if kind == "payload_drops":
        drops = event.get("drops")
        drops = drops if isinstance(drops, list) else []
        parts = [f"{d.get('count')} on {d.get('key')!s} ({d.get('reason')})"
                 for d in drops[:3] if isinstance(d, Mapping)]
        more = f"; and {len(drops) - 3} more keys or causes" if len(drops) > 3 else ""
        return LogLine("warn", "payload", f"{node} dropped {event.get('total')} payloads: "
                       + "; ".join(parts) + more)
    if kind == "send_failed":
        return LogLine("error", "driver", f"{node}: modem send failed: {event.get('error')}")
    if kind == "modem_down":
        return LogLine("error", "driver", f"{node}: modem unavailable: {event.get('error')} "
                       "(retrying)")
    if kind == "modem_up":
        down, retries = event.get("down_s"), event.get("retries")
        after = f" after {down:.1f} s" if isinstance(down, int | float) else ""
        tries = f" ({counted(retries, 'retry', 'retries')})" if isinstance(retries, int) else ""
        return LogLine("info", "driver", f"{node}: modem back{after}{tries}")
    if kind == "surfaced":  # told by each side, the surface's bridge and the vehicle's
        peer = event.get("peer")
        if event.get("ip"):
            return LogLine("info", kind, f"{node}: {peer} reached over IP (one of them "
                           "surfaced): channels between them no longer cross the water")
        return LogLine("info", kind, f"{node}: {peer} no longer reached over IP (dived): "
                       "channels between them cross the water again")
    if kind == "peer_restarted":
        return LogLine("warn", kind, f"{node}: {event.get('peer')} restarted without its "
                       f"saved state (epoch {event.get('was')} → {event.get('epoch')})")
    if kind == "mission_mismatch":
        return LogLine("error", kind, f"{node}: {event.get('peer')} runs another mission "
                       "file: its frames are not decoded (load the same file on both)")
    if kind == "peer_link":  # issue 29: a peer on one of several links
        state = str(event.get("state"))
        level = {"up": "info", "degraded": "warn"}.get(state, "error")
        return LogLine(level, "link", f"link {node} ↔ {event.get('peer')} over "
                       f"{event.get('link')}: {state}")
    if kind == "link_switched":
        was = event.get("was")
        return LogLine("warn" if event.get("reason") == "failover" else "info", "route",
                       f"{node}: traffic to {event.get('peer')} over {event.get('link')}"
                       + (f" ({event.get('reason')} from {was})" if was else ""))
    if kind == "route_switched":
        return LogLine("warn" if event.get("reason") == "failover" else "info", "route",
                       f"{node}: traffic to {event.get('peer')} through {event.get('via')} "
                       f"({event.get('reason')} from {event.get('was')})")
    extra = {k: v for k, v in event.items() if k not in ("kind", "time", "node", "data")}
    details = ", ".join(f"{k} {v}" for k, v in extra.items())
    return LogLine("info", kind, f"{node}: {kind}" + (f" ({details})" if details else ""))


def link_line(observer: str, peer: str, state: str, silent_s: float | None,
              never_heard: bool = False) -> LogLine:
    """A link changed state."""
    if never_heard and state != "up":  # at the start, before the peer's first turn: no fault
        return LogLine("info", "link", f"link {observer} ↔ {peer}: not heard yet")
    silent = f" (silent {silent_s:.0f} s)" if silent_s is not None and state != "up" else ""
    level = {"up": "info", "degraded": "warn"}.get(state, "error")
    return LogLine(level, "link", f"link {observer} ↔ {peer}: {state}{silent}")


def delivery_line(node: str, report: Mapping[str, Any]) -> LogLine:
    """A reliable value could not be delivered."""
    return LogLine("error", "delivery", f"{node}: delivery of {report.get('channel')} "
                   f"#{report.get('id')} to {report.get('dst')} failed: "
                   f"{report.get('reason') or 'no reason given'}")


def transfer_line(node: str, report: Mapping[str, Any]) -> LogLine | None:
    """A fragmented transfer ended (complete, cancelled or failed); None while under way."""
    state = report.get("state")
    if state not in ("complete", "cancelled", "failed"):
        return None
    level = "info" if state == "complete" else "error"
    return LogLine(level, "transfer", f"{node}: transfer of {report.get('channel')} "
                   f"#{report.get('id')} with {report.get('peer')} {state} "
                   f"({report.get('fragments_done')}/{report.get('fragments_total')} "
                   f"fragments, {report.get('bytes')} B)")


@dataclass
class CounterWatch:
    """Turns increases of one node's stats counters into log lines."""

    node: str
    seen: dict[str, int] = field(default_factory=dict)
    started: bool = False

    def update(self, stats: Mapping[str, Any]) -> list[LogLine]:
        counters: dict[str, int] = {"send_errors": _int(stats.get("send_errors"))}
        for prefix, name in (("drop", "frames_dropped"), ("payload", "payloads_dropped")):
            table = stats.get(name)
            if isinstance(table, Mapping):
                for reason, count in table.items():
                    counters[f"{prefix}:{reason}"] = _int(count)
        lines = []
        if self.started:
            for name, count in counters.items():
                more = count - self.seen.get(name, 0)
                if more > 0:
                    lines.append(self._line(name, more))
        self.seen, self.started = counters, True
        return lines

    def _line(self, name: str, more: int) -> LogLine:
        if name == "send_errors":
            return LogLine("error", "driver",
                           f"{self.node}: {counted(more, 'modem send error')}")
        prefix, _, what = name.partition(":")
        if prefix == "drop":
            return LogLine("warn", "frame",
                           f"{self.node} dropped {counted(more, 'frame')}: {_drop_text(what)}")
        return LogLine("warn", "payload",
                       f"{self.node} dropped {counted(more, 'payload')} on {what}")


def _int(value: Any) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) else 0
