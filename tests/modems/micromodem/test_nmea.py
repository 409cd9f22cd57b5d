"""NMEA sentences: checksums, parse and format, malformed lines, fuzzing."""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bridge.modems.micromodem.nmea import (
    MAX_SENTENCE_BYTES,
    ChecksumError,
    NmeaError,
    Sentence,
    checksum,
    checksum32,
    parse_sentence,
)
from bridge.modems.micromodem.rates import FDP_RATES, RATES, frame_bytes_for_rate, get_rate

# real lines quoted in the reference (2.1, 2.3): their checksums must verify
REAL = [
    "$CAREV,181807,AUV,2.0.27087*12",
    "$CAREV,181807,COPROC,0.20.0.56*45",
    "$CACFG,SRC,1*33",
    "$CAMPA,1,2*5D",
    "$CAMPR,2,1,0.0101*7C",
    "$CAMUA,1,2,1fab*20",
    "$CATXF,2*56",
    "$CATXF,28*6E",
    "$CCCYC,0,1,2,1,1,1*5B",
    "$CACYC,0,1,2,1,1,1*59",
    "$CADRQ,153026,1,2,1,64,1*47",
    "$CCTXD,1,2,1,48656C6C6F*05",
    "$CCTXD,2,1,1,*7A",
    "$CATXD,1,2,1,5*4D",
    "$CATXP,64*70",
    "$CARXP,1*45",
    "$CARXD,1,2,1,1,48656C6C6F*1C",
    "$CAACK,2,1,1,1*48",
    "$CAMSG,BAD_CRC,4*25",
    "$CAERR,153026,NMEA,1,Unknown command*7D",
    "$CCMPC,1,2*5D",
    "$CAMPC,1,2*5F",
    "$CCCFG,SRC,1*31",
    "$CCCFQ,SRC*3A",
    "$CCCLK,2024,5,1,12,0,1*46",
    "$CCMSC,1,1,0*41",
    "$CCTDP,2,1,0,0,DEADBEEF*6F",
    "$CAXST,7,20250606,230103.000935,3,0,200,5000,25000,1,0,1,0,0,1,5,2,25000*53",
    "$CACMA,2025-03-17T17:16:29.639994,PNG,0,1,56.7,6.62,3,0,0*74",
    "$CARFP,2025-05-29T15:26:07.286444,0,1,0,1,-1,0,0,1;6;0801000700ff,,*01",
]


@pytest.mark.parametrize("line", REAL)
def test_reference_lines_parse_and_format_back(line: str) -> None:
    sentence = parse_sentence(line + "\r\n")
    assert sentence.to_line() == line
    assert parse_sentence(sentence.encode()) == sentence
    assert sentence.encode().endswith(b"\r\n")


def test_checksum_is_upper_case_xor_between_dollar_and_star() -> None:
    assert checksum("CACFG,SRC,1") == "33"
    assert checksum("") == "00"
    assert Sentence("CC", "CFG", ("SRC", "1")).encode() == b"$CCCFG,SRC,1*31\r\n"
    assert Sentence("CC", "CFG", ("SRC", "1")).encode(with_checksum=False) == b"$CCCFG,SRC,1\r\n"


def test_fields_and_name() -> None:
    s = parse_sentence(b"$CADRQ,153026,1,2,1,64,1*47")
    assert (s.talker, s.kind, s.name) == ("CA", "DRQ", "CADRQ")
    assert s.fields == ("153026", "1", "2", "1", "64", "1")
    assert parse_sentence("$CCTXD,2,1,1,").fields == ("2", "1", "1", "")
    assert parse_sentence("$CAREV").fields == ()


def test_checksum_is_optional_on_input() -> None:
    assert parse_sentence("$CCCFG,SRC,1").fields == ("SRC", "1")


def test_a_lower_case_checksum_is_refused_but_hex_data_may_be_lower_case() -> None:
    with pytest.raises(NmeaError, match="lower-case checksum"):
        parse_sentence("$CAMPR,2,1,0.0101*7c")
    assert parse_sentence("$CAMUA,1,2,1fab*20").fields[2] == "1fab"


