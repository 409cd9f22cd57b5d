"""DCCL messages from ``.proto`` files, encoded bit-identically to libdccl 4's default codecs.

``load_message("nav.proto", "NavStatus")`` gives a :class:`DcclMessage` with ``encode(dict)``
and ``decode(bytes)``; :func:`analyze` gives its bit budget like ``dccl --analyze``. Modules:
``schema`` (protoc → definitions), ``build`` (libdccl's load checks → codecs), ``codecs`` and
``numeric`` (the field codecs), ``message`` (id, head, body), ``compile`` (the generated fast
path), ``layout`` (a channel element), ``goby`` (Goby-compatible frames), ``analyze``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from bridge.dccl.analyze import analyze
from bridge.dccl.codecs import DcclRangeError
from bridge.dccl.message import DcclMessage, peek_id
from bridge.dccl.numeric import DEFAULT_RULE, RULES
from bridge.dccl.schema import DcclSchemaError, ProtoFile, load_proto

__all__ = ["DEFAULT_RULE", "RULES", "DcclMessage", "DcclRangeError", "DcclSchemaError",
           "ProtoFile", "analyze", "load_message", "load_proto", "peek_id"]


def load_message(path: str | Path, name: str, rule: str = DEFAULT_RULE,
                 proto_path: Sequence[str | Path] = ()) -> DcclMessage:
    """Message ``name`` of the ``.proto`` file at ``path`` (imports also looked up in the
    ``proto_path`` folders), checked as libdccl's load does, under the numeric ``rule``."""
    return DcclMessage.from_proto(load_proto(path, proto_path), name, rule)
