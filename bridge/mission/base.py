"""The base of every mission model (and of the layouts' fields): numbers are finite.

YAML writes infinity and not-a-number as ``.inf`` and ``.nan``; no time, range, position or
field bound of a mission means either, so every model refuses them where it takes a number
(``must be a finite number``), once, here.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

__all__ = ["MissionModel"]


class MissionModel(BaseModel):
    """Base of every mission model: ``.inf`` and ``.nan`` are refused wherever a number is."""

    model_config = ConfigDict(allow_inf_nan=False)
