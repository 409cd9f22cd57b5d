"""Each node's modem options, checked against its backend's model when the mission loads: a
wrong type, a value out of range, a misspelt option or backend is an error of the file at its
place (``zab check`` exits 2), never a traceback once ``zab doctor`` or ``zab run`` starts the
modem; the drivers take their options from the same models."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import BackendError, MissionError
from bridge.mission.backends import BACKEND_OPTIONS
from bridge.modems.base import ModemSetup
from bridge.modems.evologics.driver import EvologicsBackend
from bridge.modems.micromodem.driver import MicromodemBackend
from bridge.modems.registry import BUILTIN_BACKENDS
from bridge.modems.sim import SimBackend
from bridge.modems.udp import UdpBackend
from tests.two_links import two_links

MISSION = """\
mission: opts
wire: {{auth: off}}
modem:
  backend: {backend}
  frame_bytes: 32
  options: {{{shared}}}
mac: {{type: tdma, slot_s: 8.0, guard_s: 1.0, order: [a, b]}}
nodes:
  a:
    address: 1
    modem: {{options: {{{own}}}}}
  b:
    address: 2
    modem: {{options: {{{own_b}}}}}
channels:
  - {{name: n, from: a, to: b, elements: [{{in: n, out: a/n, fields: [{{field: n, type: int,
      min: 0, max: 9}}]}}]}}
"""

GOOD = {
    "sim": ("preset: evologics-s2c-im, water: 127.0.0.1:25010, seed: 3", "", ""),
    "udp": ("", "port: 25011", "port: 25012"),
    "evologics": ("preset: evologics-s2c-im",
                  "device: /dev/ttyUSB0", "device: /dev/ttyUSB1"),
    "micromodem": ("preset: micromodem-rate0",
                   "device: /dev/ttyUSB0", "device: /dev/ttyUSB1"),
}


def mission(backend: str, shared: str = "", own: str = "") -> str:
    """``backend``'s good mission, with ``shared`` added to the mission's options and ``own``
    to node a's (line 6 and line 11)."""
    good_shared, good_a, good_b = GOOD[backend]
    return MISSION.format(backend=backend, shared=", ".join(filter(None, [good_shared, shared])),
                          own=", ".join(filter(None, [good_a, own])), own_b=good_b)


def error_of(text: str) -> str:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return str(info.value)


@pytest.mark.parametrize("backend", sorted(GOOD))
def test_good_options_of_every_backend_load(backend: str) -> None:
    parse_mission(mission(backend), "m.yaml")


def test_every_builtin_backend_has_an_options_model() -> None:
    assert set(BACKEND_OPTIONS) == set(BUILTIN_BACKENDS)


SHARED = [  # (backend, option, what the message says), in the mission's options (line 6)
    ("evologics", "baud: fast", "baud: evologics backend: Input should be a valid integer "
                                "(got 'fast')"),
    ("evologics", "baud: 0", "baud: evologics backend: must be a standard serial rate"),
    ("evologics", "baud: -5", "baud: evologics backend: must be a standard serial rate"),
    ("evologics", "timeout_s: -1", "timeout_s: evologics backend: Input should be greater "
                                   "than 0"),
    ("evologics", "mode: fast", "mode: evologics backend: Input should be 'data' or 'command'"),
    ("evologics", "buad: 9600", "buad: evologics backend: unknown option (check its spelling; "
                                "known: ack, ack_timeout_s, baud,"),
    ("micromodem", "rate: 9", "rate: micromodem backend: Input should be 0, 1, 2, 3, 4, 5 or 6"
                              " (got 9)"),
    ("micromodem", "retries: x", "retries: micromodem backend: Input should be a valid "
                                 "integer"),
    ("micromodem", "set_clock: gps", "set_clock: micromodem backend: Input should be 'none', "
                                     "'clk' or 'tms'"),
    ("micromodem", "rat: 1", "rat: micromodem backend: unknown option"),
    ("sim", "connect_timeout: 0", "connect_timeout: sim backend: Input should be greater than "
                                  "0"),
    ("sim", "rx_queue: many", "rx_queue: sim backend: Input should be a valid integer"),
    ("sim", "watr: 25013", "watr: sim backend: unknown option"),
    ("udp", "allow_remote: sure", "allow_remote: udp backend: Input should be a valid boolean"),
    ("udp", "rx_queue: -1", "rx_queue: udp backend: Input should be greater than or equal to 0"),
    ("udp", "hots: 127.0.0.1", "hots: udp backend: unknown option"),
]


