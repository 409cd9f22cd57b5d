"""A ``.proto`` that DCCL cannot read says so in one line naming the file.

Found from outside: a plain proto2 message (no ``dccl/option_extensions.proto`` import) gave
``KeyError: "Couldn't find message dccl.DCCLFieldOptions"`` out of ``zab check``; a file with
no ``syntax`` line and a mistake showed protoc's warning about the missing syntax, not the
mistake."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.cli.app import app
from bridge.dccl import DcclSchemaError, load_proto

MISSION = """mission: x
nodes:
  a: {address: 1}
  b: {address: 2}
mac: {type: tdma, slot_s: 2, order: [a, b]}
channels:
  - name: c
    from: a
    to: b
    elements:
      - in: k
        out: k2
        dccl: plain.proto:Plain
"""


def test_a_plain_protobuf_message_is_not_dccl(tmp_path: Path) -> None:
    proto = tmp_path / "plain.proto"
    proto.write_text('syntax = "proto2";\nmessage Plain { required int32 a = 1; }\n')
    with pytest.raises(DcclSchemaError, match="not a DCCL message file") as info:
        load_proto(proto)
    assert info.value.file == str(proto.resolve())
    (tmp_path / "m.yaml").write_text(MISSION)
    result = CliRunner().invoke(app, ["check", str(tmp_path / "m.yaml")])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "m.yaml:13:9: channels[0].elements[0].dccl: " in result.output
    assert "plain.proto: not a DCCL message file" in result.output


def test_the_error_not_the_missing_syntax_warning(tmp_path: Path) -> None:
    proto = tmp_path / "nosyntax.proto"
    proto.write_text("message Plain { required int32 a = 1 }\n")
    with pytest.raises(DcclSchemaError) as info:
        load_proto(proto)
    assert (info.value.line, info.value.reason) == (1, 'Expected ";".')
