"""Embedded bit-plane coding of quantised coefficients, every prefix decodable (pure).

Coefficients (integers, in coding order: see :mod:`bridge.image.geometry`) are sent plane by
plane from the top. In each plane the coefficients not yet significant are sorted into three
classes by what the receiver already knows at the plane's start: a significant neighbour in
its band (likely to become significant: sent first), else a significant parent, else neither
(sent last); coefficients significant from earlier planes get their next bit (*refinement*)
between the second and the third class — EBCOT's order of passes, most distortion removed per
bit first.

Each class of each band is a sequence of yes/no significance decisions, mostly no; it goes as
*adaptive run lengths* (the run-length mode of RLGR / JPEG-LS): with parameter ``k``, ``0``
says the next ``2**k`` decisions are all no (``k`` grows), ``1`` and ``k`` bits give the
position of the next yes, then its sign (``k`` shrinks); where fewer than ``2**k`` decisions
are left in the pass, the position goes in truncated binary over those left (a bit or more
less: +0.04 dB at 800 B, grey and colour 320×240, ``bench/image_bench.py``). The bands still
*idle* (nothing significant in them yet) go together, one sequence for each scale, so a
plane that wakes none of them costs a bit a scale, not a bit a band (chroma's many idle
bands cost most). ``k`` starts where one ``0`` covers the sequence's first pass and carries
over from plane to plane for each class and band (or scale of idle bands), a step and a
half lower at each new plane (:data:`PLANE_DROP`: a plane down finds more), so both ends
adapt alike with no side information. Refinement bits and signs go as they are. Everything
is decided for a whole pass from the state at the pass's start, so numpy does the
bookkeeping and Python only walks the run codes (a run of ``0`` at a time: :data:`_COVER`
says how far it reaches; the encoder takes most codes whole from :data:`_CODES`, the
decoder from :data:`_SHORT_CODES`, where enough decisions are left).

A stream cut anywhere decodes to everything before the cut (a run code or a sign cut in
half is dropped), and a corrupt stream decodes to some image of the same shape: the decoder
checks every position it reads against the pass it is in.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from itertools import accumulate

import numpy as np
from numpy.typing import NDArray

from bridge.image.geometry import Geometry

__all__ = ["KMAX", "Planes", "decode_planes", "encode_planes"]

KMAX = 15
"""Largest run parameter: a ``0`` code covers at most 32768 decisions."""
KPMAX = 4 * KMAX + 3
UP, DOWN = 4, 6
"""How the run parameter (in quarters) moves after a run of no (up) and after a yes (down)."""
PLANE_DROP = 6
"""How much lower (in quarters) a sequence's run parameter starts a plane than it ended the
one before: each plane down, a pass finds about twice as many (6, against 0: +0.03 dB at
800 B, grey and colour 320×240, ``bench/image_bench.py``; 4 to 10 give the same)."""
_UP = [min(kp + UP, KPMAX) for kp in range(KPMAX + 1)]  # (tables: the loops' hot path)
_DOWN = [max(kp - DOWN, 0) for kp in range(KPMAX + 1)]
_K = [kp >> 2 for kp in range(KPMAX + 1)]
_STEP = [1 << k for k in _K]

PASSES = (0, 1, None, 2)
"""The order of a plane's passes: the classes by number, None the refinement."""

FIRST_OFFSET = 0.375
"""Where in its interval a coefficient first found significant is put back (its magnitude is
more often near the bottom); refined ones go to the middle."""

Bools = NDArray[np.bool_]
Ints = NDArray[np.int64]


class Truncated(Exception):
    """The stream ended (or went wrong) here: everything before stands."""


