"""The EvoLogics AT parsers (host side and the emulator's command reader), sans I/O.

Every input is fed whole, one byte at a time, and followed by trailing data (h11's ``tr``).
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.modems.evologics.commands import (
    CommandReader,
    HostBurst,
    HostCommand,
    HostGarbage,
    send_im,
    set_value,
)
from bridge.modems.evologics.protocol import (
    BurstData,
    Busy,
    CanceledIm,
    Delivered,
    DeliveredIm,
    Error,
    Event,
    ExpiredIms,
    Failed,
    FailedIm,
    HostProtocol,
    LocalProtocolError,
    Malformed,
    Mode,
    Notification,
    Ok,
    Recv,
    RecvEnd,
    RecvFailed,
    RecvIm,
    RecvImLegacy,
    RecvIms,
    RecvPbm,
    RecvPbmLegacy,
    RecvStart,
    SendEnd,
    SendStart,
    UsblAngles,
    UsblLong,
    Value,
    command_name,
    firmware_is_legacy,
    parse_body,
    wrap,
)
from bridge.modems.protocol import NEED_DATA

USBLLONG = (b"USBLLONG,10446.991981,10446.534643,3,-0.0604,-1.0888,-0.5851,-0.4233,-1.0020,"
            b"-0.5901,0.0063,0.0269,-0.3295,825,-36,77,1.2375")
USBLANGLES = (b"USBLANGLES,1464207778.381274,1464207778.075953,2,0.2262,0.1253,0.2262,0.1253,"
              b"0.0000,-0.0000,0.0000,-54,106,0.0500")

# body (as the modem prints it, without wrapper) -> the event it must give
NOTIFICATIONS: list[tuple[bytes, Event]] = [
    (b"RECVIM,5,1,2,ack,312,14,11,0.03,he,\r\n",
     RecvIm(1, 2, "ack", 312, 14, 11, 0.03, b"he,\r\n")),
    (b"RECVIM,p0,4,2,3,noack,340015,-32,133,0.0534,+++A",
     RecvIm(2, 3, "noack", 340015, -32, 133, 0.0534, b"+++A", pid=0)),
    (b"RECVIMS,5,1,2,1853167139,182272,-40,120,0.03,hello",
     RecvIms(1, 2, 1853167139, 182272, -40, 120, 0.03, b"hello")),
    (b"RECVPBM,5,1,2,182272,-40,120,0.03,hello", RecvPbm(1, 2, 182272, -40, 120, 0.03, b"hello")),
    (b"RECV,5,1,2,6825,-40,120,9377,0.03,h\x00l,o", Recv(1, 2, 6825, -40, 120, 9377, 0.03,
                                                          b"h\x00l,o")),
    (b"DELIVEREDIM,3", DeliveredIm(3)),
    (b"FAILEDIM,3", FailedIm(3)),
    (b"CANCELEDIM,3", CanceledIm("IM", 3)),
    (b"CANCELEDIMS,4", CanceledIm("IMS", 4)),
    (b"CANCELEDPBM,5", CanceledIm("PBM", 5)),
    (b"EXPIREDIMS,3", ExpiredIms(3)),
    (b"DELIVERED,5,2", Delivered(5, 2)),
    (b"FAILED,5,2", Failed(5, 2)),
    (b"SENDSTART,3,im,182272,0", SendStart(3, "im", 182272, 0)),
    (b"SENDEND,3,im,1853167139,182272", SendEnd(3, "im", 1853167139, 182272)),
    (b"RECVSTART", RecvStart()),
    (b"RECVEND,1853461060,139376,-36,77", RecvEnd(1853461060, 139376, -36, 77)),
    (b"RECVEND,3349740869,182272,-40,120,0.1000", RecvEnd(3349740869, 182272, -40, 120, 0.1)),
    (b"RECVFAILED,0.00,-60,20", RecvFailed(0.0, -60, 20)),
    (USBLLONG, UsblLong(10446.991981, 10446.534643, 3, -0.0604, -1.0888, -0.5851, -0.4233, -1.002,
                        -0.5901, 0.0063, 0.0269, -0.3295, 825, -36, 77, 1.2375)),
    (USBLANGLES, UsblAngles(1464207778.381274, 1464207778.075953, 2, 0.2262, 0.1253, 0.2262,
                            0.1253, 0.0, -0.0, 0.0, -54, 106, 0.05)),
    (b"BITRATE,local,6825", Notification("BITRATE", ("local", "6825"))),
    (b"SRCLEVEL,3", Notification("SRCLEVEL", ("3",))),
    (b"RADDR,2", Notification("RADDR", ("2",))),
    (b"PHYOFF", Notification("PHYOFF")),
    (b"DROPCNT,0", Notification("DROPCNT", ("0",))),
    (b"USBLPHYD,10446.992626,10446.534642,3,0,-39278,-10591,16777215,-12608,-27941,23818,"
     b"16777215,16777215", Notification("USBLPHYD", (
         "10446.992626", "10446.534642", "3", "0", "-39278", "-10591", "16777215", "-12608",
         "-27941", "23818", "16777215", "16777215"))),
    (b"NOISE,3,1,2,3,\r\n\x00", Notification("NOISE", ("3", "1", "2", "3"), b"\r\n\x00")),
    (b"ERROR EFAULT", Error(None, "EFAULT")),
    (b"ERROR OVERLOAD", Error(None, "OVERLOAD")),
]


def feed(protocol: HostProtocol, data: bytes, how: str) -> list[Event]:
    out: list[Event] = []
    if how == "bytewise":
        for i in range(len(data)):
            protocol.receive_data(data[i : i + 1])
            out.extend(protocol.events())
    else:
        protocol.receive_data(data)
        out.extend(protocol.events())
    return out


HOW = ["whole", "bytewise"]


@pytest.mark.parametrize("how", HOW)
@pytest.mark.parametrize("body,event", NOTIFICATIONS, ids=[b[:12].decode("latin-1")
                                                            for b, _ in NOTIFICATIONS])
def test_notifications_in_both_modes(body: bytes, event: Event, how: str) -> None:
    for mode in Mode:
        protocol = HostProtocol(mode)
        trailing = wrap(b"DELIVEREDIM,9", mode)
        got = feed(protocol, wrap(body, mode) + trailing, how)
        assert got == [event, DeliveredIm(9)], mode
        assert protocol.next_event() is NEED_DATA


def test_the_real_data_mode_transcript() -> None:
    protocol = HostProtocol(Mode.DATA, eol=b"\n")
    protocol.send(b"*SENDIM,p0,4,3,ack,test")
    assert protocol.data_to_send() == b"+++AT*SENDIM,p0,4,3,ack,test\n"
    assert protocol.data_to_send() == b""  # taken once
    transcript = (b"+++AT*SENDIM:2:OK\r\n+++AT:23:SENDSTART,3,im,182272,0\r\n"
                  b"+++AT:30:SENDEND,3,im,1853167139,182272\r\n+++AT:9:RECVSTART\r\n"
                  b"+++AT:32:RECVEND,1853461060,139376,-36,77\r\n+++AT:13:DELIVEREDIM,3\r\n"
                  b"+++AT:124:" + USBLLONG + b"\r\n")
    for how in HOW:
        p = HostProtocol(Mode.DATA)
        p.send(b"*SENDIM,p0,4,3,ack,test")
        events = feed(p, transcript, how)
        assert [type(e) for e in events] == [Ok, SendStart, SendEnd, RecvStart, RecvEnd,
                                             DeliveredIm, UsblLong]
        assert events[0] == Ok("*SENDIM") and p.pending == ()


def test_real_recvim_with_a_seven_byte_payload() -> None:
    line = b"+++AT:47:RECVIM,7,6,4,ack,221308,-51,140,-0.0098,E\x01+++AT\r\n"
    assert feed(HostProtocol(Mode.DATA), line, "whole") == [
        RecvIm(6, 4, "ack", 221308, -51, 140, -0.0098, b"E\x01+++AT")]


@pytest.mark.parametrize("how", HOW)
def test_replies_in_data_mode_name_their_command(how: str) -> None:
    p = HostProtocol(Mode.DATA)
    for cmd in ("?AL", "!AL2", "@ZX1", "?UPX", "?P", "*SENDIM,1,2,noack,x"):
        p.send(cmd)
    data = (b"+++AT?AL:1:2\r\n+++AT!AL:5:[*]OK\r\n+++AT@ZX:18:ERROR WRONG FORMAT\r\n"
            b"+++AT?UPX:31:10446,3,-0.4233,-1.0020,-0.5901\r\n"
            b"+++AT?P:24:10    10   \n100   240  \n\r\n+++AT*SENDIM:18:BUSY BACKOFF STATE\r\n")
    assert feed(p, data, how) == [
        Value("?AL", "2"), Ok("!AL", pending=True), Error("@ZX", "WRONG FORMAT"),
        Value("?UPX", "10446,3,-0.4233,-1.0020,-0.5901"), Value("?P", "10    10   \n100   240  \n"),
        Busy("*SENDIM", "BACKOFF STATE"),
    ]
    assert p.pending == ()


@pytest.mark.parametrize("how", HOW)
def test_command_mode_replies_go_to_the_oldest_pending_command(how: str) -> None:
    p = HostProtocol(Mode.COMMAND)
    p.send("?AL")
    p.send("?DI")
    p.send("&V")
    p.send("!AL3")
    assert p.data_to_send() == b"AT?AL\rAT?DI\rAT&V\rAT!AL3\r"
    data = (b"2\r\nRECVSTART\r\nFAILED\r\nSource Level: 3\r\nLocal Address: 2\r\n\r\n"
            b"SENDSTART,3,im,182272,0\r\nOK\r\n")
    assert feed(p, data, how) == [
        Value("?AL", "2"), RecvStart(), Value("?DI", "FAILED"),
        Value("&V", "Source Level: 3\r\nLocal Address: 2\r\n"),
        SendStart(3, "im", 182272, 0), Ok("!AL"),
    ]


def test_data_mode_raw_data_and_partial_prefixes() -> None:
    p = HostProtocol(Mode.DATA)
    p.receive_data(b"12345++")
    assert list(p.events()) == [BurstData(b"12345")]  # "++" might start +++AT: kept
    p.receive_data(b"++AT:13:DELIVEREDIM,3\r\nab+")
    assert list(p.events()) == [BurstData(b"+"), DeliveredIm(3), BurstData(b"ab")]
    p.receive_data(b"x")
    assert list(p.events()) == [BurstData(b"+x")]


def test_firmware_16_recvim_layout() -> None:
    p = HostProtocol(Mode.COMMAND, legacy_recvim=True)
    events = feed(p, b"RECVIM,3,1,2,ack,976,-40,120,9377,0.03,a\r\n\r\n", "whole")
    assert events == [RecvImLegacy(1, 2, "ack", 976, -40, 120, 9377, 0.03, b"a\r\n")]


@pytest.mark.parametrize("legacy", [True, False])
def test_recvim_and_recvpbm_of_firmware_16_and_17(legacy: bool) -> None:
    """The same reception as firmware 1.6 (bitrate, ptime) and 1.7+ (duration) print it;
    a parser set for the other firmware reports it Malformed, never garbage."""
    old = (b"RECVIM,5,1,2,noack,976,-40,120,9377,0.0300,hello\r\n"
           b"RECVPBM,2,1,2,976,-40,120,9377,0.0300,hi\r\n")
    new = (b"RECVIM,5,1,2,noack,182272,-40,120,0.0300,hello\r\n"
           b"RECVPBM,2,1,2,182272,-40,120,0.0300,hi\r\n")
    p = HostProtocol(Mode.COMMAND, legacy_recvim=legacy)
    events = feed(p, old if legacy else new, "whole")
    if legacy:
        assert events == [RecvImLegacy(1, 2, "noack", 976, -40, 120, 9377, 0.03, b"hello"),
                          RecvPbmLegacy(1, 2, 976, -40, 120, 9377, 0.03, b"hi")]
    else:
        assert events == [RecvIm(1, 2, "noack", 182272, -40, 120, 0.03, b"hello"),
                          RecvPbm(1, 2, 182272, -40, 120, 0.03, b"hi")]
    wrong = HostProtocol(Mode.COMMAND, legacy_recvim=not legacy)
    assert all(isinstance(e, Malformed) for e in feed(wrong, old if legacy else new, "whole"))


@pytest.mark.parametrize(("reply", "legacy"), [("1.6", True), ("1.6.3", True), ("1.7", False),
                                               ("1.9", False), ("2.0.1", False)])
def test_firmware_version_from_ati0(reply: str, legacy: bool) -> None:
    assert firmware_is_legacy(reply) is legacy
    with pytest.raises(ValueError):
        firmware_is_legacy("emulated")


MALFORMED = [
    b"+++AT:5:DELIVEREDIM,3\r\n",  # declared length too short: no CRLF where it must be
    b"+++ATbad name:3:abc\r\n",
    b"+++AT:x:abc\r\n",
    b"+++AT:99999999:abc\r\n",
    b"+++AT:12:RECVIM,1,2\r\n",  # a RECVIM cut short
    b"+++AT:20:SENDSTART,x,im,1,2\r\n",
    b"+++AT:13:RECVEND,1,2,3\r\n",
    b"+++AT:12:lowercase,1\r\n",
]


@pytest.mark.parametrize("bad", MALFORMED)
def test_malformed_input_is_reported_and_the_parser_recovers(bad: bytes) -> None:
    for how in HOW:
        p = HostProtocol(Mode.DATA)
        events = feed(p, bad + b"+++AT:13:DELIVEREDIM,7\r\n", how)
        assert any(isinstance(e, Malformed) for e in events), events
        assert events[-1] == DeliveredIm(7)
        assert not any(isinstance(e, DeliveredIm) and e.dst != 7 for e in events)


@pytest.mark.parametrize("how", HOW)
def test_a_corrupt_length_does_not_stall_the_parser(how: str) -> None:
    # found from outside: a RECVIM declaring 999 B made the parser wait for them, swallowing
    # the reply and the notification behind it
    bad = b"+++AT:999:RECVIM,3,1,2,ack,1000,-50,100,0.0,abc\r\n"
    p = HostProtocol(Mode.DATA)
    events = feed(p, bad + b"+++AT*SENDIMS:2:OK\r\n+++AT:26:SENDSTART,255,ims,400850,0\r\n", how)
    assert events[0] == Malformed(bad, "+++AT packet declares 999 B, its body holds 37")
    assert events[1:] == [Ok("*SENDIMS"), SendStart(255, "ims", 400850, 0)]


def test_a_length_beyond_any_body_is_malformed_at_once() -> None:
    p = HostProtocol(Mode.DATA)
    assert feed(p, b"+++AT:1281:PHYOFF", "whole")[0] == Malformed(
        b"+++AT:1281:", "bad length b'1281' in +++AT packet")
    p = HostProtocol(Mode.DATA)  # with its line end there, the whole line goes
    events = feed(p, b"+++AT:60000:PHYOFF\r\n+++AT:13:DELIVEREDIM,7\r\n", "whole")
    assert events == [Malformed(b"+++AT:60000:PHYOFF\r\n", "bad length b'60000' in +++AT packet"),
                      DeliveredIm(7)]


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([b for b, _ in NOTIFICATIONS]), st.integers(0, 1280),
       st.sampled_from(HOW))
def test_any_wrong_length_never_loses_the_packet_behind(body: bytes, declared: int,
                                                         how: str) -> None:
    packet = b"+++AT:%d:%s\r\n" % (declared, body)
    events = feed(HostProtocol(Mode.DATA), packet + b"+++AT:13:DELIVEREDIM,7\r\n", how)
    assert events[-1] == DeliveredIm(7)
    if declared != len(body):
        assert any(isinstance(e, Malformed) for e in events)


def test_command_mode_malformed_and_truncated() -> None:
    p = HostProtocol(Mode.COMMAND)
    events = feed(p, b"RECVIM,5,1,2,ack,312,14,11,0.03,toolongpayload\r\nFAILEDIM,2\r\n", "whole")
    assert isinstance(events[0], Malformed) and events[-1] == FailedIm(2)
    p = HostProtocol(Mode.COMMAND)
    assert feed(p, b"RECVIM,5,1,2,ack,312,14,11,0.03,ab", "whole") == []  # waits for 3 more
    assert feed(p, b"\r\n\r\r\n", "whole") == [
        RecvIm(1, 2, "ack", 312, 14, 11, 0.03, b"ab\r\n\r")]
    p = HostProtocol(Mode.COMMAND)
    events = feed(p, b"x" * 5000, "whole")
    assert events and isinstance(events[0], Malformed)


def test_unsolicited_unknown_line_is_malformed() -> None:
    assert feed(HostProtocol(Mode.COMMAND), b"42\r\n", "whole") == [
        Malformed(b"42", "not a notification")]
    assert parse_body(None, b"RECVIM,1,1,2,ack,1,2,3,0.0,xy") == Malformed(
        b"RECVIM,1,1,2,ack,1,2,3,0.0,xy", "RECVIM declares 1 B, body holds 2")


def test_events_serialise_back_to_their_bytes() -> None:
    for _, event in NOTIFICATIONS:
        assert parse_body(None, event.body()) == event
    assert Ok(pending=True).body() == b"[*]OK"
    assert Busy(None, "DELIVERING").body() == b"BUSY DELIVERING"


def test_commands_and_local_errors() -> None:
    assert send_im(b"a,\r", 255) == b"*SENDIM,3,255,noack,a,\r"
    assert send_im(b"x", 2, ack=True, pid=0) == b"*SENDIM,p0,1,2,ack,x"
    assert set_value("!AL", 4) == b"!AL4"
    assert command_name(b"!AL2") == "!AL" and command_name(b"*SENDIM,1,2,ack,x") == "*SENDIM"
    assert command_name(b"?MODE") == "?MODE" and command_name(b"Z0") == "Z"
    with pytest.raises(LocalProtocolError):
        send_im(b"x" * 65, 2)
    with pytest.raises(LocalProtocolError):
        send_im(b"", 2)
    with pytest.raises(LocalProtocolError):
        set_value("AL", 1)
    with pytest.raises(LocalProtocolError):
        HostProtocol().send("")


# -- the modem's side: CommandReader ------------------------------------------------------------


def read(reader: CommandReader, data: bytes, how: str) -> list[object]:
    out: list[object] = []
    chunks = [data[i : i + 1] for i in range(len(data))] if how == "bytewise" else [data]
    for chunk in chunks:
        reader.receive_data(chunk)
        out.extend(reader.inputs())
    return out


@pytest.mark.parametrize("how", HOW)
def test_reader_command_mode(how: str) -> None:
    items = read(CommandReader(Mode.COMMAND),
                 b"AT?AL\rAT*SENDIM,7,2,ack,a\r\n+++A\rAT!AL3\n+++AT?MODE\rATO\r", how)
    assert [i.text if isinstance(i, HostCommand) else i for i in items] == [
        b"?AL", b"*SENDIM,7,2,ack,a\r\n+++A", b"!AL3", HostGarbage(b"+++AT?MODE"), b"O"]
    send = items[1].send  # type: ignore[union-attr]
    assert send is not None and send.data == b"a\r\n+++A" and send.flag == "ack" and send.dst == 2


@pytest.mark.parametrize("how", HOW)
def test_reader_data_mode(how: str) -> None:
    reader = CommandReader(Mode.DATA)
    items = read(reader, b"raw+++AT*SENDIMS,p1,2,3,,\r\n\n+++AT?AL\nmore++", how)
    commands = [i for i in items if isinstance(i, HostCommand)]
    burst = b"".join(i.data for i in items if isinstance(i, HostBurst))
    assert burst == b"rawmore" and [c.name for c in commands] == ["*SENDIMS", "?AL"]
    assert commands[0].send is not None and commands[0].send.pid == 1
    assert commands[0].send.data == b"\r\n" and commands[0].send.usec is None
    assert read(reader, b"+", how) == [] and reader.holding_escape


def test_reader_rejects_bad_sends() -> None:
    items = read(CommandReader(Mode.COMMAND),
                 b"AT*SENDIM,65,2,ack,x\rAT*SENDIM,1,2,maybe,x\rAT*SENDIM,1,2,ack,xy\rAT?AL\r",
                 "whole")
    assert [bool(getattr(i, "error", "")) for i in items] == [True, True, True, False]


# -- fuzzing -------------------------------------------------------------------------------------

PIECES = st.sampled_from([b"+++AT", b":", b",", b"\r\n", b"\r", b"RECVIM", b"12", b"OK", b"+",
                          b"ERROR ", b"SENDEND", b"p0", b"-3.5"])
NOISY = st.lists(st.one_of(PIECES, st.binary(max_size=8)), max_size=40).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(data=NOISY, mode=st.sampled_from(list(Mode)), cut=st.integers(0, 400))
def test_fuzz_host_parser_never_raises(data: bytes, mode: Mode, cut: int) -> None:
    p = HostProtocol(mode)
    p.send("?AL")
    p.receive_data(data[:cut])
    first = list(p.events())
    p.receive_data(data[cut:] + wrap(b"DELIVEREDIM,7", Mode.DATA))
    events = first + list(p.events())
    assert all(isinstance(e, Event) for e in events)


@settings(max_examples=300, deadline=None)
@given(data=NOISY, mode=st.sampled_from(list(Mode)))
def test_fuzz_command_reader_never_raises(data: bytes, mode: Mode) -> None:
    reader = CommandReader(mode)
    reader.receive_data(data)
    assert all(isinstance(i, HostCommand | HostBurst | HostGarbage) for i in reader.inputs())


@settings(max_examples=200, deadline=None)
@given(payload=st.binary(min_size=0, max_size=64), src=st.integers(0, 255),
       dst=st.integers(0, 255), rssi=st.integers(-120, 0), mode=st.sampled_from(list(Mode)),
       split=st.integers(0, 200))
def test_fuzz_any_payload_round_trips(payload: bytes, src: int, dst: int, rssi: int, mode: Mode,
                                      split: int) -> None:
    event = RecvIm(src, dst, "noack", 1000, rssi, 100, 0.5, payload)
    wire = wrap(event.body(), mode) + wrap(b"RECVSTART", mode)
    p = HostProtocol(mode)
    p.receive_data(wire[:split])
    got = list(p.events())
    p.receive_data(wire[split:])
    assert [*got, *p.events()] == [event, RecvStart()]
