"""The modem options the mission file names for the simulated water: a ``preset`` that no modem
kind has, a ``water`` address no water can listen on, two links sharing one water. Each is a
mistake of the file, refused at load (``zab check``, and every command that loads it) with its
place, never a traceback once a water or a node starts."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import parse_mission
from bridge.errors import MissionError
from bridge.mission.presets import PRESETS
from tests.two_links import two_links

ONE_LINK = """\
mission: one
wire: {{auth: off}}
modem:
  backend: sim
  frame_bytes: 64
  options:
    preset: {preset}
    water: {water}
mac: {{type: tdma, slot_s: 2.0, guard_s: 0.2, order: [a, b]}}
nodes:
  a: {{address: 1}}
  b:
    address: 2
    modem: {{options: {{preset: {b_preset}}}}}
channels:
  - {{name: n, from: a, to: b, elements: [{{in: n, out: a/n, fields: [{{field: n, type: int,
      min: 0, max: 9}}]}}]}}
"""


def one_link(preset: str = "evologics-s2c-im", water: str = "127.0.0.1:7630",
             b_preset: str = "evologics-s2c-im") -> str:
    return ONE_LINK.format(preset=preset, water=water, b_preset=b_preset)


def error_of(text: str) -> str:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return str(info.value)


def test_good_presets_and_waters_load() -> None:
    parse_mission(one_link(), "m.yaml")
    parse_mission(one_link(water="7630"), "m.yaml")  # a bare port: 127.0.0.1
    parse_mission(two_links(), "m.yaml")


def test_an_unknown_preset_is_located_and_the_known_ones_listed() -> None:
    message = error_of(one_link(preset="evologics-s2c-imm"))
    assert message.splitlines()[0].startswith(
        "m.yaml:7:5: modem.options.preset: unknown modem preset 'evologics-s2c-imm'; "
        "known presets: "), message
    assert all(name in message for name in PRESETS)
    assert len(message.splitlines()) == 1, message


def test_an_unknown_preset_of_one_node_is_located_there() -> None:
    message = error_of(one_link(b_preset="micromodem-rate9"))
    assert message.startswith("m.yaml:14:23: nodes.b.modem.options.preset: unknown modem "
                              "preset 'micromodem-rate9'; known presets: "), message


def test_a_preset_that_is_not_a_name_is_refused() -> None:
    message = error_of(one_link(preset="[1, 2]"))
    assert "modem.options.preset: unknown modem preset [1, 2]" in message, message


def test_an_unknown_preset_on_one_of_several_links_is_named_not_the_macs_timing() -> None:
    message = error_of(two_links(preset_rf="s100-rff"))
    assert "links.rf.modem.options.preset: unknown modem preset 's100-rff'; known presets: " \
        in message, message
    assert "ipg_s" not in message, message  # (the MAC's timing needs the preset it names)


@pytest.mark.parametrize(("water", "words"), [
    ("127.0.0.1:99999", "port 99999 is out of range (1-65535)"),
    ("127.0.0.1:0", "port 0 is out of range (1-65535)"),
    ("70000", "port 70000 is out of range (1-65535)"),
    ("nowhere", "must be the 'host:port' of `zab water` (got 'nowhere')"),
    ("'127.0.0.1:'", "must be the 'host:port' of `zab water` (got '127.0.0.1:')"),
])
def test_a_water_address_that_cannot_be_listened_on_is_refused(water: str, words: str) -> None:
    message = error_of(two_links(water_rf=water))
    assert message.startswith("m.yaml:10:54: "), message
    assert f"links.rf.modem.options.water: {words}" in message, message
    message = error_of(one_link(water=water))
    assert f"m.yaml:8:5: modem.options.water: {words}" in message, message


@pytest.mark.parametrize("water_rf", ["127.0.0.1:17620", "17620", "'[127.0.0.1]:17620'"])
def test_two_links_cannot_share_one_water(water_rf: str) -> None:
    message = error_of(two_links(water_rf=water_rf))
    assert message == (
        "m.yaml:10:54: links.rf.modem.options.water: 127.0.0.1:17620 is also the water of link "
        "'acoustic': each link needs a water of its own (one `zab water` per link, each with "
        "the link's modem preset)"), message


def test_check_sim_and_water_refuse_an_unknown_preset_without_a_traceback(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(one_link(preset="evologics-s2c-imm"))
    for args in (["check", "--no-key"], ["sim", "--fast", "--duration", "5"],
                 ["water"], ["sim", "--duration", "1", "--no-live"]):
        result = CliRunner().invoke(app, [*args, str(path)])
        output = result.output + (result.stderr if result.stderr_bytes is not None else "")
        assert result.exit_code == 2, (args, output, result.exception)
        assert "Traceback" not in output
        assert "unknown modem preset 'evologics-s2c-imm'" in output.replace("\n", ""), \
            (args, output)


def with_water_option(option: str, value: str) -> str:
    """The one-link mission with ``option: value`` after its water (line 9)."""
    text = one_link()
    water = "    water: 127.0.0.1:7630\n"
    return text.replace(water, f"{water}    {option}: {value}\n")


def test_a_good_seed_and_loss_load() -> None:
    parse_mission(with_water_option("seed", "4"), "m.yaml")
    parse_mission(with_water_option("loss", "0.3"), "m.yaml")
    parse_mission(with_water_option("loss", "1"), "m.yaml")


@pytest.mark.parametrize("loss", ["2", "-0.1", "x", "true", ".nan", "[0.1]"])
def test_a_loss_that_is_not_a_share_is_refused_at_its_place(loss: str) -> None:
    message = error_of(with_water_option("loss", loss))
    assert message.startswith("m.yaml:9:5: modem.options.loss: must be a number from 0 to 1, "
                              "the share of frames the simulated water loses (got "), message


@pytest.mark.parametrize("seed", ["x", "1.5", "true", "'4'"])
def test_a_seed_that_is_not_a_whole_number_is_refused_at_its_place(seed: str) -> None:
    message = error_of(with_water_option("seed", seed))
    assert message.startswith("m.yaml:9:5: modem.options.seed: must be a whole number, the "
                              "simulated water's random seed (got "), message


def test_a_bad_seed_or_loss_of_one_node_is_located_there() -> None:
    text = one_link().replace("modem: {options: {preset: evologics-s2c-im}}",
                              "modem: {options: {preset: evologics-s2c-im, loss: 7}}")
    message = error_of(text)
    assert message.startswith("m.yaml:14:"), message
    assert "nodes.b.modem.options.loss: must be a number from 0 to 1" in message, message


@pytest.mark.parametrize(("option", "value"), [("loss", "2"), ("seed", "x")])
def test_sim_and_water_refuse_a_bad_seed_or_loss_without_a_traceback(
        tmp_path: Path, option: str, value: str) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(with_water_option(option, value))
    for args in (["check", "--no-key"], ["sim", "--fast", "--duration", "5"], ["water"],
                 ["sim", "--duration", "1", "--no-live"]):
        result = CliRunner().invoke(app, [*args, str(path)])
        output = result.output + (result.stderr if result.stderr_bytes is not None else "")
        assert result.exit_code == 2, (args, output, result.exception)
        assert "Traceback" not in output
        assert f"m.yaml:9:5: modem.options.{option}: must be" in output.replace("\n", ""), \
            (args, output)