class Positions:
    """Sorted coding positions of one class: given outright (``rest`` False), or, for a
    class that holds most of ``0 .. n - 1``, as those it leaves out (never written out:
    finding a pass's positions took a fifth of encode + decode at 3200 B, grey 320×240)."""

    __slots__ = ("at", "n", "rest", "size")

    def __init__(self, at: Ints, n: int, rest: bool) -> None:
        self.at = at  # the positions, or (rest) those left out
        self.n = n
        self.rest = rest
        self.size = n - at.size if rest else at.size

    @classmethod
    def of(cls, mask: Bools) -> Positions:
        """The positions where ``mask`` is set, in the cheaper form."""
        n = mask.size
        if 2 * int(np.count_nonzero(mask)) <= n:
            return cls(np.flatnonzero(mask), n, False)
        return cls(np.flatnonzero(~mask), n, True)

    def ranks(self, positions: Ints) -> Ints:
        """How many of the class lie before each of ``positions`` (a member's place)."""
        before = np.searchsorted(self.at, positions)
        return positions - before if self.rest else before

    def take(self, ranks: Ints) -> Ints:
        """The members at places ``ranks``."""
        if not self.rest:
            return self.at[ranks]
        # the r-th position not left out is r + the number of those left out before it,
        # i.e. of the i-th one left out with at[i] - i <= r
        return ranks + np.searchsorted(self.at - np.arange(self.at.size), ranks, side="right")

    def put(self, array: NDArray[np.int64], value: int) -> None:
        """``array[members] = value``."""
        if not self.rest:
            array[self.at] = value
            return
        kept = array[self.at]
        array[:self.n] = value
        array[self.at] = kept

    def array(self) -> Ints:
        """The members, written out."""
        if not self.rest:
            return self.at
        mask = np.ones(self.n, dtype=bool)
        mask[self.at] = False
        return np.flatnonzero(mask)


class Context:
    """What the classes of a plane are computed from, kept up to date as coefficients become
    significant: which have a significant neighbour on their canvas, which a significant
    parent (one spare slot at the end takes the marks of neighbours off the canvas)."""

    def __init__(self, geometry: Geometry) -> None:
        self.geometry = geometry
        size = geometry.size + 1
        self.marked = np.zeros(2 * size, dtype=bool)  # near, then under (Geometry.marks)
        self.near = self.marked[:size]
        self.under = self.marked[size:]
        self.busy = np.zeros(len(geometry.bands), dtype=bool)  # bands with a significant one

    def became(self, positions: Ints) -> None:
        """Coefficients at coding ``positions`` became significant."""
        geometry = self.geometry  # (indices as intp: scattering through int32 ones is slower)
        self.marked[geometry.marks.take(positions, 0).astype(np.intp)] = True
        self.busy[geometry.band_of[positions]] = True

    def classes(self, sig: Bools) -> list[Positions]:
        """Coding positions not yet significant, by class: near a significant neighbour,
        under a significant parent, neither."""
        near, under = self.near[:-1], self.under[:-1]
        close = near > sig  # (a > b: a and not b)
        known = near | sig
        far_under = under > known
        np.logical_or(known, under, out=known)
        return [Positions.of(close), Positions.of(far_under),
                Positions.of(np.logical_not(known, out=known))]


@dataclass
class Planes:
    """The receiver's knowledge of every coefficient after a (possibly cut) stream."""

    size: int
    magnitude: Ints = field(init=False)  # known bits
    plane: Ints = field(init=False)  # lowest known bit plane (significant ones)
    negative: Bools = field(init=False)
    significant: Bools = field(init=False)
    refined: Bools = field(init=False)
    below: Ints = field(init=False)  # an insignificant one's magnitude is below 2**below
    threshold: int = 0  # the plane the stream stopped in
    complete: bool = False

    def __post_init__(self) -> None:
        n = self.size
        self.magnitude = np.zeros(n, dtype=np.int64)
        self.plane = np.zeros(n, dtype=np.int64)
        self.negative = np.zeros(n, dtype=bool)
        self.significant = np.zeros(n, dtype=bool)
        self.refined = np.zeros(n, dtype=bool)
        self.below = np.full(n, 62, dtype=np.int64)

    def values(self) -> tuple[Ints, NDArray[np.float64]]:
        """The significant coefficients (coding positions) and their best values (signed, in
        quantiser units); the others' are 0."""
        at = np.flatnonzero(self.significant)
        offset = np.where(self.refined[at], 0.5, FIRST_OFFSET)
        mag = self.magnitude[at] + offset * np.exp2(self.plane[at].astype(np.float64))
        return at, np.where(self.negative[at], -mag, mag)


