"""Read DCCL message definitions from ``.proto`` files with protoc (from ``grpcio-tools``).

protoc parses the file exactly as libdccl's own loader does (it is the same compiler), so
syntax errors, unknown types and unknown ``(dccl.*)`` options are refused with protoc's
``file:line:column`` message. The descriptors are then turned into plain dataclasses
(:class:`MessageDef`, :class:`FieldDef`) with the DCCL options and each field's source line.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from bridge.errors import LayoutError

__all__ = ["DcclSchemaError", "FieldDef", "MessageDef", "ProtoFile", "load_proto"]

#: Folder holding ``dccl/option_extensions.proto`` (zab's statement of the option schema).
INCLUDE_DIR = Path(__file__).resolve().parent / "include"

#: protobuf ``FieldDescriptorProto.Type`` numbers → names used here.
_TYPES = {1: "double", 2: "float", 3: "int64", 4: "uint64", 5: "int32", 6: "fixed64",
          7: "fixed32", 8: "bool", 9: "string", 10: "group", 11: "message", 12: "bytes",
          13: "uint32", 14: "enum", 15: "sfixed32", 16: "sfixed64", 17: "sint32", 18: "sint64"}
_DCCL_EXTENSION = 1012


class DcclSchemaError(LayoutError):
    """A ``.proto`` file DCCL would refuse; the message starts with ``file:line:``."""

    def __init__(self, message: str, file: str = "", line: int = 0) -> None:
        where = f"{file}:{line}: " if file and line else f"{file}: " if file else ""
        super().__init__(f"{where}{message}")
        self.file, self.line, self.reason = file, line, message


@dataclass(frozen=True)
class FieldDef:
    """One field of a message as declared: protobuf facts plus its ``(dccl.field)`` options."""

    name: str
    number: int
    type: str  # double, float, int32, ..., bool, string, bytes, enum, message
    label: str  # required, optional, repeated
    options: dict[str, Any]  # (dccl.field) options that were set, by name
    line: int  # 1-based line in ``file``
    file: str
    message_type: str | None = None  # full name, for type == "message"
    enum_values: tuple[tuple[str, int], ...] = ()  # (name, number) in declaration order
    oneof: str | None = None


@dataclass(frozen=True)
class MessageDef:
    """A message: full name, ``(dccl.msg)`` options and fields in declaration order."""

    full_name: str
    options: dict[str, Any]
    fields: tuple[FieldDef, ...]
    line: int
    file: str
    syntax: str = "proto2"
    oneofs: tuple[str, ...] = ()  # oneof names, in declaration order


@dataclass
class ProtoFile:
    """Every message of a ``.proto`` file and of the files it imports."""

    path: Path
    messages: dict[str, MessageDef] = field(default_factory=dict)

    def message(self, name: str) -> MessageDef:
        """A message by full name or by its short name if that is unambiguous."""
        if name in self.messages:
            return self.messages[name]
        hits = [m for full, m in self.messages.items() if full.rsplit(".", 1)[-1] == name]
        if len(hits) == 1:
            return hits[0]
        known = ", ".join(sorted(self.messages)) or "none"
        raise DcclSchemaError(f"no message {name!r} (messages: {known})", str(self.path))


def _protobuf_include() -> str:
    import grpc_tools

    return os.path.join(os.path.dirname(grpc_tools.__file__), "_proto")


def _run_protoc(path: Path, proto_path: tuple[str, ...]) -> bytes:
    with tempfile.TemporaryDirectory(prefix="zab-dccl-") as tmp:
        out = Path(tmp) / "set.pb"
        # zab's statement of DCCL's options before the include path: the schema zab reads
        includes = [f"-I{d}" for d in (path.parent, INCLUDE_DIR, *proto_path, _protobuf_include())]
        cmd = [sys.executable, "-m", "grpc_tools.protoc", *includes, "--include_imports",
               "--include_source_info", f"--descriptor_set_out={out}", str(path)]
        run = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if run.returncode != 0 or not out.is_file():
            lines = (run.stderr.strip() or "protoc failed").splitlines()
            # a located line first ("m.proto:3:1: Import ... was not found"), then the rest
            # (not absl's log lines: "W0000 00:00:17.. parser.cc:659] No edition or syntax")
            located = [line for line in lines if re.match(r"[^:]+:\d+:", line)
                       and not re.match(r"[IWEF]\d{4} ", line)]
            raise _protoc_error((located or lines)[0], path)
        return out.read_bytes()


def _protoc_error(text: str, path: Path) -> DcclSchemaError:
    """protoc's ``name:line:col: message`` as a located error."""
    parts = text.split(":", 3)
    if len(parts) == 4 and parts[1].isdigit():
        name = parts[0]
        shown = str(path) if Path(name).name == path.name else name
        return DcclSchemaError(parts[3].strip(), shown, int(parts[1]))
    return DcclSchemaError(text, str(path))


def _dccl_options(options: Any, cls: Any) -> dict[str, Any]:
    """The ``(dccl.*)`` extension (number 1012) of an options message, as a dict of set fields."""
    from google.protobuf import unknown_fields

    msg = cls()
    for item in unknown_fields.UnknownFieldSet(options):
        if item.field_number == _DCCL_EXTENSION:
            msg.MergeFromString(item.data)
    return _as_dict(msg)


