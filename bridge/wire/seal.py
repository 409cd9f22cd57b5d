"""Confidential frames (``wire.auth.encrypt``): the frame's body encrypted and authenticated
with AES-CCM from the ``cryptography`` library, under the mission key (pure).

A sealed frame is::

    [DLBL]      in the clear: 24 bits per foreign node (a receiver ranges before it decrypts)
    counter     32 bits, in the clear: the low half of the sender's 64-bit frame counter
    body        encrypted: everything the unsealed frame holds after the delays (epoch, count,
                entries, padding), the same length
    tag         tag_bytes × 8 bits (CCM's, truncated by the cipher itself: 4 to 16, even)

and the usual 16-bit check value (``bridge.wire.frame``). The cipher's key is HKDF-SHA256 of
the mission key (a label of its own: never the HMAC's key); its 13-byte nonce is the sender's
address (2 bytes), the 64-bit counter and ``zab``, so no two frames of one key share a nonce.
The cleartext header (the delays and the counter) is authenticated with the body, and so are
the two fingerprint bytes the check carries (as the HMAC tag covers them: a node with another
mission file and the key can still tell a key holder's frame from junk, :meth:`Sealer.vouch`):
a changed delay, counter, body or tag, or a frame from another sender address, fails the tag.

The counter, its reservation across restarts, the replay window and the ``@mark`` that tells a
sender refused as replayed where to resume are the :class:`~bridge.wire.auth.Authenticator`'s.
But a sender that starts without its saved state must not count from 0 again (its frames
would reuse nonces before any ``@mark`` came back). So the counter is held to the clock: its
*clock count* is :data:`COUNTS_PER_S` per second since the Unix epoch, and a sender reserves
counters (what a restart with its state resumes past) no further than :data:`LEAD` past it.
Every counter it used is then at most one past the clock count plus ``LEAD`` of when it was
used (more only where it sends over ``COUNTS_PER_S`` frames a second for minutes on end, or
its clock went back), and one that starts without its state starts past its clock count plus
``LEAD``: past every one of them. (Reserving a whole block past the last reservation at each
restart, as the HMAC counter does, ran ahead of the clock by a block a restart: a node killed
and restarted with its state a few times, then started without it, sealed with counters it
had used.) A receiver that holds no counter from a sender accepts one within 2**30 of its own
clock's count (about two years either way). So an encrypted frame never reuses a nonce, even
after a node lost its state, as long as its clock does not go back.

Key rotation: a :class:`KeyRing` names the next key and when it takes over. A sender seals with
the key of its clock; a receiver opens with that key and, within ``overlap_s`` of the switch,
tries the other: frames sealed on either side of the switch are accepted across it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import AESCCM
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from bridge.errors import FrameError, MissionError
from bridge.wire.auth import COUNTER_BYTES, RESERVE_BLOCK, Authenticator
from bridge.wire.channels import ChannelTable
from bridge.wire.frame import DELAY_BYTES

COUNTS_PER_S = 16
"""Counter values per second of clock a sender without saved state starts from: more than
an acoustic modem sends a second, on average, over any stretch."""
LEAD = 4 * RESERVE_BLOCK
"""How far past its clock count a sender reserves counters (4096: over four minutes of
frames beyond ``COUNTS_PER_S`` a second before it saves its state at each frame)."""
FIRST_WINDOW = 1 << 30
"""How far a first counter from a sender may be from the receiver's clock count, either way."""
_LOW = 1 << (8 * COUNTER_BYTES)
_NONCE_TAIL = b"zab"
_INFO = b"zab sealed frames v1"


@dataclass(frozen=True)
class KeyRing:
    """The mission key, and the next one with the time it takes over (seconds since the
    epoch) and how long either side of that both are accepted."""

    current: bytes
    next: bytes | None = None
    switch_at: float | None = None
    overlap_s: float = 600.0

    def keys(self, now: float | None) -> list[bytes]:
        """The keys to try at ``now``: the one in force first."""
        if self.next is None or self.switch_at is None:
            return [self.current]
        order = [self.next, self.current] if now is None or now >= self.switch_at \
            else [self.current, self.next]
        if now is not None and abs(now - self.switch_at) > self.overlap_s:
            return order[:1]
        return order


def cipher_key(key: bytes) -> bytes:
    """The AES-256 key of a mission key."""
    return HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=_INFO).derive(key)


