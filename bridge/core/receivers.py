"""The receiving ends of a node's reliable and fragmented streams, and the acks it owes (pure).

One receiver per (sender, channel), made when its first entry arrives: a
:class:`~bridge.core.reliable.ReliableReceiver` window or a
:class:`~bridge.core.transfer.TransferReceiver`. Every entry heard makes an acknowledgement
owed now and in the next :data:`ACK_REPEATS` frames (acks can be lost); to a node behind a
relay a repeat only rides a frame that goes to that node anyway (each frame relayed for a
repeat alone cost the relay a turn's share: umci_relay's relay fell behind on them); a copy
of a frame taken already, sent again for want of the answer, makes them owed now again
(:meth:`Receivers.again`). Each peer's *epoch* (drawn when it starts without saved state) is
kept here: when it changes, the peer lost its windows, so its receivers and the acks owed to
it start afresh.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

from bridge.core.outputs import Outbox
from bridge.core.reliable import ReliableReceiver
from bridge.core.transfer import TransferReceiver
from bridge.wire.channels import ChannelCodec, ChannelTable

__all__ = ["ACK_REPEATS", "Receivers"]

ACK_REPEATS = 3
"""Frames that carry an acknowledgement after it changed (acks can be lost)."""

Receiver = ReliableReceiver | TransferReceiver


class Receivers:
    """Per (sender, channel) receivers, the acks owed, and each peer's epoch."""

    def __init__(self, table: ChannelTable, outbox: Outbox, state: Mapping[str, Any]) -> None:
        self.table = table
        self.outbox = outbox
        self.peer_epochs: dict[str, int] = dict(state.get("peer_epochs", {}))
        self.by_key: dict[tuple[str, int], Receiver] = {}
        for src, name, saved in state.get("receivers") or ():
            channel = table.by_name(name)
            self.by_key[(src, channel.index)] = (
                TransferReceiver.from_state(channel, saved) if channel.fragmented
                else ReliableReceiver.from_state(saved))
        self._acks: dict[tuple[str, int], None] = {}  # (sender, channel index) owed an ack now
        self._repeats: dict[tuple[str, int], int] = {}  # and in this many more frames
        self._left: dict[tuple[str, int], float] = {}  # when each last went out
        self._streams = {c.index: i for i, c in enumerate(table.streams)}

    def _get(self, src: str, channel: ChannelCodec) -> Receiver:
        key = (src, channel.index)
        receiver = self.by_key.get(key)
        if receiver is None:
            receiver = self.by_key[key] = (TransferReceiver(channel) if channel.fragmented
                                           else ReliableReceiver())
        return receiver

    def entry(self, src: str, channel: ChannelCodec, header: tuple[int, ...],
              values: Any) -> list[Any]:
        """A reliable entry of ``channel`` from ``src``: the values it releases, in order."""
        receiver = self._get(src, channel)
        assert isinstance(receiver, ReliableReceiver)
        seq, lag = header
        delivered = receiver.on_entry(seq, lag, values)
        self._owe(src, channel.index)
        return delivered

    def fragment(self, src: str, channel: ChannelCodec, header: tuple[int, ...],
                 chunk: bytes) -> tuple[bytes | None, dict[str, Any]]:
        """A fragment of ``channel`` from ``src``: the whole payload once complete (else None),
        and the transfer's progress."""
        receiver = self._get(src, channel)
        assert isinstance(receiver, TransferReceiver)
        tid, index, count = header
        data = receiver.on_fragment(tid, index, count, chunk)
        self._owe(src, channel.index)
        return data, receiver.progress()

    def _owe(self, src: str, index: int) -> None:
        self._acks[(src, index)] = None
        self._repeats[(src, index)] = ACK_REPEATS
        self.outbox.unsaved = True

    def again(self, src: str, indices: Iterable[int], sent: float) -> None:
        """A copy of a frame of ``src`` taken already, sent at ``sent``, came again: the
        acknowledgements of its streams ``indices`` are owed now, each unless one went out
        since (the copy's sender could not have heard it: a copy that crossed it asks
        nothing, and an answer to it would cost a relayed frame for nothing)."""
        for index in indices:
            key = (src, index)
            if key in self.by_key and self._left.get(key, -math.inf) < sent:
                self._acks[key] = None

    @property
    def due(self) -> bool:
        """Whether an acknowledgement is owed now (a frame is due at once)."""
        return bool(self._acks)

    def due_to(self) -> set[str]:
        """The senders owed an acknowledgement now."""
        return {src for src, _ in self._acks}

    @property
    def owing(self) -> bool:
        """Whether the next frame carries acknowledgements (owed now, or repeated)."""
        return bool(self._acks or self._repeats)

    def owed_now(self, src: str, index: int) -> bool:
        """Whether the acknowledgement of ``src``'s stream ``index`` changed since it last
        went out (not only a repeat)."""
        return (src, index) in self._acks

    def owed(self) -> list[tuple[str, int]]:
        """The (sender, channel index) pairs to acknowledge, those owed now first."""
        return list({**self._acks, **dict.fromkeys(self._repeats)})

    def ack_bits(self, src: str, index: int) -> int:
        """The acknowledgement entry of ``src``'s stream on channel ``index``."""
        ack_codec = self.table.ack
        assert ack_codec is not None
        receiver = self.by_key[(src, index)]
        if isinstance(receiver, TransferReceiver):
            tid, base, bitmap = receiver.ack()
        else:
            (base, bitmap), tid = receiver.ack(), 0
        return ack_codec.pack(self.table.nodes.index(src), self._streams[index],
                              self.peer_epochs.get(src, 0), tid, base, bitmap)

    def acked(self, keys: Iterable[tuple[str, int]], now: float) -> None:
        """A frame carrying the acknowledgements of ``keys`` left at ``now``."""
        for key in keys:
            self._acks.pop(key, None)
            self._left[key] = now
            left = self._repeats.get(key, 0) - 1
            if left > 0:
                self._repeats[key] = left
            else:
                self._repeats.pop(key, None)

    def epoch(self, src: str, epoch: int) -> int | None:
        """``src``'s frames carry ``epoch``: the epoch it replaces when ``src`` started afresh
        (its windows and the acks owed to it are dropped), else None."""
        known = self.peer_epochs.get(src)
        if known == epoch:
            return None
        self.peer_epochs[src] = epoch
        self.outbox.unsaved = True
        if known is None:
            return None
        for key in [k for k in self.by_key if k[0] == src]:
            del self.by_key[key]
            self._acks.pop(key, None)
            self._repeats.pop(key, None)
            self._left.pop(key, None)
        return known

    def state(self) -> list[list[Any]]:
        return [[src, self.table.channels[index].name, r.state()]
                for (src, index), r in self.by_key.items()]
