"""What docs/concepts.md says ``encoding: as_sent`` keeps of a sample's encoding is what the
bridge does: four classes, each label arriving as its class's."""

from __future__ import annotations

import json

import msgpack
import pytest

from bridge.errors import DecodeError
from bridge.wire.payloads import decode_payload
from bridge.wire.sample_meta import ENCODINGS, encode_as, encoding_id
from tests.conftest import REPO

VALUE = {"v": 13}
JSON_TEXT, MSGPACK = json.dumps(VALUE).encode(), msgpack.packb(VALUE)
ARRIVES = [  # (label, payload, the label it arrives with)
    ("application/msgpack", MSGPACK, "application/msgpack"),
    ("application/x-msgpack", MSGPACK, "application/msgpack"),
    ("application/json", JSON_TEXT, "application/json"),
    ("application/json;nav.v1", JSON_TEXT, "application/json"),
    ("text/json", JSON_TEXT, "application/json"),
    ("text/plain", JSON_TEXT, "text/plain"),
    ("zenoh/bytes", JSON_TEXT, "zenoh/bytes"),
    ("application/cbor", JSON_TEXT, "zenoh/bytes"),
    ("zenoh/bytes", MSGPACK, "application/msgpack"),
]


def as_sent_row() -> str:
    text = (REPO / "docs" / "concepts.md").read_text()
    (row,) = [line for line in text.splitlines() if "`encoding: as_sent`" in line]
    return row


@pytest.mark.parametrize(("label", "payload", "arrives"), ARRIVES)
def test_each_label_arrives_as_its_class_says(label: str, payload: bytes, arrives: str) -> None:
    row = as_sent_row()
    assert f"`{label.partition(';')[0]}`" in row and f"`{arrives}`" in row
    value = decode_payload(payload, label)
    data, encoding = encode_as(value, ENCODINGS[encoding_id(label, payload)])
    assert encoding == arrives and decode_payload(data, encoding) == VALUE


@pytest.mark.parametrize(("label", "payload"), [("application/json", MSGPACK),
                                                ("text/plain", MSGPACK),
                                                ("application/msgpack", JSON_TEXT)])
def test_a_payload_its_label_belies_is_dropped_as_the_docs_say(label: str,
                                                                payload: bytes) -> None:
    assert "is dropped, counted `undecodable`" in as_sent_row()
    with pytest.raises(DecodeError):
        decode_payload(payload, label)