class Sealer(Authenticator):
    """Seals outgoing frames confidential and opens incoming ones, for one node."""

    def __init__(self, keys: KeyRing | bytes, fingerprint: bytes, address: int, tag_bytes: int,
                 clear_bytes: int, state: dict[str, Any] | None = None,
                 window: int = 0) -> None:
        """``clear_bytes``: the frame's leading bytes that stay in the clear (the DLBL
        delays); ``state``: what :meth:`state` saved in a previous run; ``window``: as the
        Authenticator's."""
        ring = keys if isinstance(keys, KeyRing) else KeyRing(keys)
        super().__init__(ring.current, fingerprint, address, tag_bytes, state, window)
        if tag_bytes % 2 or not 4 <= tag_bytes <= 16:
            raise MissionError("an encrypted frame's tag is 4 to 16 bytes, an even number")
        if ring.next is not None and len(ring.next) < 16:
            raise MissionError("the next frame key must be at least 16 bytes long")
        self.ring = ring
        self.clear_bytes = clear_bytes
        self._ciphers = {k: AESCCM(cipher_key(k), tag_length=tag_bytes)
                         for k in (ring.current, ring.next) if k is not None}
        self._resumed = bool(state and state.get("reserved"))

    def _nonce(self, src: int, counter: int) -> bytes:
        return src.to_bytes(2, "big") + counter.to_bytes(8, "big") + _NONCE_TAIL

    def seal(self, frame: bytes, now: float | None = None) -> bytes:
        """``frame`` with everything after its clear header encrypted, the counter's low half
        and the tag."""
        if now is None:
            counter = self.next_counter()
        else:
            top = math.floor(now * COUNTS_PER_S) + LEAD  # (no reservation goes past it)
            if not self._resumed:  # no saved state: past every counter it may have used
                self._resumed = True
                self.counter = self.reserved = max(self.counter, top + 1)
            counter = self.next_counter(cap=top + 1)
        clear = frame[:self.clear_bytes] + (counter % _LOW).to_bytes(COUNTER_BYTES, "big")
        cipher = self._ciphers[self.ring.keys(now)[0]]
        return clear + cipher.encrypt(self._nonce(self.address, counter),
                                      frame[self.clear_bytes:], self._fingerprint + clear)

    def open(self, sealed: bytes, src: int, now: float | None = None) -> bytes:
        """The frame inside ``sealed`` from ``src``, decrypted; FrameError if forged, altered
        or replayed."""
        head = self.clear_bytes + COUNTER_BYTES
        if len(sealed) < head + self.tag_bytes:
            raise FrameError("truncated frame: no room for the counter and tag")
        clear, body = sealed[:head], sealed[head:]
        low = int.from_bytes(clear[-COUNTER_BYTES:], "big")
        mark = self.seen.get(src)
        if mark is None:  # a first frame from src: within reach of this node's clock count
            mark = (math.floor(now) * COUNTS_PER_S if now is not None else 0) - FIRST_WINDOW
        counter = (mark + 1) + ((low - (mark + 1)) % _LOW)  # the first value past the mark
        if counter - mark <= _LOW // 2 and (plain := self._decrypt(src, counter, clear, body,
                                                                   now)) is not None:
            self._accepted(src, counter)
            return clear[:self.clear_bytes] + plain
        behind = counter - _LOW
        if (late := self._decrypt(src, behind, clear, body, now)) is not None:
            if (refused := self._behind(src, behind, mark)) is not None:
                raise refused
            return clear[:self.clear_bytes] + late  # overtaken on another link
        raise FrameError("forged or altered frame: it does not decrypt with the mission key",
                         "forged")

    def vouch(self, sealed: bytes, src: int, fingerprint: int) -> int | None:
        """The counter of ``sealed`` if a holder of the key sealed it, as ``src``, under the
        mission file of 16-bit ``fingerprint`` (another than this node's, its clear header as
        long as this one's); None otherwise. The counter's high half is guessed as
        :meth:`~bridge.wire.auth.Authenticator.vouch` guesses it."""
        head = self.clear_bytes + COUNTER_BYTES
        if len(sealed) < head + self.tag_bytes:
            return None
        clear, body = sealed[:head], sealed[head:]
        low = int.from_bytes(clear[-COUNTER_BYTES:], "big")
        mark = self.seen.get(src, -1)
        past = (mark + 1) + ((low - (mark + 1)) % _LOW)
        theirs = fingerprint.to_bytes(2, "big")
        for counter in dict.fromkeys((low, past, past - _LOW)):
            if self._decrypt(src, counter, clear, body, None, theirs) is not None:
                return counter
        return None

    def _decrypt(self, src: int, counter: int, clear: bytes, body: bytes, now: float | None,
                 fingerprint: bytes | None = None) -> bytes | None:
        """The body decrypted with the first key that opens it, or None."""
        if counter < 0:
            return None
        for key in self.ring.keys(now):
            try:
                return self._ciphers[key].decrypt(self._nonce(src, counter), body,
                                                  (fingerprint or self._fingerprint) + clear)
            except InvalidTag:
                continue
        return None


def frame_authenticator(table: ChannelTable, key: KeyRing | bytes, address: int,
                        state: dict[str, Any] | None = None, window: int = 0
                        ) -> Authenticator:
    """What authenticates the frames of an authenticated mission's node at ``address``: a
    :class:`Sealer` when they are encrypted, else an HMAC
    :class:`~bridge.wire.auth.Authenticator` (which takes no key rotation); ``window``: the
    counters below a sender's mark still accepted once (several links or relays)."""
    if table.sealed:
        clear = DELAY_BYTES * (len(table.nodes) - 1) if table.dlbl else 0
        return Sealer(key, table.fingerprint, address, table.auth_tag_bytes, clear, state,
                      window)
    if isinstance(key, KeyRing):
        key = key.current
    return Authenticator(key, table.fingerprint, address, table.auth_tag_bytes, state, window)
