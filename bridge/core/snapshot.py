"""A node's counters, channel ages, links and parts as plain data, published as its
``@zab/<mission>/<node>/stats`` and read by ``zab sim``'s report (pure)."""

from __future__ import annotations

from typing import Any

from bridge.core.drops import clamps
from bridge.core.inbound import Inbound
from bridge.core.link import Links
from bridge.core.network import NodeNetwork
from bridge.core.outbound import Outbound
from bridge.core.outputs import NodeStats
from bridge.core.queries import Queries
from bridge.wire.channels import ChannelTable

__all__ = ["snapshot"]


def snapshot(node: str, epoch: int, now: float, stats: NodeStats, out: Outbound,
             inbound: Inbound, links: Links, queries: Queries | None,
             table: ChannelTable, network: NodeNetwork | None = None) -> dict[str, Any]:
    """What ``node``'s parts hold at ``now``, as msgpack-able data (``network``: its links'
    policy and relaying, when it has several links or routes)."""
    return {
        "node": node,
        "time": now,
        "frames_sent": stats.frames_sent,
        "frames_received": stats.frames_received,
        "frames_dropped": dict(stats.frames_dropped),
        "payloads_dropped": dict(stats.payloads_dropped),
        "payload_drop_causes": out.drops.causes(),
        "clamped": {**clamps(out.bindings), **(queries.clamped() if queries else {})},
        "values_published": stats.values_published,
        **({"values_stale": stats.values_stale} if stats.values_stale else {}),
        "send_errors": stats.send_errors,
        "left_out": stats.left_out,
        "channel_age_s": {s.channel.name: s.age(now) for s in out.store.states.values()},
        "received_age_s": {k: now - t for k, t in inbound.received_at.items()},
        "last_heard": dict(links.last_heard),
        "links": {peer: state.value for peer, state in links.states.items()},
        "epoch": epoch,
        "state": out.saving.snapshot(),
        "mismatched_peers": dict(inbound.mismatched),
        "unfinished": {s.channel.name: s.pending() for s in out.senders.values()},
        "sent_per_channel": dict(stats.sent_per_channel), **stats.noticed(),
        **({"queries": queries.snapshot()} if queries else {}),
        **({"surfacing": out.surfacing.snapshot()} if out.surfacing else {}),
        **({"interest": out.interest.snapshot(table)} if out.interest else {}),
        **({"families": out.families.snapshot(now)} if table.names is not None
           or any(c.family for c in table.channels) else {}),
        **({"network": network.snapshot()} if network is not None else {}),
    }
