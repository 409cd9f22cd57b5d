"""Fields no channel reads: the shortcut for a sample of only fields read whole."""

from __future__ import annotations

import itertools

from bridge.wire.unused import field_tree, left_out, whole_names


def test_a_sample_of_names_read_whole_leaves_nothing_out() -> None:
    trees = [field_tree(p) for p in (["x", "y", "ok"], ["pos.x", "pos.y", "t"], [""], ["a.b.c"])]
    names = ["x", "y", "ok", "pos", "t", "a", "note"]
    values: list[object] = [{}, 3, [1, 2]]
    for n in range(1, 4):
        for keys in itertools.combinations(names, n):
            values.append(dict.fromkeys(keys, 1))
            values.append({k: {"x": 1, "z": 2} for k in keys})
    for tree in trees:
        whole = whole_names(tree)
        for value in values:
            if isinstance(value, dict) and value.keys() <= whole:
                assert left_out(value, tree) == [], (tree, value)
    assert whole_names(field_tree(["pos.x", "t"])) == {"t"}  # pos is read in part only
    assert left_out({"pos": {"x": 1, "z": 2}, "t": 0}, field_tree(["pos.x", "t"])) == ["pos.z"]
    assert whole_names(field_tree([""])) == frozenset()  # the whole payload: left_out says []
