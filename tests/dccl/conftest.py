"""Shared fixtures: the test .proto files."""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.dccl import DcclMessage, load_message

PROTOS = Path(__file__).parent / "protos"


@pytest.fixture(scope="session")
def golden() -> dict[str, DcclMessage]:
    names = ("Golden", "Nested", "Tie", "NoId")
    return {n: load_message(PROTOS / "golden.proto", n) for n in names}
