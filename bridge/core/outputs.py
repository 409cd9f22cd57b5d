"""What a node's core outputs, and the outbox its parts put it in (pure).

:class:`~bridge.core.node.NodeCore` has one way out: :meth:`Outbox.take` gives everything its
parts produced since the last call, in order. An output is a :class:`Publish` (a decoded value
for an application key), a :class:`Status` (bridge state under ``@zab/<mission>/<node>/…``) or
an :class:`~bridge.core.events.Event`. The outbox also keeps the node's counters
(:class:`NodeStats`) and whether what a restart must resume changed since it was last saved.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bridge.core.events import Delivery, Event
from bridge.core.surfacing import Relay
from bridge.frozen import direct_init

if TYPE_CHECKING:
    from bridge.ros2.element import Ros2Element

__all__ = ["NodeStats", "Outbox", "Output", "Publish", "Status"]


@direct_init
@dataclass(frozen=True)
class Publish:
    """Put ``value`` on the application key ``key`` (bridged; latched keys answer queries).

    ``taken``: when the value was taken at the source (the sample's Zenoh timestamp), as
    well as the receiver can tell (:mod:`bridge.wire.sample_meta`); ``delete``: a Zenoh
    delete of ``key`` instead (``value`` None); ``attachment``: the sending application's
    attachment, where the channel carries it; ``src``: the node it came from (None: this
    one's own)."""

    key: str
    value: Any
    encoding: str
    latched: bool = False
    ros2: Ros2Element | None = None  # publish as this ROS 2 topic (CDR, rmw_zenoh attachment)
    taken: float | None = None
    delete: bool = False
    attachment: bytes | None = None
    src: str | None = None


@direct_init
@dataclass(frozen=True)
class Status:
    """Publish ``payload`` (msgpack) on ``@zab/<mission>/<node>/<topic>``."""

    topic: str
    payload: dict[str, Any]


Output = Publish | Status | Event | Relay
"""What a core's parts output: values, status, events, and a surfaced peer's relays (its
queries add what they ask of the runtime and answer: :data:`bridge.core.node.Taken`)."""


@dataclass
class NodeStats:
    """Counters of one node, published on ``@zab/<mission>/<node>/stats``."""

    frames_sent: int = 0
    frames_received: int = 0
    frames_dropped: Counter[str] = field(default_factory=Counter)
    payloads_dropped: Counter[str] = field(default_factory=Counter)
    values_published: int = 0
    values_stale: int = 0  # latest values older than one published already: not published
    send_errors: int = 0
    left_out: int = 0
    sent_per_channel: Counter[str] = field(default_factory=Counter)
    received_per_channel: Counter[str] = field(default_factory=Counter)
    fields_left_out: Counter[str] = field(default_factory=Counter)  # samples, per input key
    unmapped_keys: Counter[str] = field(default_factory=Counter)  # puts no channel reads

    def noticed(self) -> dict[str, dict[str, int]]:
        """The counters of what applications put that does not cross (when there is any)."""
        return {name: dict(counter) for name, counter in (
            ("fields_left_out", self.fields_left_out), ("unmapped_keys", self.unmapped_keys))
            if counter}


class Outbox:
    """Outputs in order, the node's counters, and whether its saved state is behind.

    ``kinds``: the output types the runtime carries out (default: all). A :class:`Publish`
    or :class:`Status` of a kind left out is not built at all (counted all the same): a
    virtual-clock run that looks only at events spends ~4 % fewer CPU instructions
    (``zab sim --fast``, 64 nodes × 64 channels, callgrind: 1917M -> 1842M per 120 s)."""

    __slots__ = ("_publishes", "_statuses", "items", "stats", "unsaved")

    def __init__(self, kinds: Collection[type] | None = None) -> None:
        self.items: list[Output] = []
        self.stats = NodeStats()
        self.unsaved = True
        """What a restart must resume changed since the runtime last saved it (a new run's
        epoch, first of all)."""
        wanted = (object,) if kinds is None else tuple(kinds)  # (as isinstance reads them)
        self._publishes = issubclass(Publish, wanted)
        self._statuses = issubclass(Status, wanted)

    def event(self, event: Event) -> None:
        self.items.append(event)

    def status(self, topic: str, payload: dict[str, Any]) -> None:
        if self._statuses:
            self.items.append(Status(topic, payload))

    def publish(self, key: str, value: Any, encoding: str, latched: bool,
                ros2: Ros2Element | None = None, taken: float | None = None,
                delete: bool = False, attachment: bytes | None = None,
                src: str | None = None) -> None:
        if self._publishes:
            self.items.append(Publish(key, value, encoding, latched, ros2, taken, delete,
                                      attachment, src))
        self.stats.values_published += 1

    def reports(self, reports: list[Delivery], changed: bool = True) -> None:
        """Delivery reports of reliable values: each as status and event (``changed``: what
        they report changed the state, to be saved before they go out)."""
        if reports and changed:
            self.unsaved = True
        for report in reports:
            self.status(f"delivery/{report.channel}", report.to_dict())
            self.event(report)

    def take(self) -> list[Output]:
        """Everything put here since the last call, in order."""
        out, self.items = self.items, []
        return out
