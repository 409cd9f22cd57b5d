"""Generated fast path for DCCL messages (placeholder: reference path)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bridge.dccl.message import DcclMessage

__all__ = ["Compiled", "compile_message"]


@dataclass(frozen=True)
class Compiled:
    source: str
    encode: Callable[[Any], bytes]
    encode_strict: Callable[[Any], bytes]
    decode: Callable[[bytes], tuple[dict[str, Any], int]]


def compile_message(msg: DcclMessage) -> Compiled:
    return Compiled("", msg.encode_reference, lambda v: msg.encode_reference(v, True),
                    msg.decode_reference)