def _first_kp(length: int) -> int:
    """The run parameter a (class, band) starts with: one ``0`` covers its first pass."""
    return min(4 * max(length - 1, 1).bit_length(), KPMAX)


def _start_kp(ks: dict[tuple[int, int], int], key: tuple[int, int], length: int) -> int:
    """The run parameter a sequence starts a pass of ``length`` decisions with: where the
    plane before left it, :data:`PLANE_DROP` lower (its first pass: :func:`_first_kp`)."""
    kp = ks.get(key)
    return _first_kp(length) if kp is None else max(kp - PLANE_DROP, 0)


def _coverage(kp: int) -> list[int]:
    """How many decisions ``m`` run codes ``0`` in a row cover from run parameter ``kp``, for
    ``m = 0, 1, …`` until more than any pass holds (``2**24``)."""
    out = [0]
    while out[-1] <= 1 << 24:
        out.append(out[-1] + _STEP[kp])
        kp = _UP[kp]
    return out


_COVER = [_coverage(kp) for kp in range(KPMAX + 1)]
_AFTER = [[min(kp + UP * m, KPMAX) for m in range(len(_COVER[kp]))] for kp in range(KPMAX + 1)]
"""The run parameter after ``m`` codes ``0`` from ``kp``."""


def _segments(cut: list[int], busy: list[bool], scales: list[int]) -> list[tuple[int, list[int]]]:
    """A pass's run segments, as (key, bands): each band with something significant on its
    own (keyed by the band), then the idle bands (nothing significant yet) of each scale as
    one (keyed ``-1 - scale``), so that a plane that wakes none of them costs a bit a scale,
    not a bit a band. ``cut``: where each band starts in the pass (bands not in it left out)."""
    out: list[tuple[int, list[int]]] = []
    idle: dict[int, list[int]] = {}
    for b in range(len(cut) - 1):
        if cut[b] == cut[b + 1]:
            continue
        if busy[b]:
            out.append((b, [b]))
        else:
            idle.setdefault(-1 - scales[b], []).append(b)
    out += idle.items()
    return out


def _place(value: int, k: int, left: int) -> str:
    """The bits of a yes's place ``value`` among the next ``2**k`` decisions, or, where only
    ``left`` (fewer) remain in the pass, among those ``left`` (truncated binary: the first
    ``2**b - left`` places take ``b - 1`` bits, the others ``b``, ``b`` the bits of
    ``left - 1``)."""
    if left >= 1 << k:
        return format(value, f"0{k}b") if k else ""
    b = (left - 1).bit_length()
    u = (1 << b) - left
    if value < u:
        return format(value, f"0{b - 1}b") if b > 1 else ""
    return format(value + u, f"0{b}b") if b else ""


def _code(kp: int, gap: int, negative: int, left: int = 1 << 62) -> tuple[str, int, int]:
    """The run codes of ``gap`` decisions no then a yes (``negative``: its sign) from run
    parameter ``kp`` (in quarters: ``k = kp >> 2``) with ``left`` decisions left in the pass,
    the run parameter after them, and the fewest decisions left for which the codes are
    the same (the tables' codes stand where at least that many are left)."""
    m = 0
    covered = 0
    if gap >= _STEP[kp]:  # codes 0 before the one
        m = bisect_right(_COVER[kp], gap) - 1
        covered = _COVER[kp][m]
        gap -= covered
        kp = _AFTER[kp][m]
    k = _K[kp]
    if left - covered >= 1 << k:  # (most: ``1``, ``k`` bits of the place, the sign)
        code = "0" * m + bin((1 << k | gap) << 1 | negative)[2:]
    else:
        code = "0" * m + "1" + _place(gap, k, left - covered) + "01"[negative]
    return code, _DOWN[kp], covered + (1 << k)


