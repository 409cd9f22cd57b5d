"""Generated documentation: the mission-file reference from the pydantic models, and each
backend's documentation from its module docstring with the table of its options' model
(:mod:`bridge.mission.backends`).

Used as an mkdocs hook (``hooks: [bridge/mission/reference.py]`` in ``mkdocs.yml``): a page that
contains ``<!-- zab:mission-reference -->`` or ``<!-- zab:backend:NAME -->`` gets the generated
text in its place, so the site can never disagree with the code.
"""

from __future__ import annotations

import importlib
import inspect
import json
import re
from typing import Any

from bridge.mission.backends import BACKEND_OPTIONS
from bridge.mission.model import Mission

MISSION_MARK = "<!-- zab:mission-reference -->"
BACKEND_MARK = re.compile(r"<!-- zab:backend:([a-z_]+) -->")
MODULE_MARK = re.compile(r"<!-- zab:doc:([a-z_.]+) -->")
BACKEND_MODULES = {"sim": "bridge.modems.sim", "udp": "bridge.modems.udp",
                   "evologics": "bridge.modems.evologics.driver",
                   "micromodem": "bridge.modems.micromodem.driver"}

__all__ = ["backend_reference", "mission_reference", "module_doc", "on_page_markdown"]


def _ref_name(ref: str) -> str:
    return ref.rsplit("/", 1)[-1]


def _anchor(name: str) -> str:
    return name.lower()


def _type(schema: dict[str, Any]) -> str:
    """A short human type for a property schema, linking to referenced sections."""
    if "$ref" in schema:
        name = _ref_name(schema["$ref"])
        return f"[{name}](#{_anchor(name)})"
    if "enum" in schema:
        return " \\| ".join(f"`{json.dumps(v)}`" for v in schema["enum"])
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    for key in ("anyOf", "oneOf"):
        if key in schema:
            parts = [_type(s) for s in schema[key] if s.get("type") != "null"]
            nullable = any(s.get("type") == "null" for s in schema[key])
            return " \\| ".join(parts) + (" or null" if nullable else "")
    kind = schema.get("type")
    if kind == "array":
        return f"list of {_type(schema.get('items', {}))}"
    if kind == "object":
        extra = schema.get("additionalProperties")
        if not isinstance(extra, dict) or not extra:
            extra = next(iter(schema.get("patternProperties", {}).values()), None)
        return f"map of name → {_type(extra)}" if isinstance(extra, dict) and extra else "map"
    return str(kind or "any")


def _bounds(schema: dict[str, Any]) -> str:
    words = {"minimum": "≥", "exclusiveMinimum": ">", "maximum": "≤", "exclusiveMaximum": "<",
             "minLength": "length ≥", "maxLength": "length ≤", "minItems": "items ≥",
             "pattern": "pattern"}
    found = []
    for sub in [schema, *schema.get("anyOf", [])]:
        for key, word in words.items():
            if key in sub:
                value = f"`{sub[key]}`" if key == "pattern" else sub[key]
                found.append(f"{word} {value}")
    return ", ".join(found)


_RST_ROLE = re.compile(r":(?:class|meth|func|attr|mod|data|exc):`~?([^`]+)`")


def rst_to_markdown(text: str) -> str:
    """Docstring markup as Markdown: ``code`` and :role:`name` become `code`."""
    return _RST_ROLE.sub(r"`\1`", text).replace("``", "`")


def _cell(text: str) -> str:
    text = rst_to_markdown(" ".join(text.split()))
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _section(name: str, schema: dict[str, Any], level: int = 3) -> list[str]:
    lines = [f"{'#' * level} {name}", ""]
    if schema.get("description"):
        lines += [_cell(schema["description"]), ""]
    properties = schema.get("properties", {})
    if not properties:
        return lines
    required = set(schema.get("required", []))
    lines += ["| key | type | default | description |", "|---|---|---|---|"]
    for key, prop in properties.items():
        default = "**required**" if key in required else (
            f"`{json.dumps(prop['default'])}`" if "default" in prop else "")
        description = prop.get("description", "")
        bounds = _bounds(prop)
        if bounds:
            description = f"{description} ({bounds})" if description else bounds
        lines.append(f"| `{key}` | {_type(prop)} | {default} | {_cell(description)} |")
    if schema.get("additionalProperties") is True:
        lines += ["", "Other keys are allowed here and passed through."]
    lines.append("")
    return lines


def mission_reference() -> str:
    """Markdown for every model of the mission file, top-level first, from the JSON Schema."""
    schema = Mission.model_json_schema(by_alias=True, mode="validation")
    defs: dict[str, Any] = schema.get("$defs", {})
    lines = _section("Mission (top level)", schema, 3)
    order: list[str] = []

    def visit(node: Any) -> None:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if ref is not None and _ref_name(ref) not in order:
                order.append(_ref_name(ref))
                visit(defs.get(_ref_name(ref), {}))
            for value in node.values():
                visit(value)
        elif isinstance(node, list):
            for value in node:
                visit(value)

    visit(schema.get("properties", {}))
    order += [name for name in defs if name not in order]
    for name in order:
        lines += _section(name, defs[name], 3)
    return "\n".join(lines)


def backend_reference(name: str) -> str:
    """A backend module's docstring (its options and behaviour) as Markdown, then the table of
    its options, which ``zab check`` holds a mission's to."""
    model = BACKEND_OPTIONS[name]
    table = _section(f"`{name}` options", model.model_json_schema(mode="validation"), 4)
    table[2:2] = ["Every option a mission gives this backend is checked when it is loaded: "
                  "an unknown name or a wrong value is an error of the file.", ""]
    return module_doc(BACKEND_MODULES[name]) + "\n\n" + "\n".join(table)


def module_doc(name: str) -> str:
    """A ``bridge`` module's docstring as Markdown (``::`` literal blocks stay indented)."""
    if not name.startswith("bridge."):
        raise ValueError(f"only bridge modules are documented here, not {name!r}")
    module = importlib.import_module(name)
    text = rst_to_markdown(inspect.cleandoc(module.__doc__ or f"`{name}`."))
    text = re.sub(r"::\n", ":\n\n", text)
    # a bulleted list needs a blank line before it in Markdown
    return re.sub(r"(?m)^((?!- )\S.*)\n(- )", r"\1\n\n\2", text)


def on_page_markdown(markdown: str, **_: Any) -> str:
    """mkdocs hook: fill the generated sections of a page."""
    if MISSION_MARK in markdown:
        markdown = markdown.replace(MISSION_MARK, mission_reference())
    markdown = BACKEND_MARK.sub(lambda m: backend_reference(m.group(1)), markdown)
    return MODULE_MARK.sub(lambda m: module_doc(m.group(1)), markdown)