@pytest.mark.parametrize(("backend", "option", "words"), SHARED)
def test_a_wrong_shared_option_is_refused_at_its_place(backend: str, option: str,
                                                       words: str) -> None:
    message = error_of(mission(backend, shared=option))
    assert message.startswith("m.yaml:6:"), message
    assert f": modem.options.{words}" in message, message
    assert len(message.splitlines()) == 1, message  # once, though every node has it


@pytest.mark.parametrize(("backend", "option", "words"), [
    ("evologics", "devcie: /dev/ttyUSB2", "devcie: evologics backend: unknown option"),
    ("micromodem", "baud: 19201", "baud: micromodem backend: must be a standard serial rate"),
    ("udp", "host: 7", "host: udp backend: Input should be a valid string (got 7)"),
    ("sim", "clock_drift_ppm: lots", "clock_drift_ppm: sim backend: Input should be a valid "
                                     "number"),
])
def test_a_wrong_option_of_one_node_is_refused_there(backend: str, option: str,
                                                     words: str) -> None:
    message = error_of(mission(backend, own=option))
    assert message.startswith("m.yaml:11:"), message
    assert f": nodes.a.modem.options.{words}" in message, message


def test_fdp_at_rate_0_is_refused_at_the_options() -> None:
    message = error_of(mission("micromodem", shared="fdp: true"))
    assert message.startswith("m.yaml:6:"), message
    assert "modem.options.fdp: micromodem backend: FDP sends at rates 1-6, not rate 0" in \
        message, message


def test_options_every_backend_takes_pass_a_node_of_another_backend() -> None:
    text = mission("sim").replace("  a:\n    address: 1\n    modem: {options: {}}",
                                  "  a:\n    address: 1\n    modem: {backend: evologics, "
                                  "options: {device: /dev/ttyUSB0, ack: true}}")
    parse_mission(text, "m.yaml")  # preset, water and seed are the water's, whatever the modem


def test_a_misspelt_backend_is_refused_at_its_place_with_the_known_ones() -> None:
    message = error_of(mission("evologics").replace("backend: evologics", "backend: evologic"))
    assert message == ("m.yaml:4:3: modem.backend: unknown backend 'evologic' (known: "
                       "evologics, micromodem, sim, udp)"), message
    text = mission("sim").replace("modem: {options: {}}", "modem: {backend: simm}", 1)
    message = error_of(text)
    assert message.startswith("m.yaml:11:13: nodes.a.modem.backend: unknown backend 'simm'"), \
        message


def test_a_wrong_option_of_one_of_several_links_is_refused_in_that_link() -> None:
    text = two_links().replace("preset: s100-rf", "preset: s100-rf, clock_drift_pm: 2")
    message = error_of(text)
    assert "links.rf.modem.options.clock_drift_pm: sim backend: unknown option" in message, \
        message


@pytest.mark.parametrize(("backend", "option", "place"), [
    ("evologics", "baud: fast", "m.yaml:6:"), ("micromodem", "rate: 9", "m.yaml:6:"),
    ("evologics", "backend", "m.yaml:4:3: modem.backend: unknown backend 'evologic'")])
def test_check_doctor_and_run_refuse_a_wrong_option_without_a_traceback(
        tmp_path: Path, backend: str, option: str, place: str) -> None:
    path = tmp_path / "m.yaml"
    if option == "backend":
        path.write_text(mission(backend).replace("backend: evologics", "backend: evologic"))
    else:
        path.write_text(mission(backend, shared=option))
    state = str(tmp_path / "state")
    for args in (["check", "--no-key"], ["doctor", "--node", "a", "--state-dir", state],
                 ["run", "--node", "a", "--state-dir", state]):
        result = CliRunner().invoke(app, [*args, str(path)])
        output = result.output + (result.stderr if result.stderr_bytes is not None else "")
        assert result.exit_code == 2, (args, output, result.exception)
        assert "Traceback" not in output, (args, output)
        assert place in output, (args, output)
        assert output.count("error") <= 1, (args, output)  # no tables before the error


@pytest.mark.parametrize(("cls", "options", "words"), [
    (EvologicsBackend, {"device": "/dev/null", "baud": "fast"}, "option baud: Input should be "
                                                                "a valid integer"),
    (MicromodemBackend, {"device": "/dev/null", "rate": 9}, "option rate: Input should be 0"),
    (SimBackend, {"water": "127.0.0.1:25014", "rx_queue": -1}, "option rx_queue:"),
    (UdpBackend, {"port": 25015, "prot": 1}, "option prot: unknown option"),
])
def test_a_driver_given_a_wrong_option_says_so(cls: type, options: dict[str, object],
                                               words: str) -> None:
    with pytest.raises(BackendError, match=words):
        cls(ModemSetup(node="a", address=1, frame_bytes=32, options=options))
