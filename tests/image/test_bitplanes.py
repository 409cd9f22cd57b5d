"""The run codes of one pass: whatever the decisions, the run parameter and the decisions
left, the decoder reads back what the encoder wrote, to the bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bridge.image.bitplanes import (
    KPMAX,
    WINDOW,
    Positions,
    _place,
    _run_decode,
    _run_encode,
    _windows,
)


@given(st.data())
def test_a_pass_of_run_codes_reads_back_exactly(data: st.DataObject) -> None:
    length = data.draw(st.integers(1, 3000))
    start = data.draw(st.integers(0, length - 1))
    ones = sorted(data.draw(st.sets(st.integers(start, length - 1), max_size=40)))
    signs = data.draw(st.lists(st.booleans(), min_size=len(ones), max_size=len(ones)))
    kp = data.draw(st.integers(0, KPMAX))
    yes = [p << 1 | negative for p, negative in zip(ones, signs, strict=True)]
    out: list[str] = []
    kp_after = _run_encode(out, yes, start, length, kp)
    bits = "".join(out)
    padded = bits + "1" * WINDOW
    found: list[int] = []
    end, kp_read = _run_decode(padded, _windows(padded), len(bits), 0, start, length, kp,
                               found)
    heard = ([v >> 1 for v in found], [bool(v & 1) for v in found])
    assert (heard, end, kp_read) == ((ones, signs), len(bits), kp_after)


@given(st.integers(0, 15), st.integers(1, 1 << 16), st.data())
def test_a_place_takes_no_more_bits_than_the_decisions_left_need(
        k: int, left: int, data: st.DataObject) -> None:
    value = data.draw(st.integers(0, min(left, 1 << k) - 1))
    b = (left - 1).bit_length() if left < 1 << k else k
    assert len(_place(value, k, left)) in (max(b - 1, 0), b)


@given(st.lists(st.booleans(), min_size=1, max_size=300), st.data())
def test_a_class_kept_as_what_it_leaves_out_answers_as_one_written_out(
        bits: list[bool], data: st.DataObject) -> None:
    mask = np.array(bits)
    members = np.flatnonzero(mask)
    for positions in (Positions.of(mask), Positions(np.flatnonzero(~mask), mask.size, True),
                      Positions(members, mask.size, False)):
        assert positions.size == members.size
        assert positions.array().tolist() == members.tolist()
        probe = np.array(sorted(data.draw(st.sets(st.integers(0, mask.size)))), dtype=np.int64)
        assert positions.ranks(probe).tolist() == np.searchsorted(members, probe).tolist()
        ranks = np.arange(members.size)
        assert positions.take(ranks).tolist() == members.tolist()
        array = np.arange(mask.size, dtype=np.int64)
        positions.put(array, -1)
        assert array.tolist() == np.where(mask, -1, np.arange(mask.size)).tolist()
