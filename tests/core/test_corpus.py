"""The one path against the recorded-frames corpus (``tests/corpus/``): the same scenarios give
the same frames, publications, status, events, saved states and counters, byte for byte, as
they did when the corpus was recorded."""

from __future__ import annotations

import pytest

from tests.corpus.record import SCENARIOS, Scenario, differences, load, normal, path_of, run


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.name)
def test_the_core_outputs_what_was_recorded(scenario: Scenario) -> None:
    assert path_of(scenario).exists(), "record it: uv run python -m tests.corpus.record"
    expected = load(scenario)
    got = normal(run(scenario))
    found = list(differences(expected, got))
    assert not found, "\n".join(found)
    assert len(expected["records"]) > 100  # the scenario exercised something
    frames = [r for r in got["records"] if r[2] == "event" and r[3] == "frame_received"]
    assert frames, "no frame crossed"
