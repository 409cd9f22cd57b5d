"""Fields no channel reads: trees from the layouts' schemas, and the shortcut for a sample of
only fields read whole."""

from __future__ import annotations

import itertools
from typing import Any

from bridge.codec import Layout
from bridge.wire.unused import Tree, left_out, schema_tree, union, unread, whole_names


def tree(*paths: str) -> Tree:
    """The tree of a zab layout of float fields at ``paths``."""
    return schema_tree(Layout.from_fields([{"field": p, "bits": 4, "min": 0, "max": 1}
                                           for p in paths]).json_schema())


def test_a_sample_of_names_read_whole_leaves_nothing_out() -> None:
    trees = [tree("x", "y", "ok"), tree("pos.x", "pos.y", "t"), True, tree("a.b.c")]
    names = ["x", "y", "ok", "pos", "t", "a", "note"]
    values: list[object] = [{}, 3, [1, 2]]
    for n in range(1, 4):
        for keys in itertools.combinations(names, n):
            values.append(dict.fromkeys(keys, 1))
            values.append({k: {"x": 1, "z": 2} for k in keys})
    for one in trees:
        whole = whole_names(one)
        for value in values:
            if isinstance(value, dict) and value.keys() <= whole:
                assert left_out(value, one) == [], (one, value)
    assert whole_names(tree("pos.x", "t")) == {"t"}  # pos is read in part only
    assert left_out({"pos": {"x": 1, "z": 2}, "t": 0}, tree("pos.x", "t")) == ["pos.z"]
    assert whole_names(True) == frozenset()  # the whole payload: left_out says []


def test_trees_join_and_walk_into_lists() -> None:
    joined = union([tree("pos.x", "t"), tree("pos.y")])
    assert joined == {"pos": {"x": True, "y": True}, "t": True}
    assert union([joined, True]) is True
    items: dict[str, Any] = {"type": "object", "properties": {
        "legs": {"type": "array", "items": {"type": "object", "properties": {"d": {}}}}}}
    legs = schema_tree(items)
    assert legs == {"legs": {"d": True}}
    assert list(unread({"legs": [{"d": 1}, {"d": 2, "e": 3}], "f": 0}, legs)) == [
        ("legs.1.e", {"d": True}), ("f", legs)]
