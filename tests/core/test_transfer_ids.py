"""Transfer ids wrap at 16: a sender does not give a new transfer the id a receiver holds,
and a receiver given another transfer's fragments under the id it holds starts afresh."""

from __future__ import annotations

from bridge.core.loaded import load_mission
from bridge.core.node import NodeCore
from bridge.core.transfer import TID_MOD, TransferReceiver, TransferSender
from bridge.wire.channels import ChannelCodec
from tests.conftest import MISSIONS


def camera() -> ChannelCodec:
    core = NodeCore(load_mission(MISSIONS / "bluerov_images.yaml"), "rov")
    return next(c for c in core.table.channels if c.name == "camera")


def test_a_new_transfer_skips_the_id_each_receiver_last_acknowledged() -> None:
    channel = camera()
    sender = TransferSender(channel, ["operator"], 2.0)
    sender.offer_bytes(b"a" * 100, 0.0)
    assert sender.current is not None and sender.current.tid == 0
    sender.on_ack("operator", 0, sender.current.count, 0, 1.0)  # finished
    tids = []
    for i in range(TID_MOD):  # a burst: each cancels the one before
        sender.offer_bytes(bytes([i + 1]) * 100, 2.0)
        assert sender.current is not None
        tids.append(sender.current.tid)
    assert 0 not in tids and len(set(tids)) == TID_MOD - 1
    ids = [r.id for r in sender.offer_bytes(b"z" * 100, 3.0) if r.state == "queued"]
    assert ids == [TID_MOD + 1]  # (ids in delivery reports still count every value)
    restored = TransferSender(channel, ["operator"], 2.0)
    restored.restore(sender.state())
    assert restored.holds == {"operator": 0}


def test_a_receiver_starts_afresh_on_other_bytes_under_the_id_it_holds() -> None:
    receiver = TransferReceiver(camera())
    chunk = receiver.channel.chunk_bytes
    assert receiver.on_fragment(3, 0, 3, b"a" * chunk) is None
    assert receiver.on_fragment(3, 1, 3, b"b" * chunk) is None
    assert receiver.on_fragment(3, 1, 3, b"b" * chunk) is None  # a copy: a duplicate
    assert receiver.duplicates == 1
    assert receiver.on_fragment(3, 1, 3, b"x" * chunk) is None  # another transfer's
    assert receiver.cancelled == 1 and receiver.chunks == {1: b"x" * chunk}
    assert receiver.on_fragment(3, 0, 3, b"w" * chunk) is None
    whole = receiver.on_fragment(3, 2, 3, b"y" * chunk)
    assert whole == b"w" * chunk + b"x" * chunk + b"y" * chunk


def test_a_receiver_that_finished_an_id_takes_another_transfer_s_bytes_under_it() -> None:
    receiver = TransferReceiver(camera())
    chunk = receiver.channel.chunk_bytes
    receiver.on_fragment(5, 0, 2, b"a" * chunk)
    assert receiver.on_fragment(5, 1, 2, b"b" * chunk) == b"a" * chunk + b"b" * chunk
    assert receiver.on_fragment(5, 1, 2, b"b" * chunk) is None  # a late copy
    assert receiver.duplicates == 1 and receiver.complete
    assert receiver.on_fragment(5, 0, 2, b"c" * chunk) is None  # a new picture, 16 later
    assert not receiver.complete and receiver.chunks == {0: b"c" * chunk}
    assert receiver.on_fragment(5, 1, 2, b"d" * chunk) == b"c" * chunk + b"d" * chunk