SHORT = 64
"""Gaps below this (most of them) take their codes from a table."""
_CODES = [[(piece, after, 2 * need) for piece, after, need in (
    _code(kp, g >> 1, g & 1) for g in range(2 * SHORT))] for kp in range(KPMAX + 1)]
"""Each run parameter's codes, the parameter after them and twice the fewest decisions left
for which they stand, by ``gap << 1 | negative``."""


def _run_encode(out: list[str], yes: list[int], pos: int, length: int, kp: int) -> int:
    """Append the run codes of the decisions ``pos`` up to ``length`` of a pass, whose yes
    are ``yes`` (each ``place << 1 | negative``); ``kp`` is the run parameter in quarters;
    returns the final ``kp``. (Places go doubled, the sign in the low bit, so that the loop
    takes a yes's code from the table at ``yes - 2 * pos`` with nothing to unpack.)"""
    codes, code, append = _CODES, _code, out.append
    at, end, short = pos << 1, length << 1, SHORT << 1
    for v in yes:
        g = v - at
        if g < short:
            piece, after, need = codes[kp][g]
            if end - at < need:
                piece, after, need = code(kp, g >> 1, g & 1, (end - at) >> 1)
        else:
            piece, after, need = code(kp, g >> 1, g & 1, (end - at) >> 1)
        append(piece)
        kp = after
        at = (v | 1) + 1
    pos = at >> 1
    if pos < length:
        m = bisect_left(_COVER[kp], length - pos)
        append("0" * m)
        kp = _AFTER[kp][m]
    return kp


def encode_planes(geometry: Geometry, q: Ints, negative: Bools, top: int,
                  budget_bits: int) -> str:
    """The bit string (``'0'``/``'1'``) of ``q`` (magnitudes, coding order) from plane ``top``
    down, stopping once it holds ``budget_bits`` bits (it may run over: cut it)."""
    size = geometry.size
    sig = np.zeros(size, dtype=bool)
    starts = geometry.band_start
    scales = [band.scale for band in geometry.bands]
    ks: dict[tuple[int, int], int] = {}
    context = Context(geometry)
    parts: list[str] = []
    total = 0
    first = np.frexp(q)[1] - 1  # the plane each coefficient becomes significant in
    for n in range(top, -1, -1):
        new = np.flatnonzero(first == n)
        classes = context.classes(sig)
        was = np.flatnonzero(sig)
        near, under = context.near[new], context.under[new]  # (the new ones' classes)
        np.logical_or(near, under, out=under)
        found = [new[near], new[under ^ near], new[~under]]
        for cls, c in enumerate(PASSES):
            if c is None:  # refinement (no more than the budget still takes)
                if was.size:
                    bits = ((q[was[:budget_bits - total]] >> n) & 1).astype(np.uint8) + 48
                    piece = bits.tobytes().decode("ascii")
                    parts.append(piece)
                    total += len(piece)
                    if total >= budget_bits:
                        return "".join(parts)
                continue
            cand, hit = classes[c], found[c]  # (the pass's new ones: all in it)
            if cand.size == 0:
                continue
            ones_at = cand.ranks(hit)
            cut_at = cand.ranks(starts)
            cut_ones = np.searchsorted(ones_at, cut_at).tolist()
            cut = cut_at.tolist()
            yes_list = (ones_at << 1 | negative[hit]).tolist()
            segments = _segments(cut, context.busy.tolist(), scales)
            sig[hit] = True
            context.became(hit)
            for key_band, bands in segments:
                if len(bands) == 1:  # the band's own positions in the pass
                    b = bands[0]
                    pos, length = cut[b], cut[b + 1]
                    yes = yes_list[cut_ones[b]:cut_ones[b + 1]]
                else:  # the bands one after another, counted from 0
                    pos, length, yes = 0, 0, []
                    for b in bands:
                        shift = (length - cut[b]) << 1
                        yes += [v + shift for v in yes_list[cut_ones[b]:cut_ones[b + 1]]]
                        length += cut[b + 1] - cut[b]
                key = (cls, key_band)
                out: list[str] = []
                ks[key] = _run_encode(out, yes, pos, length, _start_kp(ks, key, length - pos))
                piece = "".join(out)
                parts.append(piece)
                total += len(piece)
                if total >= budget_bits:  # (what the state says past here is never sent)
                    return "".join(parts)
    return "".join(parts)


