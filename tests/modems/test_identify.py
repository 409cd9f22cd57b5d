"""Telling which kind of modem a device is from the lines it writes (``zab doctor``, when a
serial modem does not start): each backend knows its own protocol's lines."""

from __future__ import annotations

from bridge.modems.evologics.driver import EvologicsBackend
from bridge.modems.identify import speaker
from bridge.modems.micromodem.driver import MicromodemBackend
from bridge.modems.micromodem.nmea import Sentence, parse_sentence

BACKENDS = {"evologics": EvologicsBackend, "micromodem": MicromodemBackend}


def test_each_backend_speaks_its_own_modem_s_lines_only() -> None:
    micromodem = [b"$CAERR,170222,NMEA,1,Bad sentence*13", b"$CAREV,000040,AUV,2.0.27087*11\r\n",
                  Sentence("SN", "TTA", ("1.5", "", "", "", "120000.00")).encode()]
    evologics = [b"+++AT?MODE:2:AT\r\n", b"OK", b"[*]OK", b"ERROR WRONG FORMAT", b"BUSY BACKOFF",
                 b"SENDEND,2,2048000,160000,0", b"RECVIM,3,1,2,ack,1,2,3,0.1,abc"]
    others = [b"+++AT?MODE", b"$CCCFG,SRC,1*3C", b"$GPGGA,1*00", b"$CAERR,1*00", b"AT?MODE",
              b"\x8f\x0b\xfe\x11 garbage", b""]
    assert [MicromodemBackend.speaks(line) for line in micromodem] == [True] * 3
    assert not any(EvologicsBackend.speaks(line) for line in micromodem)
    assert [EvologicsBackend.speaks(line) for line in evologics] == [True] * 7
    assert not any(MicromodemBackend.speaks(line) for line in evologics)
    assert not any(b.speaks(line) for b in BACKENDS.values() for line in others)


def test_the_first_telling_line_names_the_modem_else_the_first_line_is_shown() -> None:
    lines = [b"\x8f\x0b noise", b"$CAERR,170222,NMEA,1,Bad sentence*13", b"OK"]
    assert speaker(lines, BACKENDS) == ("micromodem", lines[1])
    assert speaker(lines[:1], BACKENDS) == (None, lines[0])
    assert speaker([], BACKENDS) == (None, None)


def test_the_probes_are_each_modem_s_own_harmless_queries() -> None:
    assert EvologicsBackend.probe == b"+++AT?MODE\r"  # what the driver's start-up asks first
    assert MicromodemBackend.probe is not None
    query = parse_sentence(MicromodemBackend.probe)
    assert (query.talker, query.kind, query.fields) == ("CC", "CFQ", ("SRC",))
