"""Fields of a payload that no channel carries (pure): reported, so an application learns that
part of what it publishes does not cross the water.

A channel's layouts name the fields they read by dotted paths (``pos.x``); whatever else a map
payload holds is left out. :func:`field_tree` gathers the paths of every layout reading a key
once; :func:`left_out` walks a payload against it.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

Tree = dict[str, Any] | bool
"""The fields read: a name → subtree map, or True where the whole value is read."""


def field_tree(paths: Iterable[str]) -> Tree:
    """The tree of the dotted ``paths`` (an empty path reads the whole payload)."""
    tree: dict[str, Any] = {}
    for path in paths:
        if not path:
            return True
        node: dict[str, Any] = tree
        *parents, leaf = path.split(".")
        for part in parents:
            child = node.get(part)
            if child is True:
                break
            node = node.setdefault(part, {})
        else:
            node[leaf] = True
    return tree


def whole_names(tree: Tree) -> frozenset[str]:
    """The top-level names ``tree`` reads whole: a map payload whose keys are all among them
    leaves nothing out (:func:`left_out` need not walk it)."""
    if not isinstance(tree, dict):
        return frozenset()
    return frozenset(name for name, sub in tree.items() if sub is True)


def left_out(value: Any, tree: Tree, prefix: str = "") -> list[str]:
    """The dotted paths of ``value`` that ``tree`` does not read (a non-map value: none)."""
    if tree is True or not isinstance(value, dict) or not isinstance(tree, dict):
        return []
    out: list[str] = []
    for name, item in value.items():
        sub = tree.get(name) if isinstance(name, str) else None
        if sub is None:
            out.append(f"{prefix}{name}")
        elif sub is not True:
            out += left_out(item, sub, f"{prefix}{name}.")
    return out
