"""Fixtures of the deploy tests: one throwaway fleet PKI, and Zenoh sessions closed after use."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
import zenoh

from tests.deploy.tls_kit import Opener, close, make_pki


@pytest.fixture(scope="session")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fleet CA and certificates of docs/deploy.md, made once with the openssl CLI."""
    return make_pki(tmp_path_factory.mktemp("tls"))


@pytest.fixture
def sessions() -> Iterator[Opener]:
    """Opens sessions and closes every one of them, last opened first."""
    with ExitStack() as stack:
        def open_session(config: zenoh.Config) -> zenoh.Session:
            session = zenoh.open(config)
            stack.callback(close, session)
            return session
        yield open_session
