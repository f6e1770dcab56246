"""Dilation/absorption (Def. 6, 7): inverses (Lemma 2), commute with tree -> matrix (Prop. 3), Thm 1."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodyschema.conditions import check_p
from bodyschema.convert import tree_to_matrix
from bodyschema.counting import random_tree
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.operations import (
    OperationError,
    absorb,
    absorb_tree,
    can_absorb,
    can_dilate,
    dilate,
    dilate_tree,
    flatten_tree,
    is_permutation,
    reduce_to_permutation,
)
from bodyschema.outtree import OutTree
from tests.builders import chain_and_branch, trees


@settings(max_examples=100, deadline=None)
@given(trees(min_joints=2), st.data())
def test_absorption_and_dilation_are_inverse_and_commute_with_matrix(t: OutTree, data: st.DataObject) -> None:
    D = tree_to_matrix(t)
    inner_leaves = [n for n in t.leaves() if t.node_parent(n) is not None]
    if inner_leaves:
        i = data.draw(st.sampled_from(inner_leaves))
        j = t.node_parent(i)
        absorbed = absorb_tree(t, i)
        assert tree_to_matrix(absorbed) == absorb(D, i, j)  # Prop. 3 for absorption
        assert dilate_tree(absorbed, i, j) == t  # Lemma 2
        assert dilate(absorb(D, i, j), i, j) == D
    top_leaves = [n for n in t.leaves() if t.node_parent(n) is None]
    if top_leaves:
        i = data.draw(st.sampled_from(top_leaves))
        j = data.draw(st.sampled_from([n for n in t.nodes if n != i]))
        dilated = dilate_tree(t, i, j)
        assert tree_to_matrix(dilated) == dilate(D, i, j)  # Prop. 3 for dilation
        assert check_p(tree_to_matrix(dilated)).ok  # Cor. 1: still a tree
        assert absorb_tree(dilated, i) == t
        assert absorb(dilate(D, i, j), i, j) == D


@settings(max_examples=100, deadline=None)
@given(trees())
def test_every_tree_reduces_to_a_permutation_and_grows_back(t: OutTree) -> None:
    D = tree_to_matrix(t)
    r = reduce_to_permutation(D)
    assert is_permutation(r.permutation)
    assert r.pairing() == t.joint_of_node  # the reduction keeps the link-joint pairing
    assert r.grow() == D
    star, steps = flatten_tree(t)
    assert tree_to_matrix(star) == r.permutation and all(star.node_parent(n) is None for n in star.nodes)
    for node, parent in reversed(steps):
        star = dilate_tree(star, node, parent)
    assert star == t


def test_reduction_of_an_invalid_matrix_fails_clearly() -> None:
    bad = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
    with pytest.raises(OperationError, match="not a dependency matrix"):
        reduce_to_permutation(bad)
    with pytest.raises(OperationError, match="square"):
        reduce_to_permutation(bad.select_rows(["a"]))


def test_two_row_absorption_can_repair_an_invalid_matrix_but_leaf_absorption_cannot() -> None:
    # Def. 7 taken literally breaks Thm 1's "only if": an invalid matrix turns valid by one absorption
    bad = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 0]], ["a", "b", "c"], ["e1", "e2", "e3"])
    assert not check_p(bad).ok
    assert check_p(absorb(bad, "a", "c")).ok
    assert not can_absorb(bad, "a", "c", leaf=True)  # e2 is also in row b: a is no leaf
    with pytest.raises(OperationError, match="not a dependency matrix"):
        reduce_to_permutation(bad)


def test_leaf_reduction_succeeds_exactly_on_valid_3x3() -> None:
    # Thm 1 on all 512 binary 3x3 matrices: reducible to a permutation matrix <=> satisfies P
    names = ["a", "b", "c"]
    for code in range(512):
        v = ((code >> np.arange(9)) & 1).astype(bool).reshape(3, 3)
        D = DependencyMatrix(v, names, ["e1", "e2", "e3"])
        try:
            reduce_to_permutation(D)
            reducible = True
        except OperationError:
            reducible = False
        assert reducible == check_p(D).ok, D


def test_preconditions_are_enforced() -> None:
    t = chain_and_branch()  # a -> b -> d, a -> c
    with pytest.raises(OperationError, match="leaf"):
        absorb_tree(t, "b")
    with pytest.raises(OperationError, match="root"):
        absorb_tree(absorb_tree(t, "c"), "c")
    with pytest.raises(OperationError, match="on the root"):
        dilate_tree(t, "c", "d")
    with pytest.raises(OperationError, match="leaf"):
        dilate_tree(t, "a", "c")
    with pytest.raises(OperationError, match="itself"):
        dilate_tree(absorb_tree(t, "c"), "c", "c")
    D = tree_to_matrix(t)
    assert can_absorb(D, "d", "b") and not can_absorb(D, "d", "a")
    assert not can_dilate(D, "b", "c")
    star = tree_to_matrix(absorb_tree(absorb_tree(t, "d"), "c"))
    assert can_dilate(star, "c", "d") and can_dilate(star, "c", "d", leaf=True)
    assert can_dilate(star, "a", "c") and not can_dilate(star, "a", "c", leaf=True)  # a has child b
    with pytest.raises(OperationError):
        absorb(D, "d", "a")
    with pytest.raises(OperationError):
        dilate(D, "b", "c")
    with pytest.raises(OperationError, match="differ"):
        absorb(D, "d", "d")


def test_random_big_tree_reduction(rng: np.random.Generator) -> None:
    t = random_tree(80, rng, nodes=[f"n{k}" for k in range(80)])
    r = reduce_to_permutation(tree_to_matrix(t))
    assert len(r.steps) == sum(1 for n in t.nodes if t.depth(n) > 1)
    assert r.grow() == tree_to_matrix(t)
