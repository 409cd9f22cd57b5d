"""``zab demo``'s line for a published position: what a newcomer can check against the truth."""

from __future__ import annotations

from bridge.cli.demo import describe_fix
from bridge.ranging.tracker import Estimate


def test_a_fix_beside_the_truth_in_plain_rounded_numbers() -> None:
    est = Estimate("tracking", 12.0, 15.000000095, 47.12345, 18.0, 0.1, 0.8,
                   ((0.2, 0.0), (0.0, 0.1)), 0.4, anchors=("gcv", "ssv"))
    line = describe_fix(est.payload(), (15.2, 47.0))
    assert line.plain == ("position (tracking, gcv + ssv): x 15.0 m, y 47.1 m, ±0.55 m · truth "
                          "x 15.2, y 47.0 · error 0.24 m")  # hypot(0.2, 0.123)
    assert "e-" not in line.plain
    coasting = describe_fix(Estimate("coasting", 30.0, 1.0, 2.0, 3.0, cov=((1.0, 0.0),
                                                                          (0.0, 1.0)),
                                     age_s=7.6, anchors=("ssv",)).payload())
    assert coasting.plain.startswith("position (coasting 8 s, ssv): x 1.0 m, y 2.0 m, ±1.41 m")
    assert "truth" not in coasting.plain  # no simulator, no truth
