"""``zab schema --payloads``: every bridged key's payload schema, checked against real payloads."""

from __future__ import annotations

import contextlib
import io
import json
import queue
from pathlib import Path

import jsonschema
import pytest
from PIL import Image
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.core.loaded import load_mission
from bridge.image.formats import write_image
from bridge.image.synthetic import seabed
from bridge.runtime.virtual_fleet import FastFleet
from bridge.wire.images import merge_control
from bridge.wire.payload_schema import json_view, key_schemas, write_payload_schemas
from tests.conftest import MISSIONS, on_free_ports, udp_ports
from tests.harness import Inbox, outside_session, put, running_fleet

RUNNER = CliRunner()

RICH = """\
mission: rich
modem: {backend: udp, frame_bytes: 64}
mac: {type: none}
nodes:
  a: {address: 1, modem: {options: {port: PORT_A}}}
  b: {address: 2, modem: {options: {port: PORT_B}}}
channels:
  - name: status
    from: a
    to: b
    elements:
      - in: "{node}/status"
        out: "{src}/status_at_{dst}"
        fields:
          - {field: pose.x, bits: 12, min: -100, max: 100}
          - {field: pose.depth, resolution: 0.5, min: 0, max: 300}
          - {field: battery, type: int, min: 0, max: 100}
          - {field: ok, type: bool}
          - {field: mode, values: [idle, survey, home]}
          - {field: label, type: string, max_length: 6}
          - {field: blob, type: bytes, length: 3}
          - {field: temps, type: int, min: -5, max: 30, count: 3}
"""

VALUE = {"pose": {"x": 12.5, "depth": 42.0}, "battery": 77, "ok": True, "mode": "survey",
         "label": "auv", "blob": b"\x01\xfe\x10", "temps": [-5, 12, 30]}


def _rich():
    text = udp_ports(RICH)
    return on_free_ports(text, "rich.yaml")


def test_schemas_of_every_example_mission_are_valid_2020_12(tmp_path: Path) -> None:
    for path in sorted(MISSIONS.glob("*.yaml")):
        result = RUNNER.invoke(app, ["schema", "--payloads", str(path), "--out",
                                     str(tmp_path / path.stem)])
        assert result.exit_code == 0, (path, result.output)
        index = json.loads((tmp_path / path.stem / "index.json").read_text())
        assert index["keys"], path
        for entry in index["keys"]:
            schema = json.loads((tmp_path / path.stem / entry["file"]).read_text())
            jsonschema.Draft202012Validator.check_schema(schema)
            assert schema["x-zab"]["direction"] == entry["direction"]


def test_keys_and_directions_follow_the_templates() -> None:
    entries = {(e.direction, e.key): e for e in key_schemas(_rich().table)}
    assert set(entries) == {("in", "a/status"), ("out", "a/status_at_b")}
    out = entries[("out", "a/status_at_b")].schema
    assert out["properties"]["mode"] == {"enum": ["idle", "survey", "home"]}
    assert out["properties"]["temps"]["minItems"] == out["properties"]["temps"]["maxItems"] == 3
    assert out["properties"]["label"]["maxLength"] == 6
    assert out["properties"]["blob"]["maxLength"] == 6  # 3 bytes as hex
    assert out["properties"]["pose"]["required"] == ["x", "depth"]
    inp = entries[("in", "a/status")].schema
    assert {"type": "integer", "minimum": 0, "maximum": 2} in inp["properties"]["mode"]["anyOf"]


def test_a_real_decoded_payload_validates(tmp_path: Path) -> None:
    loaded = _rich()
    files = write_payload_schemas(loaded.table, loaded.mission.mission, tmp_path)
    schemas = {json.loads(p.read_text())["$id"]: json.loads(p.read_text())
               for p in files if p.name != "index.json"}
    in_schema, out_schema = schemas["zab:rich/in/a/status"], schemas["zab:rich/out/a/status_at_b"]
    jsonschema.validate(json_view(VALUE), in_schema)
    with running_fleet(loaded):
        a_app, b_app = outside_session(loaded, "a"), outside_session(loaded, "b")
        try:
            inbox = Inbox()
            b_app.declare_subscriber("a/status_at_b", inbox)
            for _ in range(20):  # the bridge's subscriber may still be propagating: put again
                put(a_app, "a/status", VALUE)
                with contextlib.suppress(queue.Empty):
                    key, decoded, _ = inbox.get(timeout=1)
                    break
            else:
                raise AssertionError("the bridged payload never arrived")
        finally:
            a_app.close()
            b_app.close()
    assert key == "a/status_at_b" and decoded["blob"] == VALUE["blob"]
    jsonschema.validate(json_view(decoded), out_schema)
    wrong = json_view({**decoded, "mode": "dive"})
    assert not jsonschema.Draft202012Validator(out_schema).is_valid(wrong)
    shorter = json_view({k: v for k, v in decoded.items() if k != "battery"})
    assert not jsonschema.Draft202012Validator(out_schema).is_valid(shorter)


def test_an_image_channel_s_keys_say_what_crosses_there() -> None:
    """bluerov_images' index left out the pictures' keys, and gave the operator's control the
    wire's layout (roi_on, x0 … in 64ths, every field required) and an output at the camera,
    where nothing is published."""
    loaded = load_mission(MISSIONS / "bluerov_images.yaml")
    entries = {(e.direction, e.key): e for e in key_schemas(loaded.table)}
    images = {k: (e.encoding, e.nodes) for k, e in entries.items() if "camera" in e.key}
    assert images == {("in", "rov/camera"): ("image/jpeg|image/png", ["rov"]),
                      ("out", "rov/camera"): ("image/png", ["operator"]),
                      ("in", "camera/control"): ("msgpack", ["operator"])}
    control = jsonschema.Draft202012Validator(entries[("in", "camera/control")].schema)
    spec = next(c.image for c in loaded.table.channels if c.image and not c.image.control)
    for good in ({"request": "now"}, {"roi": [0.25, 0.25, 0.75, 0.75], "budget_bytes": 800},
                 {"roi": None, "width": 320, "height": 240}, {}):
        assert control.is_valid(good), good
        merge_control({}, good, spec)  # (the bridge takes it as well)
    for bad in ({"roi_on": True}, {"budget_bytes": 6401}, {"request": "later"},
                {"roi": [0.5, 0.5, 1.5, 1.0]}, {"width": 4}):
        assert not control.is_valid(bad), bad
        with pytest.raises(ValueError):
            merge_control({}, bad, spec)
    # the metadata the schema lists is what a published picture carries
    fleet = FastFleet(loaded, seed=1)
    fleet.put("rov", "rov/camera", write_image(seabed(120, 160, seed=1, colour=False), "jpeg"),
              encoding="image/jpeg", at=1.0)
    fleet.run_until(5.0)
    [(_, first), *_] = fleet.published("operator", "rov/camera")
    text = Image.open(io.BytesIO(first.value)).text  # type: ignore[attr-defined]
    listed = entries[("out", "rov/camera")].schema["x-zab-metadata"]
    assert set(text) == set(listed)
