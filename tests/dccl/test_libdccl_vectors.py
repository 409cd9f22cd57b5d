"""zab against libdccl itself: every vector in ``../shared/reference/dccl-vectors/``.

The vectors were produced by libdccl (GobySoft/dccl 4.2.0+3) in two builds, its release numeric
rule and the 2026 one (see the folder's README), for DCCL's own test messages, restated in
``protos/libdccl/``. For every message type and both rules: the sizes libdccl reports, the
non-strict and strict encoding of every value (or the refusal), the decoding of libdccl's own
bytes, and libdccl's outcome on every bad buffer (value and bytes used, or a refusal).

One divergence is kept on purpose (docs/dccl.md): under the 2026 rule libdccl's 128-bit working
value overflows for a float whose exponent lies far below the minimum's (1e-30 in a ±180
field) and it writes the minimum; zab writes the exact code. Those cases are checked to differ
from libdccl's bytes only by that field set to its minimum.
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path
from typing import Any

import pytest

from bridge.dccl import DcclMessage, DcclRangeError, DcclSchemaError, load_message, load_proto
from bridge.dccl.codecs import EnumCodec, MessageCodec, NumericCodec, RepeatedCodec
from bridge.dccl.numeric import f32
from bridge.errors import DecodeError, EncodeError
from tests.dccl.conftest import PROTOS

INDEPENDENT = True  # pure: xdist may spread the files (the four all_fields files take ~5 s of
# CPU each: 8,500 bad buffers, each refused by the generated decoder and then again by the
# reference path for its message, and every case decoded both ways)
VECTORS = Path(__file__).resolve().parents[2].parent / "shared" / "reference" / "dccl-vectors"
LIBDCCL = PROTOS / "libdccl"
RULES = {"release-4.2": "dccl-4.2", "numeric-2026": "dccl-2026"}
#: upstream test folders whose messages another folder's file already holds
SAME_AS = {"static_methods": "repeated"}
FILES = sorted(VECTORS.glob("*/*.json.gz")) if VECTORS.is_dir() else []
needs_vectors = pytest.mark.skipif(not FILES, reason=f"libdccl's vectors are not at {VECTORS} "
                                   "(CI has ../shared beside the clone)")


def _value(v: Any) -> Any:
    """A vector's value as zab's payload: bytes for ``{"bytes": hex}``, floats for
    ``{"float": "nan"}``."""
    if isinstance(v, dict):
        if set(v) == {"bytes"}:
            return bytes.fromhex(v["bytes"])
        if set(v) == {"float"}:
            return float(v["float"])
        return {k: _value(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_value(x) for x in v]
    return v


def _printed(codec: Any, v: Any) -> Any:
    """A decoded value as the vectors print it: strings and bytes as hex, and an empty list
    (protobuf's unset repeated field) left out."""
    if isinstance(codec, RepeatedCodec):
        return [_printed(codec.element, x) for x in v]
    if isinstance(codec, MessageCodec):
        fields = dict(codec.fields)
        return {k: _printed(fields[k], x) for k, x in v.items() if x != []}
    if isinstance(codec, EnumCodec):
        return v
    if isinstance(v, str):
        return v.encode().hex()
    if isinstance(v, bytes):
        return v.hex()
    return v


def _same(a: Any, b: Any) -> bool:
    """Equal, with floats compared bit for bit (libdccl printed them with 17 digits)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, int | float) and isinstance(b, int | float) and (
            a == b or (math.isnan(a) and math.isnan(b)))
    return type(a) is type(b) and a == b


def _outcome(encode: Any) -> str:
    """Hex, or libdccl's name for the refusal."""
    try:
        return encode().hex()
    except DcclRangeError:
        return "ERR range"
    except EncodeError:
        return "ERR dccl"  # not initialized: a required field missing


def _decompose(x: float, single: bool) -> tuple[int, int]:
    """libdccl's ``decompose_float_format``: integer significand and exponent."""
    if x == 0:
        return 0, 0
    frac, bias = (23, 127) if single else (52, 1023)
    if abs(x) < 2.0 ** (1 - bias):  # subnormal
        return int(math.ldexp(abs(x), bias - 1 + frac)), 1 - bias - frac
    m, e = math.frexp(abs(x))
    return int(math.ldexp(m, frac + 1)), e - frac - 1


def overflows_2026(value: float, lo: float, res: float, single: bool) -> bool:
    """Whether libdccl's 2026 encode shifts a significand out of its working width (128 bits
    for doubles, 64 for floats) when it brings value, minimum and resolution to one exponent."""
    if single:
        value, lo, res = f32(value), f32(lo), f32(res)
    parts = [_decompose(x, single) for x in (value, lo, res)]
    common = min(e for _, e in parts)
    return any((s << (e - common)).bit_length() > (64 if single else 128) for s, e in parts)


def _to_minimum(codec: Any, v: Any) -> Any:
    """``v`` with every in-range float that overflows libdccl's 2026 encode set to its field's
    minimum, which is what libdccl writes for it."""
    if isinstance(codec, RepeatedCodec) and isinstance(v, list):
        return [_to_minimum(codec.element, x) for x in v]
    if isinstance(codec, MessageCodec) and isinstance(v, dict):
        fields = dict(codec.fields)
        return {k: _to_minimum(fields[k], x) if k in fields else x for k, x in v.items()}
    if (isinstance(codec, NumericCodec) and codec.is_float and isinstance(v, float)
            and math.isfinite(v) and codec.in_range(codec.to_wire(v))
            and overflows_2026(v, codec.lo, codec.res, codec.single)):
        return codec.lo
    return v


def _proto_file(vectors: dict[str, Any]) -> Path:
    """The restated ``.proto`` file of a vector file's upstream test folder."""
    folder = vectors["file"].removeprefix("dccl:").removeprefix("dccl_")
    return LIBDCCL / f"{SAME_AS.get(folder, folder)}.proto"


def _message(vectors: dict[str, Any], rule: str) -> DcclMessage:
    proto = load_proto(_proto_file(vectors), [LIBDCCL / "include"])
    return DcclMessage.from_proto(proto, vectors["message"], rule)


def _check_file(path: Path) -> list[str]:
    """Every disagreement with libdccl in one vector file (empty: none)."""
    vectors = json.loads(gzip.decompress(path.read_bytes()))
    rule = RULES[path.parent.name]
    msg = _message(vectors, rule)
    whole = MessageCodec("", True, [*msg.head, *msg.body])
    wrong: list[str] = []
    # libdccl's sizes count its identifier codec's smallest (8 bits) and largest (16) head
    id_min, id_max = (0, 0) if msg.omit_id else (8, 16)
    head = sum(c.max_bits for _, c in msg.head)
    sizes = [(id_min + head + 7) // 8 + (msg.body_min_bits + 7) // 8,
             (id_max + head + 7) // 8 + (msg.body_max_bits + 7) // 8]
    if sizes != vectors["libdccl_sizes"]:
        wrong.append(f"sizes {sizes} != {vectors['libdccl_sizes']}")
    for case in vectors["cases"]:
        value = _value(case["value"])
        for mode, strict in (("libdccl_nonstrict", False), ("libdccl_strict", True)):
            want = case[mode]
            got = _outcome(lambda v=value, s=strict: msg.encode(v, s))
            if got != want and rule == "dccl-2026":  # the kept divergence, and only it
                tiny = _to_minimum(whole, value)
                if tiny != value:
                    got = _outcome(lambda v=tiny, s=strict: msg.encode(v, s))
            if got != want:
                wrong.append(f"{mode} {case['value']}: {got} != {want}")
        if case["libdccl_decoded"] is not None:
            data = bytes.fromhex(case["libdccl_nonstrict"])
            decoded = msg.decode(data)
            if decoded != msg.decode_reference(data)[0]:
                wrong.append(f"fast and reference decode differ on {data.hex()}")
            if not _same(_printed(whole, decoded), case["libdccl_decoded"]):
                wrong.append(f"decode {data.hex()}: {decoded} != {case['libdccl_decoded']}")
    for bad in vectors["bad_buffers"]:
        data = bytes.fromhex(bad["hex"])
        outcome, value, used = bad["libdccl"]
        try:
            got_value, got_used = msg.decode_prefix(data)
        except DecodeError:
            if outcome == "OK":
                wrong.append(f"bad buffer {bad['hex']}: refused, libdccl decodes {value}")
            continue
        if outcome != "OK":  # SHORT: shorter than the head, never given to libdccl
            wrong.append(f"bad buffer {bad['hex']}: decoded, libdccl: {outcome}")
        elif got_used != used or not _same(_printed(whole, got_value), value):
            wrong.append(f"bad buffer {bad['hex']}: {got_value} ({got_used} bytes) != "
                         f"{value} ({used} bytes)")
    return wrong


@needs_vectors
@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name[5:-8]}" for p in FILES])
def test_zab_is_libdccl(path: Path) -> None:
    wrong = _check_file(path)
    assert not wrong, f"{len(wrong)} disagreements, the first: " + "\n".join(wrong[:5])


@needs_vectors
def test_both_builds_are_here() -> None:
    """The same message types in both builds, each one with its .proto restated here."""
    builds = {rule: {p.name for p in FILES if p.parent.name == rule} for rule in RULES}
    assert builds["release-4.2"] == builds["numeric-2026"]
    files = {_proto_file(json.loads(gzip.decompress(p.read_bytes()))) for p in FILES}
    assert [f for f in files if not f.is_file()] == []


@pytest.mark.parametrize(("file", "name", "reason"), [
    ("numeric_bounds", "TooBigNumericMsg", "must fit in a double-precision floating point"),
    ("resolution", "TooBigNumericMsg", "must fit in a double-precision floating point"),
    ("resolution", "NegativeResolutionNumericMsg", "resolution must be greater than 0"),
    ("resolution", "BothResolutionAndPrecisionSetNumericMsg", "at most one of either"),
    ("resolution", "MinNotMultipleOfResolution", "min must be an exact multiple"),
    ("resolution", "MaxNotMultipleOfResolution", "max must be an exact multiple"),
])
def test_libdccl_refuses_these_at_load(file: str, name: str, reason: str) -> None:
    """The messages of DCCL's tests that libdccl's load refuses (no vectors: no codec)."""
    with pytest.raises(DcclSchemaError, match=reason):
        load_message(LIBDCCL / f"{file}.proto", name)


def test_the_kept_divergence_is_the_exact_code() -> None:
    """1e-30 in dccl_numeric_bounds' ±180 field (precision 12): libdccl 2026 overflows and
    writes the minimum (-180); zab writes round(1e-30 / 1e-12) - round(-180 / 1e-12), which
    decodes as 0, and libdccl decodes zab's bytes the same way."""
    msg = load_message(LIBDCCL / "numeric_bounds.proto", "NumericMsg", "dccl-2026")
    value = {"a": 1e-30, "u1": 0, "u2": 0}
    assert overflows_2026(1e-30, -180.0, 1e-12, single=False)
    assert msg.decode(msg.encode(value))["a"] == 0.0
    assert msg.decode(msg.encode({**value, "a": -180.0}))["a"] == -180.0
