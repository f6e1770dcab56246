"""The out-tree type: construction, queries, validation, and the random-tree strategy other tests use
(:func:`tests.builders.trees`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings

from bodyschema.counting import random_tree
from bodyschema.outtree import OutTree, OutTreeError, link_label
from tests.builders import chain_and_branch, trees


def test_queries_on_a_known_tree() -> None:
    t = chain_and_branch()
    assert t.n == 4
    assert t.nodes == ("a", "b", "c", "d")
    assert t.path("d") == ("j1", "j2", "j4")
    assert t.ancestors("d") == ("b", "a")
    assert [t.depth(n) for n in t.nodes] == [1, 2, 2, 3]
    assert t.children(None) == ("a",)
    assert t.children("a") == ("b", "c")
    assert t.subtree("a") == ("a", "b", "d", "c")
    assert t.leaves() == ("c", "d")
    assert t.is_leaf("c") and not t.is_leaf("b")
    assert t.node_parent("a") is None and t.node_parent("d") == "b"
    assert t.incoming("c") == "j3"
    assert t.height() == 3


def test_default_nodes_are_link_labels() -> None:
    t = OutTree.from_parents({"j1": None, "j2": "j1"})
    assert t.nodes == (link_label("j1"), link_label("j2")) == ("link:j1", "link:j2")


def test_equality_is_structural_and_order_free() -> None:
    a = chain_and_branch()
    b = OutTree.from_parents(
        {"j4": "j2", "j3": "j1", "j2": "j1", "j1": None}, {"j4": "d", "j3": "c", "j2": "b", "j1": "a"}
    )
    assert a == b and hash(a) == hash(b)
    swapped = a.replace(node_of_joint={"j1": "a", "j2": "c", "j3": "b", "j4": "d"})
    assert swapped != a  # same shape, different pairing: a different heterogeneous tree (Fig. 5c)


@pytest.mark.parametrize(
    ("parents", "nodes", "message"),
    [
        ({"j1": "j2", "j2": "j1"}, None, "cycle"),
        ({"j1": None, "j2": "jx"}, None, "unknown joint"),
        ({"j1": "j1"}, None, "itself"),
        ({"j1": None, "j2": None}, {"j1": "a", "j2": "a"}, "same node label"),
        ({"j1": None}, {"j1": "base"}, "root label"),
        ({"j1": None, "j2": None}, {"j1": "a"}, "one node per joint"),
    ],
)
def test_bad_maps_are_rejected_with_a_reason(parents, nodes, message) -> None:
    with pytest.raises(OutTreeError, match=message):
        OutTree.from_parents(parents, nodes)


def test_from_node_parents_rejects_unknown_parent() -> None:
    with pytest.raises(OutTreeError, match="unknown node"):
        OutTree.from_node_parents({"a": None, "b": "zz"}, {"a": "j1", "b": "j2"})


def test_relabel_and_text() -> None:
    t = chain_and_branch().relabel(nodes={"a": "A"}, joints={"j1": "J1"})
    assert t.node_parent("b") == "A" and t.incoming("A") == "J1"
    assert t.to_text().splitlines()[:2] == ["base", "  -[J1]-> A"]


@settings(max_examples=60, deadline=None)
@given(trees())
def test_random_trees_are_consistent(t: OutTree) -> None:
    # depth = path length, parent's path is a prefix, every node reachable from the root exactly once
    seen = []
    stack = list(t.children(None))
    while stack:
        n = stack.pop()
        seen.append(n)
        stack.extend(t.children(n))
        p = t.node_parent(n)
        assert t.path(n) == (t.path(p) if p else ()) + (t.incoming(n),)
        assert t.depth(n) == len(t.path(n))
    assert sorted(seen) == sorted(t.nodes)


def test_random_tree_is_uniform_for_two_joints(rng: np.random.Generator) -> None:
    # 2 joints: 3 joint trees x 2 pairings = 6 trees, each should come up ~1/6 of the time
    counts: dict[OutTree, int] = {}
    for _ in range(3000):
        t = random_tree(["j1", "j2"], rng, nodes=["a", "b"])
        counts[t] = counts.get(t, 0) + 1
    assert len(counts) == 6
    assert all(350 < c < 650 for c in counts.values()), counts
