"""Read a mission file and explain every mistake with file, line, column and field path.

The model and the cross-references between its parts are checked here; what needs the
channel table or the MAC's timing is checked where a mission is loaded to run
(:mod:`bridge.core.loaded`), and located through :func:`located`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from bridge.errors import MissionError
from bridge.mission.model import Mission

Loc = tuple[str | int, ...]
Key = tuple[Any, ...]
"""A place in the YAML document: mapping keys (any scalar) and sequence indices."""
Marks = dict[Key, tuple[int, int]]


@dataclass(frozen=True)
class Problem:
    """One mistake in a mission file, where it is and what is wrong."""

    file: str
    line: int
    column: int
    path: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.column}"
        return f"{where}: {self.path}: {self.message}" if self.path else f"{where}: {self.message}"


class MissionProblems(MissionError):
    """An invalid mission file, its problems also as data (``zab check --json``)."""

    def __init__(self, problems: list[Problem]) -> None:
        super().__init__("\n".join(dict.fromkeys(map(str, problems))))
        self.problems = list({str(p): p for p in problems}.values())


MAX_DEPTH = 100
"""Levels of nesting a mission file may have (its deepest field is under ten)."""
MAX_VALUES = 1_000_000
"""Values (mappings, lists, scalars) a mission file may hold once its aliases are expanded
(a few hundred in the largest): a tiny file of aliases of aliases builds billions."""


def _build(node: yaml.Node, loc: Key, marks: Marks, constructor: yaml.SafeLoader) -> Any:
    """Turn a composed YAML node into Python data, remembering where each value starts;
    refuse (located) nesting deeper than :data:`MAX_DEPTH` and a scalar Python cannot hold
    (an integer of more than 4300 digits). (:func:`_count` first: aliases bounded.)"""
    if len(loc) > MAX_DEPTH:
        raise _located(marks, loc[:1], f"nested deeper than {MAX_DEPTH} levels: not a "
                       "mission", node)
    marks[loc] = (node.start_mark.line + 1, node.start_mark.column + 1)
    if isinstance(node, yaml.MappingNode):
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                raise _located(marks, loc, "unsupported key (a key is a name or a number, "
                               "not a list or a mapping)", key_node)
            key = _scalar(key_node, loc, marks, constructor)
            if not isinstance(key, str | int | float | bool) and key is not None:
                raise _located(marks, loc, f"unsupported key {key!r}", key_node)
            if key in out:
                raise _located(marks, loc, f"duplicate key {key!r}", key_node)
            marks[(*loc, key)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            out[key] = _build(value_node, (*loc, key), marks, constructor)
            marks[(*loc, key)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_build(item, (*loc, i), marks, constructor) for i, item in enumerate(node.value)]
    return _scalar(node, loc, marks, constructor)


def _count(node: yaml.Node, counted: dict[int, int], depth: int = 0) -> int:
    """How many values ``node`` builds, its aliases expanded (each node counted once:
    quick however many times it is aliased); stops past :data:`MAX_DEPTH` levels (a node
    that holds itself) and past :data:`MAX_VALUES` (:func:`_build` refuses both)."""
    if id(node) in counted:
        return counted[id(node)]
    total = 1
    if depth <= MAX_DEPTH and isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        for child in node.value:
            for part in child if isinstance(child, tuple) else (child,):
                total += _count(part, counted, depth + 1)
                if total > MAX_VALUES:
                    return total
    counted[id(node)] = total
    return total


def _scalar(node: yaml.Node, loc: Key, marks: Marks, constructor: yaml.SafeLoader) -> Any:
    """A scalar's value; one Python cannot hold (an integer of more than 4300 digits, a
    timestamp out of range) is refused where it is written."""
    try:
        return constructor.construct_object(node, deep=True)
    except (ValueError, OverflowError) as exc:
        why = str(exc).split(";")[0]  # (not Python's advice to raise its limit)
        raise _located(marks, loc, f"cannot read this value: {why}", node) from None


class _LocatedYamlError(Exception):
    def __init__(self, message: str, line: int, column: int) -> None:
        super().__init__(message)
        self.line, self.column = line, column


def _located(marks: Marks, loc: Key, message: str, node: yaml.Node) -> _LocatedYamlError:
    path = format_loc(loc)
    return _LocatedYamlError(
        f"{path + ': ' if path else ''}{message}",
        node.start_mark.line + 1,
        node.start_mark.column + 1,
    )


def format_loc(loc: Iterable[str | int]) -> str:
    """``("channels", 0, "elements", 1, "in")`` → ``channels[0].elements[1].in``."""
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _where(marks: Marks, loc: Loc) -> tuple[int, int]:
    """Line and column of the deepest part of ``loc`` that exists in the document."""
    for end in range(len(loc), -1, -1):
        if loc[:end] in marks:
            return marks[loc[:end]]
    return (1, 1)


def _describe(error: Mapping[str, Any]) -> str:
    message = str(error["msg"])
    if error["type"] == "extra_forbidden":
        return "unknown key (check its spelling and indentation)"
    if error["type"] == "missing":
        return "required key missing"
    if error["type"] == "finite_number":
        return (f"must be a finite number, not {error['input']!r} (.inf and .nan mean no "
                "number here: write the number meant)")
    if (error["type"] not in ("value_error", "assertion_error") and "input" in error
            and not (error["type"] == "zab_field" and error.get("ctx"))  # values in message
            and "(got " not in message):
        shown = repr(error["input"])
        if len(shown) > 40:
            shown = shown[:37] + "..."
        message += f" (got {shown})"
    return message.removeprefix("Value error, ")


def _compose(text: str) -> yaml.Node | None:
    """The YAML node tree, by libyaml when present (a 250-node mission: ~0.3 s → 0.08 s); a
    file it refuses is parsed again in Python, whose error messages the loader reports."""
    fast = getattr(yaml, "CSafeLoader", None)
    if fast is not None:
        try:
            return yaml.compose(text, Loader=fast)
        except yaml.YAMLError:
            pass
    return yaml.compose(text, Loader=yaml.SafeLoader)


def read_mission(text: str, path: str | Path = "<mission>") -> tuple[Mission, Marks]:
    """Mission ``text`` as a validated model, with where each of its values is written (for
    :func:`located`); raise :class:`MissionProblems` listing every problem of its YAML or of
    its model (the cross-references between its parts: :func:`cross_problems`)."""
    name = str(path)
    marks: Marks = {}
    try:
        root = _compose(text)
        if root is None:
            raise MissionError(f"{name}: the file is empty")
        if _count(root, {}) > MAX_VALUES:
            raise MissionError(f"{name}: invalid YAML: more than {MAX_VALUES:,} values (aliases "
                               "expand to that many): not a mission")
        data = _build(root, (), marks, yaml.SafeLoader(""))
    except _LocatedYamlError as exc:
        raise MissionProblems([Problem(name, exc.line, exc.column, "", str(exc))]) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, column = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise MissionProblems([Problem(name, line, column, "",
                                       f"invalid YAML: {exc.problem or exc}")]) from None
    except yaml.YAMLError as exc:
        raise MissionError(f"{name}: invalid YAML: {exc}") from None
    except RecursionError:  # (Python's parser, on a file libyaml refused)
        raise MissionError(f"{name}: invalid YAML: nested deeper than {MAX_DEPTH} levels: "
                           "not a mission") from None
    if not isinstance(data, dict):
        raise MissionProblems([Problem(name, 1, 1, "",
                                       "a mission file is a mapping (key: value), not a list")])

    try:
        mission = Mission.model_validate(data, context={"mission_dir": Path(path).parent})
    except ValidationError as exc:
        found = []
        for error in exc.errors():
            loc = tuple(p for p in error["loc"] if not _is_union_tag(p))
            found.append(Problem(name, *_where(marks, loc), format_loc(loc), _describe(error)))
        raise MissionProblems(found) from None
    return mission, marks


def located(name: str, marks: Marks, problems: Iterable[tuple[Loc, str]]) -> MissionProblems:
    """``problems`` (field path, message) of the mission file ``name``, with their lines."""
    return MissionProblems([Problem(name, *_where(marks, loc), format_loc(loc), msg)
                            for loc, msg in problems])


def _is_union_tag(part: str | int) -> bool:
    return isinstance(part, str) and (part in ("tdma", "none", "polled", "aloha", "{nodes}",
                                               "{learn}") or "[" in part)


def cross_problems(mission: Mission) -> Iterable[tuple[Loc, str]]:
    """Cross-references that a single model cannot check (those of the MAC are its own:
    :meth:`bridge.core.mac.Mac.problems`)."""
    seen: dict[int, str] = {}
    for name, node in mission.nodes.items():
        if node.address in seen:
            yield (("nodes", name, "address"),
                   f"address {node.address} already used by node {seen[node.address]!r}")
        seen.setdefault(node.address, name)
    for i, anchor in enumerate(mission.ranging.anchors or ()):
        if anchor not in mission.nodes:
            yield (("ranging", "anchors", i), f"unknown node {anchor!r}")
    for anchor in mission.ranging.anchor_keys:
        if anchor not in mission.nodes:
            yield (("ranging", "anchor_keys", anchor), f"unknown node {anchor!r}")
    ping = mission.ranging.ping
    for field in ("peers", "nodes"):
        for i, name in enumerate(getattr(ping, field) or () if ping is not None else ()):
            if name not in mission.nodes:
                yield (("ranging", "ping", field, i), f"unknown node {name!r}")


def read_mission_file(path: str | Path) -> str:
    """The text of the mission file at ``path``; MissionError when it cannot be read."""
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MissionError(f"{p}: no such mission file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionError(f"{p}: cannot read the mission file: {exc}") from None
