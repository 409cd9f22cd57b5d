"""Per-hop retransmission of reliable values across relays (pure): a relay keeps each frame
it carries on that holds reliable entries (and an origin its own such frame, for its first
hop), and sends it again on its next hop until that hop is seen to have it (link-layer ARQ,
as DTN custody transfer), so a loss on the third hop is repaired by the third hop's sender,
not by the origin three hops away. Which frames are kept, and the copies' bytes, are
:mod:`bridge.core.routing`'s (a hop's sender keeps only where it hears the answer:
:func:`~bridge.core.routing.overhears`).

No byte is added to the air: what releases a kept frame is what the relay hears anyway.

- *The hop carried it on*: the relay hears its next hop send the same routed frame (the
  origin's number) one hop further (on a shared medium a relay hears its neighbour's turns).
- *The destination acknowledged it*: an acknowledgement of the destination for the origin's
  stream, heard by the relay (it carries it back, or overhears it), covers every reliable
  entry the frame holds for it. This releases the last hop, and any relay whose next hop
  forwarded unheard.
- *A bound*: :data:`HOP_COPIES` copies after the first, the frame's life (the header's), at
  most :data:`KEPT_MAX` frames per link (the oldest is let go).

A kept frame is due again once its next hop has been heard since the copy could reach it and
its answer come back (the hop had its turn and did not carry it on: the copy was lost), or
after the hop's worst-case round trip when nothing is heard of it at all. The end-to-end
acknowledgement stays the final word to the origin: its reliable sender still retries on its
own timer (:mod:`bridge.core.reliable`); a copy the next hop has taken already is dropped there
as a duplicate (:mod:`bridge.core.routing`), so it is never delivered twice.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from bridge.core.reliable import seq_after
from bridge.wire.channels import WINDOW

__all__ = ["HOP_COPIES", "KEPT_MAX", "Custody", "Kept"]

HOP_COPIES = 4
"""Copies a relay sends of a kept frame after the first (at 20 % loss a hop, all five lost
one time in 3000)."""
KEPT_MAX = 16
"""Frames a relay keeps for resending per link at most (its queue of frames to carry is
bounded apart: :data:`~bridge.core.routing.CARRIED_KEPT`)."""


class Frame(Protocol):
    """What custody needs of a carried frame (:class:`~bridge.core.routing.Carried`)."""

    def expires(self) -> float: ...


F = TypeVar("F", bound=Frame)


@dataclass(eq=False)
class Kept(Generic[F]):
    """A carried frame kept until its next hop has it."""

    frame: F
    link: str
    hop: str
    origin: str
    seq: int
    """The origin's routed-frame number (what a forward by the next hop carries)."""
    owed: dict[str, set[tuple[int, int]]]
    """Per destination, the (channel index, seq) of the reliable entries it has not
    acknowledged yet."""
    sent: float | None = None
    copies: int = 0
    waiting: bool = True
    """In the link's queue of frames to carry (not sent since it was last put there)."""


