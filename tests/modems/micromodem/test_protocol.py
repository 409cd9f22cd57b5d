"""The host-side Micro-Modem state machine: every sentence type, transfers, fuzzing."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.modems.micromodem import nav
from bridge.modems.micromodem.nav import TravelTimes
from bridge.modems.micromodem.nmea import Sentence, parse_sentence
from bridge.modems.micromodem.protocol import (
    Ack,
    ApiLevel,
    BadSentence,
    Clock,
    ClockReply,
    Config,
    CycleInit,
    DataRequest,
    FdpAck,
    FdpEcho,
    FdpFrame,
    FdpReceived,
    HostProtocol,
    MiniPacket,
    ModemError,
    ModemMessage,
    Packet,
    PacketLost,
    Pinged,
    PingReply,
    PingSent,
    Revision,
    RxData,
    RxStart,
    RxStats,
    Sleep,
    TransferDone,
    TransferFailed,
    TransferState,
    TxData,
    TxFrame,
    TxStart,
    TxStats,
    Unhandled,
    UsblFix,
)
from bridge.modems.protocol import NEED_DATA


def line(text: str) -> bytes:
    """A modem line with its checksum."""
    s = parse_sentence(text)
    return s.encode()


def feed(proto: HostProtocol, data: bytes, how: str = "whole") -> list[object]:
    """Feed ``data`` whole, one byte at a time, or followed by a partial next line."""
    if how == "bytes":
        for i in range(len(data)):
            proto.receive_data(data[i : i + 1])
    elif how == "trailing":
        proto.receive_data(data + b"$CAREV,0000")
    else:
        proto.receive_data(data)
    return list(proto.events())


HOW = ["whole", "bytes", "trailing"]

MM1_CST = ("$CACST,1,153026.0000,0,4105,30,0318,0193,10,00,00,01,01,2,004,004,3,3,3,1,154,09,08,"
           "10,-6,000,0.0,4125000,5000*5B")
MM2_CST = ("$CACST,8,0,20250606230123.348554,06,32767,45,0102,0123,07,00,00,00,00,1,001,000,0,5,"
           "1,0,150,26.0,9.48,-100,-6.48,-01,0.01,51,25000,5000,0,-1,-1,00*4A")
USB2 = ("$CAUSB2,0,2025-05-29T15:26:07.286444,45.5,-10.25,0.0125,2,0.1,0.0,0.2,0.0,0.3,0.0,"
        "0.4,0.0,3")

CASES = [
    ("$CAREV,181807,AUV,2.0.27087*12", Revision("181807", "AUV", "2.0.27087")),
    ("$CAREV,000003,INIT,2.0.27087", Revision("000003", "INIT", "2.0.27087")),
    ("$CACFG,SRC,1*33", Config("SRC", "1")),
    ("$CACYC,0,1,2,1,1,1*59", CycleInit(1, 2, 1, True, 1)),
    ("$CADRQ,153026,1,2,1,64,1*47", DataRequest("153026", 1, 2, True, 64, 1)),
    ("$CATXD,1,2,1,5*4D", TxData(1, 2, True, 5)),
    ("$CATXP,64*70", TxStart(64)),
    ("$CATXF,2*56", TxFrame(2)),
    ("$CARXP,1*45", RxStart(1)),
    ("$CARXD,2,7,0,1,48656c6C6F", RxData(2, 7, False, 1, b"Hello")),
    ("$CAACK,2,1,1,1*48", Ack(2, 1, 1, True)),
    ("$CAMSG,BAD_CRC,4*25", ModemMessage("BAD_CRC", "4")),
    ("$CAERR,153026,NMEA,1,Unknown command*7D", ModemError("153026", "NMEA", "1",
                                                         "Unknown command")),
    ("$CAERR,153026,DATA_TIMEOUT,1", ModemError("153026", "DATA_TIMEOUT", "1", "")),
    ("$CAMPC,1,2*5F", PingSent(1, 2)),
    ("$CAMPA,1,2*5D", Pinged(1, 2)),
    ("$CAMPR,2,1,0.0101*7C", PingReply(2, 1, 0.0101)),
    ("$CAMUC,1,2,1FAB", MiniPacket("echo", 1, 2, 0x1FAB)),
    ("$CAMUA,1,2,1fab*20", MiniPacket("received", 1, 2, 0x1FAB)),
    ("$CAMUR,2,1,0001", MiniPacket("reply", 2, 1, 1)),
    ("$CAMSC,1,1,0", Sleep(1, 1, 0)),
    ("$CACLK,2024,5,1,12,0,1", Clock(("2024", "5", "1", "12", "0", "1"))),
    ("$CAXST,7,20250606,230103.000935,3,0,200,5000,25000,1,0,1,0,0,1,5,2,25000*53",
     TxStats(("7", "20250606", "230103.000935", "3", "0", "200", "5000", "25000", "1", "0",
              "1", "0", "0", "1", "5", "2", "25000"))),
    ("$CACST,8,0,20250606230123.348554,06", RxStats(("8", "0", "20250606230123.348554", "06"))),
    # LBL travel times (goby, pyacomms, libumutil layout [C line]): C and D not heard
    ("$SNTTA,0.1,0.2,,,120000.00", TravelTimes((0.1, 0.2, None, None), "120000.00")),
    # recorded real lines (reference 2.1): MM1's 28-field $CACST, MM2's v8 $CACST and v7 $CAXST
    (MM1_CST, RxStats(tuple(MM1_CST.split("*")[0].split(",")[1:]))),
    (MM2_CST, RxStats(tuple(MM2_CST.split("*")[0].split(",")[1:]))),
    ("$CAXST,7,20250606,230117.336548,3,0,200,5000,25000,1,0,0,0,0,8,5,28,25000*66",
     TxStats(("7", "20250606", "230117.336548", "3", "0", "200", "5000", "25000", "1", "0",
              "0", "0", "0", "8", "5", "28", "25000"))),
    # MM2's FDP ping, recorded real lines (reference 2.1): our echo, heard at 1, 1 answered 0
    ("$CACMD,PNG,0,1,1,0,3*22", PingSent(0, 1)),
    ("$CACMA,2025-03-17T17:16:29.639994,PNG,0,1,56.7,6.62,3,0,0*74", Pinged(0, 1)),
    ("$CACMR,PNR,2025-05-29T15:09:05.461473,1,0,0.001997,6.3,7.65,1,0,*41",
     PingReply(1, 0, 0.001997)),
    # ... and pyacomms' other layouts [C lines]: $CACMA type first (firmware 3.0 on), the reply
    # as $CACMD before 3.0
    ("$CACMA,PNG,2025-03-17T17:16:29.639994,0,1,56.7,6.62,3,0,0", Pinged(0, 1)),
    ("$CACMD,2025-05-29T15:09:05.461473,PNR,1,0,0.0125,6.3,7.65,1,0,0", PingReply(1, 0, 0.0125)),
    # an FDP acknowledgement, pyacomms' layout [C line, hex masks U]: frames 1-3 of packet 12
    ("$CACDR,2025-05-29T15:09:05.461473,12,2,9,-1,00,0007", FdpAck(12, 2, 9, 0, 7)),
    # what this driver has no use for passes as unhandled, not as a bad line [C lines]
    ("$CACMD,RLS,1,2", Unhandled(Sentence("CA", "CMD", ("RLS", "1", "2")))),
    ("$SNPDT,1,1,0,0,2716,1,1,0,0", Unhandled(Sentence("SN", "PDT", (
        "1", "1", "0", "0", "2716", "1", "1", "0", "0")))),
    ("$SNPNT,120000,9000,10,10,2716,10000,0,0,0,1", Unhandled(Sentence("SN", "PNT", (
        "120000", "9000", "10", "10", "2716", "10000", "0", "0", "0", "1")))),
    ("$CAMEC,1,1,5,0,1", Unhandled(Sentence("CA", "MEC", ("1", "1", "5", "0", "1")))),
    ("$CAMER,2,1,6,1,1", Unhandled(Sentence("CA", "MER", ("2", "1", "6", "1", "1")))),
    ("$CARSP,0,2,0", Unhandled(Sentence("CA", "RSP", ("0", "2", "0")))),
    ("$CATFP,0,7,2,1,1,1,0", Unhandled(Sentence("CA", "TFP", ("0", "7", "2", "1", "1", "1",
                                                             "0")))),
    # MM2 FDP: the real $CARFP of a ping (only the modem's own mini-frame: no user data) and
    # constructed lines in the layouts of goby ($CARDP) and pyacomms ($CATDP)
    ("$CARFP,2025-05-29T15:26:07.286444,0,1,0,1,-1,0,0,1;6;0801000700ff,,*01",
     FdpReceived(1, 0, -1, False, (), ())),
    ("$CARDP,2,7,5,0,0,,1;2;BEEF;1;1;01", FdpReceived(2, 7, 5, False, (), (
        FdpFrame(True, b"\xbe\xef"), FdpFrame(True, b"\x01")))),
    ("$CATDP,0,12,7,5,0,0", FdpEcho(0, 12, 7, 5, False)),
    ("$CAMSG,PACKET_TIMEOUT,1", ModemMessage("PACKET_TIMEOUT", "1")),
    ("$CATMS,0,2024-05-01T12:00:01Z", ClockReply("TMS", "2024-05-01T12:00:01Z")),
    ("$CATMQ,2024-05-01T12:00:01.500000Z,RTC,NONE",
     ClockReply("TMQ", "2024-05-01T12:00:01.500000Z", source="RTC,NONE")),
    ("$CAALQ,zab-emulator,11", ApiLevel("zab-emulator", 11)),
    # MM2 USBL, pyacomms' 15-field layout [C line]; nobody heard yet, so no source
    (USB2, UsblFix("2025-05-29T15:26:07.286444", 45.5, -10.25, 0.0125, 2, 3)),
    # the MM2's 8-digit CRC-32 in place of the XOR sum
    (Sentence("CA", "CFG", ("SRC", "1")).to_line(crc32=True), Config("SRC", "1")),
]


@pytest.mark.parametrize("how", HOW)
@pytest.mark.parametrize(("text", "event"), CASES, ids=[c[0][:6] for c in CASES])
def test_every_sentence_type(text: str, event: object, how: str) -> None:
    proto = HostProtocol(9)
    got = feed(proto, text.encode() + b"\r\n", how)
    assert got[0] == event
    # a lone received frame is also a whole packet; nothing else follows
    follows: list[object] = []
    if isinstance(event, RxData):
        follows = [Packet(2, 7, False, None, 1, b"Hello")]
    elif isinstance(event, FdpReceived) and event.frames:  # an FDP packet arrives whole
        follows = [Packet(2, 7, False, 5, 2, b"\xbe\xef\x01")]
    elif isinstance(event, ModemMessage) and event.packet_timeout:  # counted as a loss
        follows = [PacketLost(None, "packet timeout (1)")]
    assert got[1:] == follows
    assert proto.bad_lines == 0


@pytest.mark.parametrize("how", HOW)
def test_line_ends_cr_lf_or_both_and_blank_lines(how: str) -> None:
    proto = HostProtocol(1)
    got = feed(proto, b"\r\n\r\n$CATXF,2*56\r$CATXF,2*56\n$CATXF,2*56\r\n\n", how)
    assert got == [TxFrame(2)] * 3


BAD = [
    b"$CATXF,2*57",  # wrong checksum
    b"$CATXF",  # missing field
    b"$CATXF,2,3",  # extra field
    b"$CATXF,x",
    b"$CAACK,2,1,9,1",  # frame 9 > 8
    b"$CAACK,2,1,1,2",  # flag 2
    b"$CACYC,0,1,200,1,1,1",  # address > 127
    b"$CARXD,1,2,1,1,ABC",  # odd hex
    b"$CARXD,1,2,1,1,XYZW",
    b"$CAMPR,2,1,abc",
    b"$CAMPR,2,1,nan",
    b"$CAMUA,1,2,FFFF",  # more than 13 bits
    b"CATXF,2*56",  # no $
    b"$CA\xffTXF",
    b"$CADRQ,1,2",
]


@pytest.mark.parametrize("how", HOW)
@pytest.mark.parametrize("bad", BAD)
def test_bad_lines_are_counted_and_dropped(bad: bytes, how: str) -> None:
    proto = HostProtocol(1)
    got = feed(proto, bad + b"\r\n$CATXF,2*56\r\n", how)
    assert len(got) == 2 and isinstance(got[0], BadSentence) and got[1] == TxFrame(2)
    assert proto.bad_lines == 1


def test_next_event_needs_data_until_a_line_ends() -> None:
    proto = HostProtocol(1)
    proto.receive_data(b"$CATXP,64")
    assert proto.next_event() is NEED_DATA
    proto.receive_data(b"\r\n")
    assert proto.next_event() == TxStart(64)
    assert proto.next_event() is NEED_DATA


def test_noise_before_a_sentence_is_dropped_and_the_sentence_kept() -> None:
    proto = HostProtocol(1)
    got = feed(proto, b"\x00\x13garbage$CATXF,2*56\r\n")
    assert isinstance(got[0], BadSentence) and got[1:] == [TxFrame(2)]


@pytest.mark.parametrize("how", HOW)
def test_a_sentence_cut_off_does_not_eat_the_next_one(how: str) -> None:
    # a modem rebooting mid-line: the cut-off $CARXD has no line end before the $CAREV
    proto = HostProtocol(3)
    proto.start_transfer(2, b"abc", rate=1, ack=False)
    got = feed(proto, b"$CARXD,1,3,0,1,01$CAREV,000000,INIT,2.0.27087*4D\r\n", how)
    assert isinstance(got[0], BadSentence) and got[0].line == b"$CARXD,1,3,0,1,01"
    assert got[1] == Revision("000000", "INIT", "2.0.27087")
    assert isinstance(got[2], TransferFailed) and proto.needs_init
    assert proto.bad_lines == 1


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=60).map(lambda b: b.replace(b"\r", b"").replace(b"\n", b"")),
       st.sampled_from([c for c in CASES if isinstance(c[1], TxFrame | Ack | Revision | Config)]))
def test_garbage_before_a_valid_sentence_never_loses_it(
        garbage: bytes, case: tuple[str, object]) -> None:
    # garbage without '$' is noise; with '$' it is a cut-off sentence: either way the valid
    # sentence after it is kept
    proto = HostProtocol(1)
    got = feed(proto, garbage + line(case[0]))
    assert got[-1] == case[1]
    assert proto.bad_lines == len(got) - 1 == (1 if garbage else 0)


def test_overlong_line_is_dropped_up_to_the_next_line_end() -> None:
    proto = HostProtocol(1)
    proto.receive_data(b"$CARXD," + b"A" * 9000)
    proto.receive_data(b"B" * 100 + b"*00\r\n$CATXF,2*56\r\n")
    got = list(proto.events())
    assert isinstance(got[0], BadSentence) and got[1:] == [TxFrame(2)]


def cycle(proto: HostProtocol, modem_lines: list[str], how: str = "whole") -> list[object]:
    return feed(proto, b"".join(line(t) for t in modem_lines), how)


def sent(proto: HostProtocol) -> list[str]:
    return [parse_sentence(x).to_line(with_checksum=False)
            for x in proto.data_to_send().split(b"\r\n") if x]


@pytest.mark.parametrize("how", ["whole", "bytes"])
def test_rate0_transfer_with_cycle_init_and_ack(how: str) -> None:
    proto = HostProtocol(1)
    proto.start_transfer(2, b"Hello", rate=0, ack=True)
    assert sent(proto) == ["$CCCYC,0,1,2,0,1,1"]
    assert proto.transfer_state is TransferState.WAIT_ECHO
    cycle(proto, ["$CACYC,0,1,2,0,1,1"], how)
    assert proto.transfer_state is TransferState.WAIT_CYCLE_INIT
    cycle(proto, ["$CATXF,2", "$CAXST,20250606,1"], how)  # the cycle-init mini-packet
    assert proto.transfer_state is TransferState.WAIT_REQUEST
    cycle(proto, ["$CADRQ,120000,1,2,1,32,1"], how)
    assert sent(proto) == ["$CCTXD,1,2,1,48656C6C6F"]
    events = cycle(proto, ["$CATXD,1,2,1,5", "$CATXP,5", "$CAREV,1,AUV,1", "$CATXF,5"], how)
    assert not any(isinstance(e, TransferDone) for e in events)
    assert proto.transfer_state is TransferState.WAIT_ACKS
    events = cycle(proto, ["$CAACK,3,1,1,1", "$CAACK,2,1,1,1"], how)  # only node 2's counts
    assert events[-1] == TransferDone(2, 1, acked=True)
    assert proto.transfer_state is TransferState.IDLE


def test_rate1_multi_frame_transfer_without_ack() -> None:
    proto = HostProtocol(4)
    data = bytes(range(150))
    proto.start_transfer(5, data, rate=1, ack=False)
    assert sent(proto) == ["$CCCYC,0,4,5,1,0,3"]
    cycle(proto, ["$CACYC,0,4,5,1,0,3", "$CACYC,0,4,5,1,0,3"])
    handed = b""
    for f in (1, 2, 3):
        cycle(proto, [f"$CADRQ,120000,4,5,0,64,{f}"])
        (txd,) = sent(proto)
        handed += bytes.fromhex(txd.split(",")[-1])
    assert handed == data
    cycle(proto, ["$CADRQ,120000,4,5,0,64,4"])  # beyond our frames: blank TXD
    assert sent(proto) == ["$CCTXD,4,5,0,"]
    assert cycle(proto, ["$CATXF,150"])[-1] == TransferDone(5, 3, acked=False)


def test_transfer_refuses_oversize_and_overlap() -> None:
    proto = HostProtocol(1)
    with pytest.raises(ValueError):
        proto.start_transfer(2, bytes(33), rate=0, ack=False)
    with pytest.raises(ValueError):
        proto.start_transfer(2, b"", rate=0, ack=False)
    proto.start_transfer(2, bytes(32), rate=0, ack=False)
    with pytest.raises(ValueError):
        proto.start_transfer(2, b"x", rate=0, ack=False)


@pytest.mark.parametrize(
    ("lines", "reason"),
    [
        (["$CAERR,120000,DATA_TIMEOUT,1"], "DATA_TIMEOUT"),
        (["$CAERR,120000,NMEA,1,Unknown command"], "NMEA"),
        (["$CAREV,000001,INIT,2.0"], "rebooted"),
    ],
)
def test_transfer_fails_on_error_or_reboot(lines: list[str], reason: str) -> None:
    proto = HostProtocol(1)
    proto.start_transfer(2, b"x", rate=1, ack=False)
    cycle(proto, ["$CACYC,0,1,2,1,0,1"])
    events = cycle(proto, lines)
    failed = [e for e in events if isinstance(e, TransferFailed)]
    assert len(failed) == 1 and reason in failed[0].reason
    assert proto.transfer_state is TransferState.IDLE
    assert proto.needs_init == (reason == "rebooted")


def test_abort_is_the_adapters_timeout() -> None:
    proto = HostProtocol(1)
    proto.abort("nothing running")
    assert list(proto.events()) == []
    proto.start_transfer(2, b"x", rate=0, ack=True)
    proto.abort("no echo within 5 s")
    assert list(proto.events()) == [TransferFailed("no echo within 5 s")]


def test_poll_from_another_node_gets_a_blank_txd() -> None:
    proto = HostProtocol(1)
    cycle(proto, ["$CACYC,0,1,3,1,0,1", "$CADRQ,120000,1,3,0,64,1"])
    assert sent(proto) == ["$CCTXD,1,3,0,"]


@pytest.mark.parametrize("how", ["whole", "bytes"])
def test_incoming_frames_are_joined_into_a_packet(how: str) -> None:
    proto = HostProtocol(2)
    events = cycle(proto, [
        "$CARXP,1", "$CACYC,0,7,2,1,1,2",
        "$CARXD,7,2,1,1,0102", "$CACST,8,0", "$CARXD,7,2,1,2,03",
    ], how)
    assert events[-1] == Packet(7, 2, True, 1, 2, b"\x01\x02\x03")


def test_overheard_frames_are_delivered_too_and_without_cycle_init() -> None:
    proto = HostProtocol(2)
    events = cycle(proto, ["$CARXD,7,3,0,1,AA"])
    assert events[-1] == Packet(7, 3, False, None, 1, b"\xaa")


def test_bad_crc_and_incomplete_packets_are_lost() -> None:
    proto = HostProtocol(2)
    events = cycle(proto, ["$CACYC,0,7,2,1,0,2", "$CARXD,7,2,0,1,01", "$CAMSG,BAD_CRC,2"])
    assert events[-1] == PacketLost(7, "bad CRC (2)")
    events = cycle(proto, ["$CACYC,0,7,2,1,0,2", "$CARXD,7,2,0,1,01", "$CACYC,0,8,2,0,0,1",
                           "$CARXD,8,2,0,1,02"])
    assert PacketLost(7, "incomplete packet (new cycle-init)") in events
    assert events[-1] == Packet(8, 2, False, 0, 1, b"\x02")


def test_fdp_transfer_and_reception_beside_legacy() -> None:
    proto = HostProtocol(1)
    proto.start_fdp(2, b"\x01" * 100, 5, False)
    assert sent(proto) == ["$CCTDP,2,5,0,0," + "01" * 100]
    events = cycle(proto, ["$CATDP,0,3,2,5,0,0", "$CATXP,100", "$CATXF,100"])
    assert events[-1] == TransferDone(2, 1, False)
    with pytest.raises(ValueError, match="FDP runs at rates"):
        proto.start_fdp(2, b"x", 0, False)
    with pytest.raises(ValueError, match="does not fit"):
        proto.start_fdp(2, b"x" * 193, 6, False)
    # a legacy packet and an FDP packet, one after the other, both arrive
    got = cycle(proto, ["$CACYC,0,3,1,1,0,1", "$CARXD,3,1,0,1,AA",
                        "$CARFP,2025-05-29T15:26:07.286444,4,2,1,1,5,0,0,,1;1;BB,1;2;CCDD"])
    packets = [e for e in got if isinstance(e, Packet)]
    assert packets == [Packet(3, 1, False, 1, 1, b"\xaa"), Packet(2, 1, False, 5, 2,
                                                                   b"\xbb\xcc\xdd")]
    # a bad FDP frame loses the packet; the refusal of a $CCTDP fails the transfer
    assert cycle(proto, ["$CARDP,2,1,5,0,0,,1;1;BB;0;2;CCDD"])[-1] == PacketLost(
        2, "FDP packet with bad CRC in frames [2]")
    proto.start_fdp(2, b"x", 1, True)
    assert cycle(proto, ["$CATDP,1,4,2,1,1,0"])[-1] == TransferFailed(
        "modem refused the FDP packet ($CATDP error 1)")


def test_fdp_with_ack_ends_at_its_acknowledgement() -> None:
    """With ack, an FDP packet is done when its destination acknowledged every data frame."""
    proto = HostProtocol(1)
    proto.start_fdp(2, bytes(150), 1, True)  # three 64-byte frames at rate 1
    assert sent(proto) == ["$CCTDP,2,1,1,0," + "00" * 150]
    cycle(proto, ["$CATDP,0,3,2,1,1,0", "$CATXP,150", "$CATXF,150"])
    assert proto.transfer_state is TransferState.WAIT_ACKS
    stamp = "2025-05-29T15:09:05.461473"
    assert not any(isinstance(e, TransferDone) for e in cycle(proto, [
        f"$CACDR,{stamp},3,4,1,-1,00,0007",  # another node's
        f"$CACDR,{stamp},3,2,5,-1,00,0007",  # to another node
        f"$CACDR,{stamp},3,2,1,-1,00,0003"]))  # frame 3 missing
    assert cycle(proto, [f"$CACDR,{stamp},3,2,1,-1,00,0007"])[-1] == TransferDone(2, 1, True)
    # user mini-frames ($CCTFP) arrive in $CARFP's user field, joined before the data
    got = cycle(proto, [f"$CARFP,{stamp},4,2,1,1,1,0,0,,1;2;0A0B,1;1;0C"])
    assert got[-1] == Packet(2, 1, False, 1, 2, b"\x0a\x0b\x0c")


def test_packet_timeout_loses_the_packet_and_usbl_names_the_last_sender() -> None:
    proto = HostProtocol(1)
    got = cycle(proto, ["$CACYC,0,4,1,0,0,1", "$CAMSG,PACKET_TIMEOUT,1", USB2])
    assert PacketLost(4, "packet timeout (1)") in got
    assert got[-1] == UsblFix("2025-05-29T15:26:07.286444", 45.5, -10.25, 0.0125, 2, 3, src=4)
    assert cycle(proto, ["$CAMSG,PACKET_TIMEOUT,1"])[-1] == PacketLost(None,
                                                                      "packet timeout (1)")


def test_commands() -> None:
    proto = HostProtocol(3)
    proto.configure("SRC", 3)
    proto.configure("CST", True)
    proto.query("SRC")
    proto.ping(4)
    proto.ping(5, fdp=True)
    proto.reboot()
    assert sent(proto) == ["$CCCFG,SRC,3", "$CCCFG,CST,1", "$CCCFQ,SRC", "$CCMPC,3,4",
                           "$CCCMD,PNG,3,5,1,0", "$CCMSC,3,3,0"]
    assert proto.data_to_send() == b""


def test_lbl_sentences() -> None:
    """The interrogations the driver writes, goby's window, and ``$SNTTA`` as printed."""
    assert nav.window_ms(2000, 50) == 2716
    assert nav.remus(1, 2716, {"A", "c"}).to_line(with_checksum=False) == (
        "$CCPDT,1,1,0,0,2716,1,0,1,0")
    assert nav.narrowband(9000, 10, 2716, {"B": 10500}).to_line(with_checksum=False) == (
        "$CCPNT,9000,10,10,2716,0,10500,0,0,1")
    assert nav.tta({"A": 0.2, "D": 1.25}, 86400 * 3 + 12 * 3600 + 5.678).to_line(
        with_checksum=False) == "$SNTTA,0.2000,,,1.2500,120005.67"
    asked = nav.interrogation(nav.narrowband(9000, 10, 500, {"B": 10500}))
    assert (asked.listen, asked.window_s, asked.transmit) == ((False, True, False, False), 0.5,
                                                              True)
    for bad in (lambda: nav.remus(5, 100, {"A"}), lambda: nav.remus(1, 100, {"E"}),
                lambda: nav.narrowband(9000, 10, 100, {"A": 0})):
        with pytest.raises(ValueError):
            bad()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=20), st.booleans())
def test_fuzz_receive_never_raises(chunks: list[bytes], transfer: bool) -> None:
    proto = HostProtocol(1)
    if transfer:
        proto.start_transfer(2, b"abc", rate=0, ack=True)
    for chunk in chunks:
        proto.receive_data(chunk)
    list(proto.events())
    proto.data_to_send()


SENTENCES = st.sampled_from([c[0] for c in CASES] + [
    "$CACYC,0,1,2,0,1,1", "$CADRQ,1,1,2,1,32,1", "$CATXF,3", "$CACYC,0,5,1,1,0,2",
    "$CARXD,5,1,0,2,00", "$CAACK,2,1,1,1", "$CAERR,1,X",
])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(SENTENCES, st.booleans()), max_size=30))
def test_fuzz_sentence_sequences_keep_state_consistent(items: list[tuple[str, bool]]) -> None:
    proto = HostProtocol(1)
    proto.start_transfer(2, b"abc", rate=0, ack=True)
    for text, corrupt in items:
        raw = line(text)
        if corrupt:
            raw = raw.replace(b"*", b"*F", 1)
        proto.receive_data(raw)
        for event in proto.events():
            if isinstance(event, TransferDone | TransferFailed):
                assert proto.transfer_state is TransferState.IDLE
