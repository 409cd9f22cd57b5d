"""The signature check developers.md gives runs as it is written, and says which form of the
mission key signs: the text of ``$ZAB_KEY``, not the bytes its hex spells."""

from __future__ import annotations

import contextlib
import io
import re
import secrets

import pytest

from bridge.runtime.keys import find_key
from bridge.wire.proofs import sign_output
from tests.conftest import REPO


def snippet() -> str:
    text = (REPO / "docs" / "developers.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.DOTALL)
                if "zab-out/1" in b]
    return "\n".join(line.removeprefix("  ") for line in block.splitlines())


def test_the_documented_check_verifies_with_the_keys_text_only(
        monkeypatch: pytest.MonkeyPatch) -> None:
    key = secrets.token_hex(32)  # as `openssl rand -hex 32` makes it
    monkeypatch.setenv("ZAB_KEY", key)
    assert find_key("ZAB_KEY", None) == key.encode()  # what a bridge signs with
    payload, key_expr = b"\x81\xa1v\x03", "auv1/probe"
    said = []
    for signing in (key.encode(), bytes.fromhex(key)):  # the text; the bytes it spells
        attachment = sign_output(signing, b"zab/1 zspace/auv1", key_expr, 7, payload)
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(snippet(), {"attachment": attachment, "key_expr": key_expr,
                             "payload": payload})
        said.append(out.getvalue().strip())
    assert said == ["True", "False"]