class Custody(Generic[F]):
    """The frames a relay keeps until their next hop has them, per link."""

    def __init__(self, answer_s: Mapping[str, float], round_trip_s: Mapping[str, float]
                 ) -> None:
        """Per neighbour: ``answer_s``, how long after a copy leaves a frame of it heard can
        answer it (the copy's frame time there and the answer's back); ``round_trip_s``, how
        long the relay waits for it when it is not heard at all."""
        self.answer_s = dict(answer_s)
        self.round_trip_s = dict(round_trip_s)
        self.kept: dict[str, list[Kept[F]]] = {}
        self.heard_at: dict[str, float] = {}
        self.resent = self.released = 0
        """Copies sent again; kept frames let go because their next hop had them."""

    def keep(self, frame: F, link: str, hop: str, origin: str, seq: int,
             owed: Mapping[str, Iterable[tuple[int, int]]]) -> None:
        """``frame`` (queued on ``link`` for ``hop``) carries reliable entries of ``origin``:
        ``owed``, per destination it serves, those entries."""
        entries = {d: set(e) for d, e in owed.items() if e}
        if not entries:
            return
        kept = self.kept.setdefault(link, [])
        kept.append(Kept(frame, link, hop, origin, seq, entries))
        if len(kept) > KEPT_MAX:
            del kept[0]

    def _find(self, frame: F) -> Kept[F] | None:
        for kept in self.kept.values():
            for item in kept:
                if item.frame is frame:
                    return item
        return None

    def sent(self, frame: F, now: float) -> None:
        """``frame`` went out (a first copy or another)."""
        item = self._find(frame)
        if item is None:
            return
        if item.sent is not None:
            self.resent += 1
        item.sent, item.waiting = now, False
        item.copies += 1

    def forget(self, frame: F) -> None:
        """``frame`` left the relay's queue unsent (expired, or the queue was full)."""
        item = self._find(frame)
        if item is not None:
            self.kept[item.link].remove(item)

    def heard(self, src: str, now: float) -> None:
        """A frame of neighbour ``src`` was heard."""
        self.heard_at[src] = now

    def forwarded(self, src: str, origin: str, seq: int) -> None:
        """Neighbour ``src`` sent on the routed frame ``seq`` of ``origin``: kept for it,
        that frame is released."""
        for kept in self.kept.values():
            for item in [k for k in kept if k.hop == src and k.origin == origin
                         and k.seq == seq]:
                self._release(item)

    def acked(self, dest: str, origin: str, channel: int, base: int, bitmap: int) -> None:
        """``dest``'s acknowledgement of ``origin``'s stream on ``channel`` (its ``base`` and
        ``bitmap``): the entries it covers are owed no more; a frame owed nothing is released."""
        for kept in self.kept.values():
            for item in [k for k in kept if k.origin == origin and dest in k.owed]:
                owed = item.owed[dest]
                for entry in [e for e in owed if e[0] == channel and _covers(base, bitmap,
                                                                            e[1])]:
                    owed.discard(entry)
                if not owed:
                    del item.owed[dest]
                if not item.owed:
                    self._release(item)

    def _release(self, item: Kept[F]) -> None:
        self.kept[item.link].remove(item)
        self.released += 1

    def due_at(self, item: Kept[F]) -> float | None:
        """When ``item`` goes again (None: it waits in the queue already, or is spent)."""
        if item.waiting or item.sent is None or item.copies > HOP_COPIES:
            return None
        heard = self.heard_at.get(item.hop)
        if heard is not None and heard >= item.sent + self.answer_s.get(item.hop, 0.0):
            return heard  # the hop had its turn since, and did not carry it on
        return item.sent + self.round_trip_s.get(item.hop, 0.0)

    def due(self, link: str, now: float) -> list[F]:
        """The kept frames of ``link`` to put in its queue again now (each marked waiting);
        those spent or past their life are let go."""
        out = []
        kept = self.kept.get(link, [])
        for item in list(kept):
            if item.frame.expires() < now or (not item.waiting
                                              and item.copies > HOP_COPIES):
                kept.remove(item)
                continue
            at = self.due_at(item)
            if at is not None and at <= now + 1e-9:
                item.waiting = True
                out.append(item.frame)
        return out

    def next_time(self, link: str) -> float | None:
        """When a kept frame of ``link`` is next due again (None: none is)."""
        times = [t for item in self.kept.get(link, ()) if (t := self.due_at(item)) is not None]
        return min(times, default=None)

    def snapshot(self) -> dict[str, object]:
        return {"kept": {link: len(k) for link, k in self.kept.items()},
                "resent": self.resent, "released": self.released}


def _covers(base: int, bitmap: int, seq: int) -> bool:
    """Whether an acknowledgement (``base``, ``bitmap``) shows ``seq`` arrived."""
    d = seq_after(seq, base)
    return d < 0 or (1 <= d <= WINDOW and bool(bitmap >> (d - 1) & 1))
