"""Authenticated frames: a counter and a truncated keyed hash, so nobody without the mission key
can forge, alter or replay a frame (pure).

A sealed frame is the plain frame's bytes (without its check value), then::

    counter  32 bits  the low half of a 64-bit counter, strictly increasing per sender
    tag      tag_bytes × 8 bits: HMAC-SHA256(key, "zab-auth/2" ‖ the fingerprint's first two
                      bytes ‖ sender address ‖ 64-bit counter ‖ everything before the tag),
                      truncated

and the usual 16-bit check value last (``bridge.wire.frame``).

The counter never depends on a clock: it counts frames. Its high-water mark survives restarts
through :meth:`Authenticator.state`: a sender *reserves* counters in blocks of
:data:`RESERVE_BLOCK` and the runtime saves that reservation before any frame using it leaves,
so a restarted sender resumes past every counter it may have used. At ten frames a second the
64 bits last 58 billion years. A receiver keeps, per sender, the highest counter it accepted
(saved likewise, before what the frame carried is published) and rebuilds a received counter's
high half from it: the candidate is the first value above that mark with the received low half,
so a sender may run up to 2**31 frames ahead of what a receiver last heard. A frame whose
counter is at or below the mark is refused as replayed — also after either end restarts.

A sender that lost its state counts from 0 again, below every mark its peers hold. A receiver
that refuses a frame whose tag is valid for a counter at or below the mark (a replay, or such a
sender: it cannot tell) owes that sender its mark (:meth:`Authenticator.hints`), which its next
frames carry (``@mark``, :mod:`bridge.wire.marks`); the sender resumes past it
(:meth:`Authenticator.resume_past`) and is heard again. The tag covers only the two bytes of
the fingerprint that the check carries, so that a node with *another* mission file and the same
key can still tell a frame of a key holder from junk (:meth:`Authenticator.vouch`: the mission
mismatch alarm). Why this keeps every replay out: docs/wire-format.md.

With several links or relays a sender's frames may arrive out of order (a frame over RF
overtakes one over acoustics). Such missions give the receiver a *window*: a counter up to
``window - 1`` below the mark is accepted once, as IPsec's anti-replay window does (a bitmap
per sender says which of them arrived; saved with the mark).
"""

from __future__ import annotations

import hashlib
import hmac
from typing import Any

from bridge.errors import FrameError, MissionError

COUNTER_BYTES = 4
"""Bytes of the counter on the wire (its low half)."""
RESERVE_BLOCK = 1 << 10
"""Counters reserved per state write: at most one save per 1024 frames sent."""
_LOW = 1 << (8 * COUNTER_BYTES)
_AHEAD = _LOW // 2  # how far past the receiver's mark a counter may be rebuilt
_MAX = (1 << 64) - 1
AUTH_VERSION = 2
"""2: the tag covers the check's two fingerprint bytes; refused counters are answered with
``@mark``. Part of the mission fingerprint."""
_TAG_PREFIX = b"zab-auth/2"
HINT_REPEATS = 2
"""Frames that carry an ``@mark`` once it is owed (a frame can be lost)."""