WINDOW = 8
"""Bits the decoder looks at to take a short code whole from a table."""


def _short_codes(kp: int) -> list[tuple[int, int, int, int, int] | None]:
    """What ``WINDOW`` bits starting with a whole code say from run parameter ``kp``:
    (the code's bits, its ``gap << 1 | negative``, ``gap + 1``, the run parameter after it,
    the fewest decisions left for which it stands), by the bits' value; None where the code
    is longer."""
    table: list[tuple[int, int, int, int, int] | None] = [None] * (1 << WINDOW)
    for gap in range(1 << WINDOW):
        pair = [_code(kp, gap, negative) for negative in (0, 1)]
        size = len(pair[0][0])
        if size > WINDOW:  # (a longer gap takes no fewer bits)
            break
        for negative, (code, after, need) in enumerate(pair):
            first = int(code, 2) << (WINDOW - size)
            table[first:first + (1 << (WINDOW - size))] = [
                (size, gap << 1 | negative, gap + 1, after, need)] * (1 << (WINDOW - size))
    return table


_SHORT_CODES = [_short_codes(kp) for kp in range(KPMAX + 1)]


def _windows(bits: str) -> bytes:
    """The value of the ``WINDOW`` bits from each position of ``bits`` (which goes on
    ``WINDOW`` bits past the last position it is read from), one byte a position."""
    b = np.frombuffer(bits.encode("ascii"), dtype=np.uint8) - 48
    out = np.zeros(len(bits) - WINDOW + 1, dtype=np.uint8)
    for j in range(WINDOW):
        out |= b[j:j + out.size] << (WINDOW - 1 - j)
    return out.tobytes()


def _run_decode(bits: str, windows: bytes, end: int, i: int, pos: int, length: int, kp: int,
                found: list[int]) -> tuple[int, int]:
    """Read the run codes of the decisions ``pos`` up to ``length`` of a pass from
    ``bits[i:end]`` into ``found`` (each yes as ``place << 1 | negative``, as
    :func:`_run_encode` takes them); returns ``(i, kp)`` after them. Raises
    :class:`Truncated` where the bits end or lie. ``bits`` goes on past ``end`` with
    ``WINDOW`` ``1``s (so that a window is whole and the next one always found);
    ``windows``: :func:`_windows` of it."""
    cover, after, down, widths, short = _COVER, _AFTER, _DOWN, _K, _SHORT_CODES
    find, found_one = bits.find, found.append
    while True:
        entry = short[kp][windows[i]]
        if entry is not None:  # a short code, whole in the window
            size, yes, step, next_kp, need = entry
            if pos + need <= length and i + size <= end:
                found_one((pos << 1) + yes)
                pos += step
                kp = next_kp
                i += size
                continue
        j = find("1", i)
        covered = cover[kp]
        m = j - i  # codes 0 before the next 1
        if m >= len(covered) or pos + covered[m] >= length:  # the pass ends first
            m = bisect_left(covered, length - pos)
            if i + m > end:
                raise Truncated
            return i + m, after[kp][m]
        if m:
            pos += covered[m]
            kp = after[kp][m]
            if widths[kp] <= WINDOW - 2:  # the rest may be a short code from the new kp
                i = j
                continue
        k = widths[kp]
        at = j + 1
        left = length - pos
        if left >= 1 << k:
            p = pos + int(bits[at:at + k], 2) if k else pos
            at += k
        else:  # fewer left than 2**k: truncated binary (see _place)
            b = (left - 1).bit_length()
            u = (1 << b) - left
            v = int(bits[at:at + b - 1], 2) if b > 1 else 0
            at += max(b - 1, 0)
            if v >= u and b:
                if at >= end:
                    raise Truncated
                v = (v << 1 | (bits[at] == "1")) - u
                at += 1
            p = pos + v
        i = at + 1
        if i > end:
            raise Truncated
        if p >= length:
            raise Truncated  # corrupt: a position past the pass
        found_one(p << 1 | (bits[i - 1] == "1"))
        pos = p + 1
        kp = down[kp]


