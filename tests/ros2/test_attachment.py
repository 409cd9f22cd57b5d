"""The rmw_zenoh attachment, checked against Zenoh's own serializer (zenoh.ext)."""

from __future__ import annotations

import pytest
from zenoh import ZBytes
from zenoh.ext import Int64, UInt8, z_deserialize, z_serialize

from bridge.errors import DecodeError
from bridge.ros2.attachment import ATTACHMENT_SIZE, Attachment, bridge_gid, from_bridge

GID = bytes(range(0xA0, 0xB0))


def test_layout_is_zenoh_ext_serialisation_of_int64_int64_uint8_array() -> None:
    attachment = Attachment(42, 1_700_000_000_123_456_789, GID)
    reference = z_serialize((Int64(42), Int64(1_700_000_000_123_456_789),
                             [UInt8(b) for b in GID])).to_bytes()
    assert attachment.pack() == reference
    assert len(reference) == ATTACHMENT_SIZE == 33
    assert reference[16] == 16  # the array's LEB128 length before the GID


def test_each_side_reads_what_the_other_wrote() -> None:
    data = z_serialize((Int64(-1), Int64(5), [UInt8(b) for b in GID])).to_bytes()
    assert Attachment.unpack(data) == Attachment(-1, 5, GID)
    ours = Attachment(7, 123, GID).pack()
    seq, stamp, gid = z_deserialize(tuple[Int64, Int64, list[UInt8]], ZBytes(ours))
    assert (int(seq), int(stamp), bytes(int(b) for b in gid)) == (7, 123, GID)


@pytest.mark.parametrize("data", [b"", b"\x00" * 32, b"\x00" * 34, b"\x00" * 16 + b"\x0f"
                                  + b"\x00" * 16])
def test_other_shapes_are_refused(data: bytes) -> None:
    with pytest.raises(DecodeError):
        Attachment.unpack(data)


def test_bridge_gids_are_marked_and_stable() -> None:
    gid = bridge_gid("mission", "zab_ship", "token")
    assert len(gid) == 16 and gid == bridge_gid("mission", "zab_ship", "token")
    assert gid != bridge_gid("mission", "zab_auv1", "token")
    assert from_bridge(Attachment(1, 0, gid).pack())
    assert not from_bridge(Attachment(1, 0, GID).pack())
    assert not from_bridge(b"zab/1 lab/a")