class Authenticator:
    """Seals outgoing frames and checks incoming ones for one node.

    ``changed`` turns true whenever :meth:`state` holds something a restart must not lose (a
    new reservation, a newly accepted counter); the runtime saves it and clears the flag.
    """

    def __init__(self, key: bytes, fingerprint: bytes, address: int, tag_bytes: int,
                 state: dict[str, Any] | None = None, window: int = 0) -> None:
        """``window``: counters below a sender's mark still accepted once (0: none)."""
        if len(key) < 16:
            raise MissionError("the frame key must be at least 16 bytes long")
        self._key = key
        self._fingerprint = fingerprint[:2]  # what the check carries, and the tag covers
        self.address = address
        self.tag_bytes = tag_bytes
        state = state or {}
        self.counter = int(state.get("reserved", 0))  # the next counter to use
        self.reserved = self.counter  # counters below this are saved as used
        self.seen: dict[int, int] = {int(k): int(v) for k, v in state.get("seen", {}).items()}
        self.window = window
        self.late: dict[int, int] = {int(k): _bitmap(v) & ((1 << window) - 1)
                                     for k, v in state.get("late", {}).items()}
        """Per sender, bit i set: the counter i below its mark arrived (with a window)."""
        self.changed = False
        self.owed: dict[int, list[int]] = {}
        """Per sender address: the mark its next frames should hear, and in how many frames
        more (:meth:`hints`)."""
        self._answered: dict[int, int] = {}  # per sender: the highest refused counter owed

    @property
    def overhead_bytes(self) -> int:
        return COUNTER_BYTES + self.tag_bytes

    def state(self) -> dict[str, Any]:
        """What must survive a restart: the reservation and the receive window (plain data)."""
        state: dict[str, Any] = {"reserved": self.reserved,
                                 "seen": {str(k): v for k, v in self.seen.items()}}
        if self.window:
            state["late"] = {str(k): v.to_bytes((v.bit_length() + 7) // 8, "big")
                             for k, v in self.late.items()}
        return state

    def _tag(self, src: int, counter: int, data: bytes, fingerprint: bytes | None = None
             ) -> bytes:
        mac = hmac.new(self._key, _TAG_PREFIX + (fingerprint or self._fingerprint)
                       + src.to_bytes(2, "big") + counter.to_bytes(8, "big") + data,
                       hashlib.sha256)
        return mac.digest()[: self.tag_bytes]

    def next_counter(self, cap: int = _MAX) -> int:
        """This node's next counter, reserving a new block (``changed``) when needed: up to
        ``cap`` at most (one at least)."""
        counter = self.counter
        if counter >= _MAX:
            raise FrameError("the 64-bit frame counter is exhausted", "exhausted")
        if counter >= self.reserved:
            self.reserved = max(min(counter + RESERVE_BLOCK, cap, _MAX), counter + 1)
            self.changed = True
        self.counter = counter + 1
        return counter

    def seal(self, frame: bytes, now: float | None = None) -> bytes:
        """``frame`` followed by the low half of this node's next counter and the tag
        (``now``: unused here; :class:`~bridge.wire.seal.Sealer` chooses its key by it)."""
        counter = self.next_counter()
        data = frame + (counter % _LOW).to_bytes(COUNTER_BYTES, "big")
        return data + self._tag(self.address, counter, data)

    def open(self, sealed: bytes, src: int, now: float | None = None) -> bytes:
        """The frame inside ``sealed`` from ``src``; FrameError if forged, altered or replayed
        (``now``: as for :meth:`seal`)."""
        if len(sealed) < self.overhead_bytes:
            raise FrameError("truncated frame: no room for the counter and tag")
        data, tag = sealed[: -self.tag_bytes], sealed[-self.tag_bytes:]
        low = int.from_bytes(data[-COUNTER_BYTES:], "big")
        mark = self.seen.get(src, -1)
        counter = (mark + 1) + ((low - (mark + 1)) % _LOW)  # first value past the mark
        if counter - mark <= _AHEAD and hmac.compare_digest(tag, self._tag(src, counter, data)):
            self._accepted(src, counter)
            return data[:-COUNTER_BYTES]
        behind = counter - _LOW
        if behind >= 0 and hmac.compare_digest(tag, self._tag(src, behind, data)):
            if (refused := self._behind(src, behind, mark)) is not None:
                raise refused
            return data[:-COUNTER_BYTES]
        raise FrameError("forged or altered frame: the authentication tag does not match",
                         "forged")

    def _accepted(self, src: int, counter: int) -> None:
        """A frame of ``src`` sealed with ``counter`` opened: its mark moves there."""
        if self.window:  # (the window moves with the mark)
            moved = counter - self.seen.get(src, counter - self.window)
            late = self.late.get(src, 0) << moved if moved < self.window else 0
            self.late[src] = (late | 1) & ((1 << self.window) - 1)
        self.seen[src] = counter
        self.changed = True
        if self._answered:
            self._answered.pop(src, None)

    def _behind(self, src: int, behind: int, mark: int) -> FrameError | None:
        """A frame of ``src`` sealed with ``behind``, at or below ``mark``: accepted (None)
        when a window holds it and it did not come before (overtaken on another link), else
        why it is refused (:meth:`_replayed`)."""
        late, below = self.late.get(src, 0), mark - behind
        if src in self.seen and below < self.window and not late >> below & 1:
            self.late[src] = late | 1 << below
            self.changed = True
            return None
        return self._replayed(src, behind, mark)

    def _replayed(self, src: int, behind: int, mark: int) -> FrameError:
        """Why a frame of ``src`` sealed with ``behind``, at or below ``mark``, is refused
        (``src`` is owed its mark)."""
        self._owe(src, behind, mark)
        return FrameError(f"replayed frame: counter {behind} from {src} is not past {mark} (a "
                          "replay, or a sender restarted without its state: told where to "
                          "resume)", "replayed")

    # -- a sender that lost its state ----------------------------------------------------------

    def _owe(self, src: int, refused: int, mark: int) -> None:
        """``src``'s frame with counter ``refused`` (at or below ``mark``) was refused: owe it
        the mark, unless a refusal of that counter or a later one is owed or answered already
        (a replayer repeating one frame costs one answer)."""
        if refused > self._answered.get(src, -1):
            self._answered[src] = refused
            self.owed[src] = [mark, HINT_REPEATS]

    def hints(self) -> list[tuple[int, int]]:
        """``(sender address, mark)`` for each sender this node's next frame should tell."""
        return [(src, owed[0]) for src, owed in self.owed.items()]

    def hinted(self, src: int) -> None:
        """A frame telling ``src`` its mark left."""
        owed = self.owed.get(src)
        if owed is not None:
            owed[1] -= 1
            if owed[1] <= 0:
                del self.owed[src]

    def resume_past(self, mark: int) -> bool:
        """A peer's ``@mark`` for this node: its counters resume past ``mark`` (a new block is
        reserved, and saved, before the next frame uses it). False: they are past it already."""
        if mark < self.counter or mark >= _MAX:
            return False
        self.counter = mark + 1
        return True

    def vouch(self, sealed: bytes, src: int, fingerprint: int) -> int | None:
        """The counter of ``sealed`` if a holder of the key sealed it, as ``src``, under the
        mission file of 16-bit ``fingerprint`` (another than this node's); None otherwise.

        Its counter's high half is guessed as :meth:`open` rebuilds it, or zero (a node whose
        state belonged to another mission file starts again from 0): three tags at most."""
        if len(sealed) < self.overhead_bytes:
            return None
        data, tag = sealed[: -self.tag_bytes], sealed[-self.tag_bytes:]
        low = int.from_bytes(data[-COUNTER_BYTES:], "big")
        mark = self.seen.get(src, -1)
        past = (mark + 1) + ((low - (mark + 1)) % _LOW)
        theirs = fingerprint.to_bytes(2, "big")
        for counter in dict.fromkeys((low, past, past - _LOW)):
            if counter >= 0 and hmac.compare_digest(tag, self._tag(src, counter, data, theirs)):
                return counter
        return None


def _bitmap(saved: int | bytes) -> int:
    """A saved window's bitmap: bytes, big-endian (an integer in the state of a version
    whose window was 64 bits)."""
    return saved if isinstance(saved, int) else int.from_bytes(saved, "big")
