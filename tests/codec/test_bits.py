"""Bit helpers: level counts, byte conversion, writer/reader."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bridge.codec.bits import BitReader, BitWriter, bits_for, bytes_to_int, int_to_bytes
from bridge.errors import DecodeError, EncodeError


def test_bits_for() -> None:
    assert [bits_for(n) for n in (1, 2, 3, 4, 5, 256, 257, 10001)] == [0, 1, 2, 2, 3, 8, 9, 14]
    with pytest.raises(ValueError):
        bits_for(0)


def test_int_to_bytes_pads_low_bits() -> None:
    assert int_to_bytes(0b11, 2) == b"\xc0"
    assert int_to_bytes(0x3FFF, 14) == b"\xff\xfc"
    with pytest.raises(EncodeError):
        int_to_bytes(4, 2)
    with pytest.raises(DecodeError):
        bytes_to_int(b"\xc1", 2)  # non-zero pad bits
    with pytest.raises(DecodeError):
        bytes_to_int(b"\xc0\x00", 2)  # extra byte


@given(st.lists(st.tuples(st.integers(0, 70), st.data()), max_size=10))
def test_writer_reader_round_trip(items: list) -> None:
    writer = BitWriter()
    values = []
    for width, data in items:
        n = data.draw(st.integers(0, (1 << width) - 1))
        writer.write(n, width)
        values.append((n, width))
    reader = BitReader(writer.to_bytes(), writer.bits)
    assert [reader.read(w) for _, w in values] == [n for n, _ in values]
    assert reader.remaining == 0
    with pytest.raises(DecodeError):
        reader.read(1)
