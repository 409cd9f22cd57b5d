"""A node's keyspace, the Zenoh side (:mod:`bridge.core.keyspace` decides): a subscriber on
the node's keyspace hands the core every application put there that nothing reads, and a
queryable on each peer's keyspace answers a get that maps to nothing with a reply error
saying so (a get that asks a query or a latched value is left to those), unless a peer's bridge
token is alive on this node's Zenoh: then the get may be answered over IP, and the error would
contradict that answer (the core's own surfacing comes only once the peer has proven itself,
after the join that may carry the get).

In a demand-driven mission a keyspace expression that meets an output key of this node is
not watched (warned at start): the bridge's own subscriber there would count as an
application wanting that channel.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from functools import partial
from typing import Any

import zenoh

from bridge.core.interest import intersects, output_keys
from bridge.core.node import NodeCore
from bridge.runtime.intake import Intake
from bridge.runtime.session import bridged_attachment

log = logging.getLogger("zab.node")


class KeyspaceWatch:
    """Unmapped puts under this node's keyspace; gets under its peers' that map to nothing."""

    def __init__(self, session: zenoh.Session, intake: Intake, core: NodeCore,
                 lock: threading.RLock, clock: Callable[[], float],
                 flush: Callable[[], None], joined: Callable[[], bool]) -> None:
        """``intake``: the node's bounded subscriptions; ``core``, used under ``lock`` at the
        time ``clock`` tells; ``flush``: carry out what the core output (on the loop);
        ``joined``: whether a peer's bridge token is alive on this node's Zenoh (any thread)."""
        self.core, self.lock, self.clock, self.flush = core, lock, clock, flush
        self.joined = joined
        self.intake = intake
        keyspace = self.keyspace = core.outbound.keyspace
        self.entities: list[Any] = []
        outputs = sorted({k for keys in output_keys(core.table, core.node).values()
                          for k in keys}) if core.interest is not None else []
        for expression in keyspace.expressions:
            meets = [k for k in outputs if intersects(expression, k)]
            if meets:
                # (a subscriber there would read as demand for those outputs)
                log.info("%s: keyspace %r is not watched for unmapped puts: it meets output "
                         "keys of this demand-driven node (%s)", core.node, expression,
                         ", ".join(meets))
                continue
            intake.subscribe(expression, partial(self._put, expression))
        for expression in keyspace.peer_keyspaces():
            self.entities.append(session.declare_queryable(expression, self._get))

    def _put(self, expression: str, sample: zenoh.Sample) -> None:
        """The intake's thread: an application's put under the keyspace ``expression``; to
        the core (through the loop, bounded) if nothing reads it."""
        if sample.kind != zenoh.SampleKind.PUT:
            return
        attachment = sample.attachment
        if attachment is not None and bridged_attachment(attachment.to_bytes()):
            return
        key = str(sample.key_expr)
        if not self.keyspace.maps(key):
            self.intake.to_loop(expression, partial(self._unmapped, key))

    def _unmapped(self, key: str) -> None:
        with self.lock:
            self.keyspace.unmapped(key, self.clock())
        self.flush()

    def _get(self, query: zenoh.Query) -> None:
        """Zenoh thread: a get under a peer's keyspace; a reply error if it maps to nothing."""
        why = self.keyspace.unanswered(str(query.key_expr))
        try:
            if why is not None and not self.joined():
                query.reply_err(why.encode())
            query.drop()
        except zenoh.ZError as exc:  # the getter gave up already
            log.debug("query already finished: %s", exc)
