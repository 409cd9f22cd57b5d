"""A modem's outage is one ``modem_down`` and one ``modem_up`` however often the runtime
retries: a tester's restarted EvoLogics emulator left ``modem_down`` every few seconds, then
nothing once the modem was back, and the GUI stayed on 'modem unavailable'."""

from __future__ import annotations

from bridge.core.events import ModemDown, ModemUp, notable
from bridge.core.modem_outage import ModemOutage


def test_an_outage_is_one_down_and_one_up_with_its_length_and_retries() -> None:
    outage = ModemOutage()
    assert outage.opened(0.0) is None  # the first open: no outage ended
    assert outage.failed("port gone", 10.0) == ModemDown(10.0, "port gone")
    assert outage.failed("port gone", 10.5) is None
    assert outage.failed("no answer", 11.5) is None
    up = outage.opened(13.5)
    assert up == ModemUp(13.5, 3.5, 2) and notable(up)
    assert up.to_dict() == {"time": 13.5, "down_s": 3.5, "retries": 2}
    assert outage.opened(20.0) is None
    assert outage.failed("port gone", 30.0) == ModemDown(30.0, "port gone")  # the next one
    assert outage.opened(30.5) == ModemUp(30.5, 0.5, 0)
