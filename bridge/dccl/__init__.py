"""DCCL messages from ``.proto`` files, encoded bit-identically to libdccl 4's default codecs.

``load_message("nav.proto", "NavStatus")`` gives a :class:`DcclMessage` with ``encode(dict)``
and ``decode(bytes)``; :func:`analyze` gives its bit budget like ``dccl --analyze``. Modules:
``schema`` (protoc → definitions), ``build`` (libdccl's load checks → codecs), ``codecs`` and
``numeric`` (the field codecs), ``message`` (id, head, body), ``compile`` (the generated fast
path), ``layout`` (a channel element), ``goby`` (Goby-compatible frames), ``analyze``.
"""

from __future__ import annotations

from pathlib import Path

from bridge.dccl.analyze import analyze
from bridge.dccl.codecs import DcclRangeError
from bridge.dccl.message import DcclMessage, peek_id
from bridge.dccl.schema import DcclSchemaError, ProtoFile, load_proto

__all__ = ["DcclMessage", "DcclRangeError", "DcclSchemaError", "ProtoFile", "analyze",
           "load_message", "load_proto", "peek_id"]


def load_message(path: str | Path, name: str) -> DcclMessage:
    """Message ``name`` of the ``.proto`` file at ``path``, checked as libdccl's load does."""
    return DcclMessage.from_proto(load_proto(path), name)
