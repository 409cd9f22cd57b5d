"""Bad modem input is logged so an operator sees a noisy line without a flood: each kind's
first at WARNING with its bytes, then one WARNING per period per kind with the count."""

from __future__ import annotations

import logging

import pytest

from bridge.modems.base import BadInputLog


def test_first_of_each_kind_warns_then_once_per_period_with_the_count(
        caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    noise = BadInputLog(logging.getLogger("zab.test"), "micromodem n1", period_s=60.0,
                        clock=lambda: now[0])
    caplog.set_level(logging.DEBUG, logger="zab.test")
    noise.bad(b"$CATXF,2*00", "checksum mismatch in $CATXF,2: got 00, computed 56")
    noise.bad(b"$CATXF,3*00", "checksum mismatch in $CATXF,3: got 00, computed 57")
    noise.bad(b"\x00garbage", "noise before '$'")
    now[0] = 61.0
    noise.bad(b"$CATXF,4*00", "checksum mismatch in $CATXF,4: got 00, computed 50")
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 3 and all(m.startswith("micromodem n1: bad modem input") for m in warned)
    assert "1 of this kind" in warned[0] and "b'$CATXF,2*00'" in warned[0]
    assert "noise before" in warned[1] and "b'\\x00garbage'" in warned[1]
    assert "3 of this kind" in warned[2]  # the repeat inside the period went to DEBUG
    assert noise.counts == {"checksum mismatch": 3, "noise before": 1}


def test_the_bytes_shown_are_bounded(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="zab.test")
    BadInputLog(logging.getLogger("zab.test"), "evologics n1").bad(b"+" * 5000, "bad")
    [record] = caplog.records
    assert len(record.getMessage()) < 200
