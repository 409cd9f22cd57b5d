"""Water <-> sim modem wire protocol."""

from __future__ import annotations

import asyncio
import struct

import msgpack
import pytest

from bridge.sim.protocol import MAX_MESSAGE_BYTES, MessageReader, ProtocolError, pack, read_message

MSGS = [
    {"t": "hello", "v": 1, "addr": 3, "name": "auv", "pos": [1.0, 2.0, 3.0]},
    {"t": "tx", "id": 1, "data": b"\x00\xff" * 10, "dest": None},
    {"t": "rx", "src": 2, "data": b"x", "time": 1.5, "meta": {"dest": 3}},
]


def test_roundtrip_whole_and_byte_by_byte() -> None:
    wire = b"".join(pack(m) for m in MSGS)
    assert MessageReader().feed(wire) == MSGS
    reader = MessageReader()
    got = [m for i in range(len(wire)) for m in reader.feed(wire[i : i + 1])]
    assert got == MSGS


def test_garbage_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError):
        MessageReader().feed(struct.pack(">I", MAX_MESSAGE_BYTES + 1))
    body = msgpack.packb([1, 2])
    with pytest.raises(ProtocolError):
        MessageReader().feed(struct.pack(">I", len(body)) + body)
    with pytest.raises(ProtocolError, match=r"undecodable message: reserved byte 0xc1 at "
                                            r"offset 0$"):  # (msgpack's own text is empty)
        MessageReader().feed(struct.pack(">I", 1) + b"\xc1")


def test_read_message_from_stream() -> None:
    async def main() -> None:
        reader = asyncio.StreamReader()
        reader.feed_data(pack(MSGS[0]) + pack(MSGS[1])[:3])
        reader.feed_eof()
        assert await read_message(reader) == MSGS[0]
        with pytest.raises(asyncio.IncompleteReadError):
            await read_message(reader)
        empty = asyncio.StreamReader()
        empty.feed_eof()
        assert await read_message(empty) is None

    asyncio.run(main())