def decode_planes(geometry: Geometry, bits: str, top: int) -> Planes:
    """What a (possibly cut) bit string from :func:`encode_planes` tells."""
    state = Planes(geometry.size)
    whole: list[Positions] = []
    low = _read_planes(geometry, bits, top, state, whole)
    state.below[:] = low  # (those still insignificant: below every plane read whole,
    for cand in whole:  # and below the one the stream stopped in if their pass came whole)
        cand.put(state.below, low - 1)
    return state


def _read_planes(geometry: Geometry, bits: str, top: int, state: Planes,
                 whole: list[Positions]) -> int:
    """Read ``bits`` into ``state``; returns the lowest plane read whole (``top + 1``: none),
    leaving in ``whole`` the passes of the next plane that came whole."""
    sig = state.significant
    starts = geometry.band_start
    scales = [band.scale for band in geometry.bands]
    ks: dict[tuple[int, int], int] = {}
    context = Context(geometry)
    i = 0
    end = len(bits)
    padded = bits + "1" * WINDOW
    windows = _windows(padded)
    for n in range(top, -1, -1):
        state.threshold = n
        whole.clear()
        classes = context.classes(sig)
        was = np.flatnonzero(sig)
        for cls, c in enumerate(PASSES):
            if c is None:
                m = min(int(was.size), end - i)
                if m > 0:
                    got = np.frombuffer(bits[i:i + m].encode("ascii"), dtype=np.uint8) == 49
                    idx = was[:m]
                    state.magnitude[idx] |= got.astype(np.int64) << n
                    state.plane[idx] = n
                    state.refined[idx] = True
                    i += m
                if m < was.size:
                    return n + 1
                continue
            cand = classes[c]
            if cand.size == 0:
                continue
            found: list[int] = []  # (place << 1 | negative)
            stop = False
            cut = cand.ranks(starts).tolist()
            for key_band, bands in _segments(cut, context.busy.tolist(), scales):
                key = (cls, key_band)
                if len(bands) == 1:
                    pos, length, heard = cut[bands[0]], cut[bands[0] + 1], found
                else:
                    lengths = [cut[b + 1] - cut[b] for b in bands]
                    pos, length, heard = 0, sum(lengths), []
                try:
                    i, ks[key] = _run_decode(padded, windows, end, i, pos, length,
                                             _start_kp(ks, key, length - pos), heard)
                except Truncated:
                    stop = True
                if heard is not found:  # back from counted-from-0 to the pass's positions
                    ends = list(accumulate(lengths))
                    for v in heard:
                        at = bisect_right(ends, v >> 1)
                        found.append(v + ((cut[bands[at]] - ends[at] + lengths[at]) << 1))
                if stop:
                    break
            if found:
                yes = np.array(found, dtype=np.int64)
                idx = cand.take(yes >> 1)
                sig[idx] = True
                context.became(idx)
                state.magnitude[idx] = 1 << n
                state.plane[idx] = n
                state.negative[idx] = (yes & 1).astype(bool)
            if stop:
                return n + 1
            whole.append(cand)
    state.complete = True
    whole.clear()
    return 0
