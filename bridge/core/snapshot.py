"""A node's counters and channel ages as plain data, published on
``@zab/<mission>/<node>/stats`` and kept in the mission report (pure)."""

from __future__ import annotations

from typing import Any, Protocol

from bridge.core.drops import clamps
from bridge.core.link import LinkState
from bridge.core.network import NodeNetwork
from bridge.core.outbound import Outbound
from bridge.core.outputs import NodeStats
from bridge.core.queries import Queries
from bridge.wire.channels import ChannelTable

__all__ = ["snapshot"]


class Parts(Protocol):
    """What a snapshot reads of a node (:class:`~bridge.core.node.NodeCore`)."""

    node: str
    stats: NodeStats
    outbound: Outbound
    queries: Queries | None
    network: NodeNetwork | None
    table: ChannelTable
    epoch: int
    received_at: dict[str, float]
    last_heard: dict[str, float]
    link_states: dict[str, LinkState]
    mismatched: dict[str, str]


def snapshot(core: Parts, now: float) -> dict[str, Any]:
    """``core``'s counters and channel ages at ``now``."""
    stats, out, table = core.stats, core.outbound, core.table
    return {
        "node": core.node,
        "time": now,
        "frames_sent": stats.frames_sent,
        "frames_received": stats.frames_received,
        "frames_dropped": dict(stats.frames_dropped),
        "payloads_dropped": dict(stats.payloads_dropped),
        "payload_drop_causes": out.drops.causes(),
        "clamped": clamps(out.bindings),
        "values_published": stats.values_published,
        "send_errors": stats.send_errors,
        "left_out": stats.left_out,
        "channel_age_s": {s.channel.name: s.age(now) for s in out.store.states.values()},
        "received_age_s": {k: now - t for k, t in core.received_at.items()},
        "last_heard": dict(core.last_heard),
        "links": {peer: state.value for peer, state in core.link_states.items()},
        "epoch": core.epoch,
        "state": out.saving.snapshot(),
        "mismatched_peers": dict(core.mismatched),
        "unfinished": {s.channel.name: s.pending() for s in out.senders.values()},
        "sent_per_channel": dict(stats.sent_per_channel),
        **({"queries": core.queries.snapshot()} if core.queries else {}),
        **({"surfacing": out.surfacing.snapshot()} if out.surfacing else {}),
        **({"interest": out.interest.snapshot(table)} if out.interest else {}),
        **({"families": out.families.snapshot(now)} if table.names is not None
           or any(c.family for c in table.channels) else {}),
        **({"network": core.network.snapshot()} if core.network is not None else {}),
    }