def test_eight_digit_crc32_is_checked() -> None:
    good = Sentence("CA", "CFG", ("SRC", "1")).to_line(crc32=True)
    assert len(good.rpartition("*")[2]) == 8
    assert parse_sentence(good).fields == ("SRC", "1")
    with pytest.raises(ChecksumError):
        parse_sentence("$CACFG,SRC,1*DEADBEEF")  # any 8 hex digits no longer pass
    with pytest.raises(NmeaError, match="lower-case"):
        parse_sentence(good.lower().replace("$cacfg,src", "$CACFG,SRC"))


@pytest.mark.parametrize("body", ["CACFG,SRC,1", "CAREV,181807,AUV,2.0.27087",
                                  "CARXD,1,2,0,1," + "AB" * 64, "CCTDP,2,1,0,0,DEADBEEF"])
def test_crc32_is_the_one_pyacomms_computes(body: str) -> None:
    """pyacomms 3.1.1 (WHOI's host library) computes the same CRC, minus one bug: its
    ``hex(...)[2:-1]`` (a Python 2 ``L`` strip) drops the last digit, and a leading zero."""
    acomms = pytest.importorskip("acomms.micromodem")
    ours = checksum32(body)
    assert acomms.nmeaChecksum32(body) == ours.lstrip("0")[:-1]


@pytest.mark.parametrize(
    "line",
    [
        "$CACFG,SRC,1*34",  # wrong checksum
        "$CAREV,181807,AUV,2.0.27087*13",
        "$CATXF,2*65",
    ],
)
def test_wrong_checksum(line: str) -> None:
    with pytest.raises(ChecksumError):
        parse_sentence(line)


@pytest.mark.parametrize(
    "line",
    [
        b"",
        b"CACFG,SRC,1*33",  # no $
        b"$CA,1*00",  # talker too short
        b"$cacfg,SRC,1",  # lower-case address
        b"$CACFGXY,1",
        b"$CACFG,SRC,1*3",  # truncated checksum
        b"$CACFG,SRC,1*",
        b"$CACFG,SRC,1*GG",
        b"$CACFG,SR\x00C,1",
        b"$CACFG,\xff",
        b"$CACFG,A$B",
        b"$CACFG,SRC,1*33*33",
        b"$" + b"A" * (MAX_SENTENCE_BYTES + 1),
    ],
)
def test_malformed_lines(line: bytes) -> None:
    with pytest.raises(NmeaError):
        parse_sentence(line)


def test_sentence_rejects_reserved_characters() -> None:
    with pytest.raises(ValueError):
        Sentence("CC", "TXD", ("1,2",))
    with pytest.raises(ValueError):
        Sentence("C", "CTXD")


@given(st.binary(max_size=300))
def test_fuzz_bytes_only_nmea_error(data: bytes) -> None:
    try:
        sentence = parse_sentence(data)
    except NmeaError:
        return
    assert parse_sentence(sentence.encode()) == sentence


@given(st.sampled_from(REAL), st.integers(0, 60), st.integers(0, 255))
def test_fuzz_mutated_real_lines(line: str, pos: int, byte: int) -> None:
    raw = bytearray(line.encode())
    raw[pos % len(raw)] = byte
    with contextlib.suppress(NmeaError):
        parse_sentence(bytes(raw))


@given(st.lists(st.text(alphabet="0123456789ABCDEF.-_ ", max_size=12), max_size=8))
def test_fuzz_format_parse_round_trip(fields: list[str]) -> None:
    s = Sentence("CA", "XYZ", tuple(fields))
    assert parse_sentence(s.encode()) == s


def test_rate_table() -> None:
    assert [frame_bytes_for_rate(r) for r in range(7)] == [32, 192, 192, 512, 512, 2048, 192]
    assert [RATES[r].frame_bytes for r in range(7)] == [32, 64, 64, 256, 256, 256, 32]
    assert [RATES[r].frames for r in range(7)] == [1, 3, 3, 2, 2, 8, 6]
    assert RATES[0].bitrate_bps == 80 and RATES[0].fsk and not RATES[1].fsk
    assert RATES[1].frames_for(65) == 2 and RATES[1].frames_for(1) == 1
    assert sorted(FDP_RATES) == [1, 2, 3, 4, 5, 6]
    for bad in (7, -1, "x", None):
        with pytest.raises(ValueError):
            get_rate(bad)  # type: ignore[arg-type]
