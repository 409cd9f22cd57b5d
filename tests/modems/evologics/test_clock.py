"""The S2C's 32-bit µs clock as continuous seconds: anchoring, wraps, drift, SENDIMS times."""

from __future__ import annotations

import pytest

from bridge.modems.evologics.clock import WRAP_US, ModemClock
from bridge.modems.evologics.commands import CommandReader, send_ims
from bridge.modems.evologics.protocol import LocalProtocolError, Mode


def test_counter_and_seconds_are_exact_across_wraps() -> None:
    clock = ModemClock()
    assert not clock.synced
    with pytest.raises(ValueError, match="not been read"):
        clock.counter(1.0)
    clock.sync(1_700_000_000.0, WRAP_US - 2_000_000)  # two seconds before the counter wraps
    assert clock.synced and clock.now(1_700_000_000.5) == 1_700_000_000.5
    assert clock.counter(1_700_000_000.0) == WRAP_US - 2_000_000
    after = 1_700_000_003.25  # past the wrap
    assert clock.counter(after) == 1_250_000
    assert clock.seconds(1_250_000, near=after + 0.3) == pytest.approx(after, abs=1e-6)
    # a difference of two modem times is exact to the µs, whatever the wrap in between
    t1 = clock.seconds(WRAP_US - 1_000_017, near=1_700_000_001.0)
    t2 = clock.seconds(483, near=1_700_000_002.0)
    assert (t2 - t1) * 1e6 == pytest.approx(1_000_500, abs=0.5)
    # one wrap (71.6 min) later the same counter value is another time
    later = clock.seconds(1_250_000, near=after + WRAP_US * 1e-6)
    assert later - after == pytest.approx(WRAP_US * 1e-6, abs=1e-6)


def test_resync_follows_drift_without_moving_the_scale() -> None:
    clock = ModemClock()
    clock.sync(1000.0, 5_000_000)
    scale = clock.seconds(5_000_000 + 300_000_000, near=1300.0)
    clock.sync(1300.0, 5_000_000 + 300_000_000 + 6_000)  # the modem ran 20 ppm fast
    assert clock.now(1300.0) == pytest.approx(1300.006, abs=1e-9)
    assert clock.seconds(5_000_000 + 300_000_000, near=1300.0) == scale  # scale unchanged
    assert clock.readings == 2
    with pytest.raises(ValueError, match="outside"):
        clock.sync(1301.0, WRAP_US)


def test_a_slow_reading_moves_the_offset_only_as_far_as_it_proves_it_wrong() -> None:
    clock = ModemClock()
    clock.sync(1000.0, 5_000_000)
    # answered 0.4 s late: the midpoint says the modem is 0.2 s behind, but anywhere in
    # [-0.4, 0] s fits the reading, and 0 (the last estimate) is in it: kept
    clock.sync(1010.2, 5_000_000 + 10_000_000, uncertainty_s=0.2)
    assert clock.now(1020.0) == pytest.approx(1020.0, abs=1e-9)
    # a reading that does prove it wrong (the modem 0.5 s ahead, ± 0.1 s) moves it to the
    # nearest offset it allows
    clock.sync(1020.0, 5_000_000 + 20_500_000, uncertainty_s=0.1)
    assert clock.now(1020.0) == pytest.approx(1020.4, abs=1e-9)
    assert clock.readings == 3


def test_sendims_builder_round_trips_through_the_modem_reader() -> None:
    wire = send_ims(b"a,b\r\n", 3, 4_294_000_123)
    assert wire == b"*SENDIMS,5,3,4294000123,a,b\r\n"
    assert send_ims(b"x", 255, None) == b"*SENDIMS,1,255,,x"
    reader = CommandReader(Mode.COMMAND)
    reader.receive_data(b"AT" + wire + b"\r")
    (command,) = list(reader.inputs())
    assert command.send is not None
    assert (command.send.kind, command.send.dst, command.send.usec, command.send.data) == (
        "IMS", 3, 4_294_000_123, b"a,b\r\n")
    for bad in ((b"", 3, 0), (b"x" * 65, 3, 0), (b"x", 256, 0), (b"x", 3, WRAP_US)):
        with pytest.raises(LocalProtocolError):
            send_ims(*bad)  # type: ignore[arg-type]
