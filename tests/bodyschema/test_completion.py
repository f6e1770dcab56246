"""Completion of partially observed matrices (Alg. 2, Thm 3) against brute force over all joint trees."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodyschema.completion import complete, count_completions
from bodyschema.conditions import InvalidMatrixError, check_p
from bodyschema.convert import matrix_to_tree, tree_to_matrix
from bodyschema.counting import iter_parent_maps, random_tree
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import OutTree
from tests.builders import trees


@functools.cache
def _families(n: int) -> list[tuple[dict[str, str | None], frozenset[frozenset[str]]]]:
    """Every joint tree on j0..j{n-1} with the set of its root paths (one per joint)."""
    joints = [f"j{k}" for k in range(n)]
    out = []
    for jp in iter_parent_maps(joints):
        paths = set()
        for j in joints:
            p, cur = set(), j
            while cur is not None:
                p.add(cur)
                cur = jp[cur]
            paths.add(frozenset(p))
        out.append((jp, frozenset(paths)))
    return out


def brute_force(partial: DependencyMatrix) -> list[dict[str, str | None]]:
    """Joint trees (on the partial's columns, named j0..) in which every observed row is a root path."""
    rows = [frozenset(partial.row_set(r)) for r in partial.rows]
    return [jp for jp, paths in _families(partial.shape[1]) if all(r in paths for r in rows)]


def _random_partial(rng: np.random.Generator, n: int, k: int) -> tuple[OutTree, DependencyMatrix]:
    t = random_tree(n, rng, nodes=[f"s{i}" for i in range(n)])
    keep = sorted(rng.choice(n, size=k, replace=False).tolist())
    return t, tree_to_matrix(t, rows=[t.nodes[i] for i in keep])


@settings(max_examples=80, deadline=None)
@given(trees(max_joints=25), st.data())
def test_completion_satisfies_p_and_keeps_observed_rows(t: OutTree, data: st.DataObject) -> None:
    keep = data.draw(st.lists(st.sampled_from(t.nodes), unique=True, max_size=t.n))
    partial = tree_to_matrix(t, rows=keep)
    seed = data.draw(st.integers(0, 2**31 - 1))
    for rng in (None, np.random.default_rng(seed)):
        c = complete(partial, rng=rng)
        assert c.matrix.shape == (t.n, t.n)
        assert check_p(c.matrix).ok
        assert c.matrix.select_rows(keep) == partial
        assert len(c.hidden) == t.n - len(keep)
        assert matrix_to_tree(c.matrix).n == t.n
    assert c.count >= 1 and c.unique == (c.count == 1)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_count_and_uniqueness_agree_with_brute_force(n: int, rng: np.random.Generator) -> None:
    cases = 12 if n < 6 else 4
    for _ in range(cases):
        k = int(rng.integers(0, n + 1))
        _, partial = _random_partial(rng, n, k)
        truth = brute_force(partial)
        c = complete(partial)
        assert c.count == len(truth), partial
        assert c.unique == (len(truth) == 1)
        assert count_completions(partial) == len(truth)
        if n <= 5:
            listed = [t.joint_parent for t in c.trees()]
            assert len(listed) == c.count
            assert sorted(map(sorted_items, listed)) == sorted(map(sorted_items, truth))
            mats = list(c.enumerate(limit=50))
            assert all(check_p(m).ok and m.select_rows(partial.rows) == partial for m in mats)
            assert len(set(mats)) == len(mats)


def sorted_items(d: dict[str, str | None]) -> list[tuple[str, str]]:
    return sorted((a, b or "") for a, b in d.items())


def test_theorem_3_verdict_versus_all_zero_hidden_column() -> None:
    # N - K = 1, the hidden link is a branching point: its column set is distinct and non-empty,
    # J_Sc is empty, and the filling is unique, as Thm 3 says
    t = OutTree.from_parents(
        {"j1": None, "j2": "j1", "j3": "j2", "j4": "j2"}, {"j1": "a", "j2": "h", "j3": "c", "j4": "d"}
    )
    c = complete(tree_to_matrix(t, rows=["a", "c", "d"]))
    assert c.unique and c.theorem3_unique and c.tree() == t.relabel(nodes={"h": "link:j2"})
    # N - K = 1, hidden joint with an all-0 column: J_Sc is empty too, but the link can hang under any
    # of the 3 nodes: Thm 3 would call it unique, brute force finds 3
    t2 = OutTree.from_parents({"j1": None, "j2": "j1", "j3": "j2"}, {"j1": "a", "j2": "b", "j3": "h"})
    c2 = complete(tree_to_matrix(t2, rows=["a", "b"]))
    assert c2.theorem3_unique and not c2.unique
    assert c2.count == 3 == len(brute_force(_renamed(c2.partial)))
    # N - K = 1 with a duplicate column: two orders of the run, not unique (Thm 3 agrees)
    t3 = OutTree.from_parents({"j1": None, "j2": "j1"}, {"j1": "h", "j2": "b"})
    c3 = complete(tree_to_matrix(t3, rows=["b"]))
    assert c3.count == 2 == len(brute_force(_renamed(c3.partial)))
    assert not c3.unique and not c3.theorem3_unique
    assert c3.labelled_count == 2


def _renamed(D: DependencyMatrix) -> DependencyMatrix:
    """The same matrix with columns named j0.. as brute_force expects."""
    return DependencyMatrix(D.values, D.rows, [f"j{k}" for k in range(D.shape[1])])


def test_labelled_count_is_count_times_hidden_permutations(rng: np.random.Generator) -> None:
    _, partial = _random_partial(rng, 7, 3)
    c = complete(partial)
    assert c.labelled_count == c.count * math.factorial(4)


def test_complete_square_and_invalid_inputs() -> None:
    t = OutTree.from_parents({"j1": None, "j2": "j1"}, {"j1": "a", "j2": "b"})
    D = tree_to_matrix(t)
    c = complete(D)
    assert c.matrix == D and c.unique and c.hidden == ()
    crossing = DependencyMatrix(
        [[1, 1, 0, 0], [0, 1, 1, 0], [1, 0, 1, 0]], ["a", "b", "c"], ["e1", "e2", "e3", "e4"]
    )
    with pytest.raises(InvalidMatrixError) as err:
        complete(crossing)
    assert err.value.report.failed == (5,)
    dup = DependencyMatrix([[1, 0, 0], [1, 0, 0]], ["a", "b"], ["e1", "e2", "e3"])
    with pytest.raises(InvalidMatrixError):
        complete(dup)
    assert count_completions(dup) == 0
    square_bad = DependencyMatrix([[1, 1], [1, 1]], ["a", "b"], ["e1", "e2"])
    with pytest.raises(InvalidMatrixError):
        complete(square_bad)


def test_no_rows_at_all() -> None:
    # nothing observed: every joint tree completes it
    D = DependencyMatrix(np.zeros((0, 3), dtype=bool), [], ["j0", "j1", "j2"])
    c = complete(D)
    assert c.count == 16 == len(brute_force(D))
