"""Fields of a payload that no channel carries (pure): reported, so an application learns that
part of what it publishes does not cross the water.

A channel's layout says what it reads by its JSON Schema (zab's own layouts and DCCL's alike):
:func:`schema_tree` turns one into a tree of the names read, :func:`union` joins the trees of
every layout reading a key, and :func:`left_out` walks a payload against it. ``zab put
--mission`` asks the same walk (:func:`unread`) for the names there are where one is unknown.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

Tree = dict[str, Any] | bool
"""The fields read: a name → subtree map, or True where the whole value is read. A list's
items are read by its tree (their indices are not named)."""


def schema_tree(schema: dict[str, Any]) -> Tree:
    """The names a layout's JSON ``schema`` reads: an object's properties, an array's items'."""
    if isinstance(properties := schema.get("properties"), dict):
        return {name: schema_tree(sub) for name, sub in properties.items()}
    if isinstance(items := schema.get("items"), dict):
        return schema_tree(items)
    return True


def union(trees: Iterable[Tree]) -> Tree:
    """What any of ``trees`` reads."""
    joined: dict[str, Any] = {}
    for tree in trees:
        if tree is True:
            return True
        assert isinstance(tree, dict)
        for name, sub in tree.items():
            joined[name] = union((joined[name], sub)) if name in joined else sub
    return joined


def whole_names(tree: Tree) -> frozenset[str]:
    """The top-level names ``tree`` reads whole: a map payload whose keys are all among them
    leaves nothing out (:func:`left_out` need not walk it)."""
    if not isinstance(tree, dict):
        return frozenset()
    return frozenset(name for name, sub in tree.items() if sub is True)


def unread(value: Any, tree: Tree, prefix: str = "") -> Iterator[tuple[str, dict[str, Any]]]:
    """Each dotted path of ``value`` that ``tree`` does not read, with the names read there."""
    if tree is True or not isinstance(tree, dict):
        return
    if isinstance(value, list):
        for i, item in enumerate(value):
            yield from unread(item, tree, f"{prefix}{i}.")
    elif isinstance(value, dict):
        for name, item in value.items():
            sub = tree.get(name) if isinstance(name, str) else None
            if sub is None:
                yield f"{prefix}{name}", tree
            elif sub is not True:
                yield from unread(item, sub, f"{prefix}{name}.")


def left_out(value: Any, tree: Tree) -> list[str]:
    """The dotted paths of ``value`` that ``tree`` does not read (a scalar value: none)."""
    return [path for path, _ in unread(value, tree)]
