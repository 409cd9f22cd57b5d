"""JSON Schema of the mission file, generated from the pydantic models (``zab schema``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bridge.mission.model import Mission
from bridge.resources import data_dir

SCHEMA_ID = "https://zenoh-acoustic-bridge/schemas/mission.schema.json"


def mission_schema() -> dict[str, Any]:
    schema = Mission.model_json_schema(by_alias=True, mode="validation")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": SCHEMA_ID, **schema}


def schema_text() -> str:
    return json.dumps(mission_schema(), indent=2, sort_keys=True) + "\n"


def default_schema_path() -> Path:
    return data_dir("schemas") / "mission.schema.json"
