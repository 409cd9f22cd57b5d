"""Open a node's Zenoh session from the mission, safely (explicit endpoints, no multicast)."""

from __future__ import annotations

import contextlib
import json
from typing import Any

import zenoh

from bridge.mission.model import ZenohSettings

# Every sample a bridge publishes carries this attachment prefix; bridges never re-bridge it.
ORIGIN_PREFIX = b"zab/1 "


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """A Zenoh config listening and connecting only where the mission says.

    The default listen endpoint would be every interface; here it is none unless given.
    Multicast scouting is off unless the node's ``zenoh`` section turns it on.
    """
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    config.insert_json5("listen/endpoints", json.dumps(settings.listen))
    config.insert_json5("connect/endpoints", json.dumps(settings.connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    for key, value in settings.passthrough().items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(settings: ZenohSettings) -> zenoh.Session:
    return zenoh.open(zenoh_config(settings))


def close_quietly(session: Any) -> None:
    """Close a session; Zenoh may raise if a link is being torn down at the same moment."""
    with contextlib.suppress(Exception):
        session.close()


def origin_tag(mission: str, node: str) -> bytes:
    return ORIGIN_PREFIX + f"{mission}/{node}".encode()


def is_bridged(sample: zenoh.Sample) -> bool:
    """True when a bridge published this sample (loop safety)."""
    attachment = sample.attachment
    return attachment is not None and attachment.to_bytes().startswith(ORIGIN_PREFIX)