def _as_dict(msg: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for desc, value in msg.ListFields():
        out[desc.name] = _as_dict(value) if desc.message_type is not None else value
    return out


@lru_cache(maxsize=64)
def _load_cached(path: str, mtime: float, proto_path: tuple[str, ...]) -> ProtoFile:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    file = Path(path)
    fds = descriptor_pb2.FileDescriptorSet.FromString(_run_protoc(file, proto_path))
    pool = descriptor_pool.DescriptorPool()
    for fdp in fds.file:
        pool.Add(fdp)
    try:
        field_type = pool.FindMessageTypeByName("dccl.DCCLFieldOptions")
        msg_type = pool.FindMessageTypeByName("dccl.DCCLMessageOptions")
    except KeyError:  # (a plain protobuf message: no DCCL options to read)
        raise DcclSchemaError('not a DCCL message file: it does not import '
                              '"dccl/option_extensions.proto" (a DCCL message needs its '
                              '(dccl.msg) id and max_bytes, and bounds on its fields)',
                              str(file)) from None
    field_cls = message_factory.GetMessageClass(field_type)
    msg_cls = message_factory.GetMessageClass(msg_type)
    enums: dict[str, tuple[tuple[str, int], ...]] = {}
    for fdp in fds.file:
        _collect_enums(fdp.package, fdp.enum_type, fdp.message_type, enums)
    result = ProtoFile(file)
    for fdp in fds.file:
        if fdp.name in ("google/protobuf/descriptor.proto", "dccl/option_extensions.proto"):
            continue
        shown = str(file) if fdp.name == file.name else fdp.name
        lines = {tuple(loc.path): loc.span[0] + 1 for loc in fdp.source_code_info.location}
        syntax = fdp.syntax or "proto2"
        for i, mdp in enumerate(fdp.message_type):
            _collect_message(mdp, fdp.package, (4, i), lines, shown, syntax, enums,
                             field_cls, msg_cls, result.messages)
    return result


def _collect_enums(prefix: str, enum_types: Any, message_types: Any,
                   out: dict[str, tuple[tuple[str, int], ...]]) -> None:
    for e in enum_types:
        out[f".{prefix}.{e.name}" if prefix else f".{e.name}"] = tuple(
            (v.name, v.number) for v in e.value)
    for m in message_types:
        inner = f"{prefix}.{m.name}" if prefix else m.name
        _collect_enums(inner, m.enum_type, m.nested_type, out)


def _collect_message(mdp: Any, prefix: str, path: tuple[int, ...], lines: dict[Any, Any],
                     file: str, syntax: str, enums: dict[str, Any], field_cls: Any, msg_cls: Any,
                     out: dict[str, MessageDef]) -> None:
    full = f"{prefix}.{mdp.name}" if prefix else mdp.name
    fields = []
    for j, fd in enumerate(mdp.field):
        label = {1: "optional", 2: "required", 3: "repeated"}[fd.label]
        if syntax == "proto3" and label == "optional" and not fd.proto3_optional:
            label = "implicit"
        fields.append(FieldDef(
            name=fd.name, number=fd.number, type=_TYPES[fd.type], label=label,
            options=_dccl_options(fd.options, field_cls),
            line=lines.get((*path, 2, j), lines.get(path, 0)), file=file,
            message_type=fd.type_name.lstrip(".") if fd.type in (10, 11) else None,
            enum_values=enums.get(fd.type_name, ()) if fd.type == 14 else (),
            oneof=(mdp.oneof_decl[fd.oneof_index].name
                   if fd.HasField("oneof_index") and not fd.proto3_optional else None),
        ))
    used = {f.oneof for f in fields if f.oneof is not None}
    oneofs = tuple(o.name for o in mdp.oneof_decl if o.name in used)
    out[full] = MessageDef(full, _dccl_options(mdp.options, msg_cls), tuple(fields),
                           lines.get(path, 0), file, syntax, oneofs)
    for k, nested in enumerate(mdp.nested_type):
        _collect_message(nested, full, (*path, 3, k), lines, file, syntax, enums,
                         field_cls, msg_cls, out)


def load_proto(path: str | Path, proto_path: Sequence[str | Path] = ()) -> ProtoFile:
    """Parse ``path`` (and its imports) with protoc; :class:`DcclSchemaError` if it is invalid.

    Imports are looked up in ``path``'s folder, then (``dccl/option_extensions.proto``) zab's
    statement of DCCL's options, then in each ``proto_path`` folder in order (as ``protoc -I``
    and ``dccl --proto_path`` take them)."""
    p = Path(path).resolve()
    if not p.is_file():
        raise DcclSchemaError("no such .proto file", str(path))
    folders = tuple(str(Path(d).resolve()) for d in proto_path)
    for given, folder in zip(proto_path, folders, strict=True):
        if not Path(folder).is_dir():
            raise DcclSchemaError(f"proto_path {str(given)!r} is not a folder", str(path))
    return _load_cached(str(p), p.stat().st_mtime, folders)
