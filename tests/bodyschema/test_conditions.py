"""Conditions P, P0, P⁻ (Def. 10): reports, equivalence P <=> P0 (Prop. 5), and P <=> tree (Thm 2)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodyschema.conditions import (
    check,
    check_p,
    check_p0,
    check_p_minus,
    condition_table,
    unique_element_sets,
)
from bodyschema.convert import tree_to_matrix
from bodyschema.counting import count_trees, iter_trees, random_tree
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import OutTree
from tests.builders import trees

P_COLS = [1, 2, 3, 4, 5]
P0_COLS = [1, 2, 5, 6]


def _m(rows: list[list[int]]) -> DependencyMatrix:
    return DependencyMatrix(rows, [f"r{i}" for i in range(len(rows))], [f"c{k}" for k in range(len(rows[0]))])


@settings(max_examples=100, deadline=None)
@given(trees())
def test_every_tree_matrix_satisfies_p_and_p0(t: OutTree) -> None:
    D = tree_to_matrix(t)
    assert check_p(D).ok and check_p0(D).ok
    # J_Sc of a joint's column is exactly its child node (Def. 9 / proof of Thm 2)
    assert unique_element_sets(D) == {j: frozenset([n]) for j, n in t.node_of_joint.items()}


@settings(max_examples=60, deadline=None)
@given(trees(), st.data())
def test_any_row_subset_of_a_tree_matrix_satisfies_p_minus(t: OutTree, data: st.DataObject) -> None:
    keep = data.draw(st.lists(st.sampled_from(t.nodes), min_size=1, unique=True))
    assert check_p_minus(tree_to_matrix(t, rows=keep)).ok


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_exhaustive_small_matrices_valid_count_is_property_5(n: int) -> None:
    # all 2^(n*n) binary matrices: P <=> P0, and exactly (n+1)^(n-1) n! of them are valid (Thm 2 + Prop. 5)
    codes = np.arange(2 ** (n * n), dtype=np.int64)
    batch = ((codes[:, None] >> np.arange(n * n)) & 1).astype(bool).reshape(-1, n, n)
    table = condition_table(batch)
    p = table[:, P_COLS].all(axis=1)
    p0 = table[:, P0_COLS].all(axis=1)
    assert np.array_equal(p, p0)
    assert int(p.sum()) == count_trees(n)
    if n <= 3:
        names_r, names_c = [f"r{i}" for i in range(n)], [f"c{k}" for k in range(n)]
        from_trees = {
            tree_to_matrix(t).reorder(names_r, names_c).values.tobytes() for t in iter_trees(names_c, names_r)
        }
        assert from_trees == {m.tobytes() for m in batch[p]}


def test_p_iff_p0_on_many_random_square_matrices(rng: np.random.Generator) -> None:
    """>= 10,000 random binary matrices, drawn so that both valid and invalid ones are common."""
    agree = valid = invalid = 0
    for n in range(1, 13):
        for kind in ("dense", "near_tree"):
            b = 500
            if kind == "dense":
                dens = rng.uniform(0.05, 0.95, size=(b, 1, 1))
                batch = rng.random((b, n, n)) < dens
            else:
                batch = np.empty((b, n, n), dtype=bool)
                for k in range(b):
                    t = random_tree(n, rng, nodes=[f"r{i}" for i in range(n)])
                    batch[k] = tree_to_matrix(t).values
                flips = rng.integers(0, 3, size=b)  # 0, 1 or 2 flipped bits
                for k in np.flatnonzero(flips):
                    idx = rng.choice(n * n, size=min(int(flips[k]), n * n), replace=False)
                    batch[k].reshape(-1)[idx] ^= True
                # shuffle rows and columns: labels do not matter to the conditions (Property 1)
                batch = batch[:, rng.permutation(n)][:, :, rng.permutation(n)]
            table = condition_table(batch)
            p = table[:, P_COLS].all(axis=1)
            p0 = table[:, P0_COLS].all(axis=1)
            agree += int((p == p0).sum())
            assert np.array_equal(p, p0), np.flatnonzero(p != p0)
            valid += int(p.sum())
            invalid += int((~p).sum())
    assert agree >= 10_000
    assert valid > 2000 and invalid > 2000, (valid, invalid)


def test_reports_name_condition_and_place() -> None:
    D = _m([[1, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0], [1, 1, 0, 0]])
    rep = check_p(D)
    assert not rep.ok and rep.failed == (1, 2, 3, 4)
    by = {f.condition: f for f in rep.failures}
    assert by[1].rows == ("r1",)
    assert {f.cols for f in rep.failures if f.condition == 2} == {("c2",), ("c3",)}
    assert by[3].rows == ("r0", "r2")
    assert by[4].cols == ("c2", "c3")
    assert rep.counts[2] == 2
    assert "no all-0 rows" in str(rep)


def test_crossing_column_sets_and_unique_element_sets() -> None:
    # Eq. 20: columns overlap without nesting -> condition 5; every J_Sc has two rows -> condition 6
    D = _m([[1, 1, 0], [0, 1, 1], [1, 0, 1]])
    p, p0 = check_p(D), check_p0(D)
    assert p.failed == (5,) and p0.failed == (5, 6)
    assert {f.cols for f in p.failures} == {("c0", "c1"), ("c0", "c2"), ("c1", "c2")}
    assert next(f for f in p.failures if f.cols == ("c0", "c1")).rows == ("r0",)
    six = [f for f in p0.failures if f.condition == 6]
    expected = {"c0": {"r0", "r2"}, "c1": {"r0", "r1"}, "c2": {"r1", "r2"}}
    assert {f.cols[0]: set(f.rows) for f in six} == expected


def test_non_square_and_p_minus() -> None:
    partial = _m([[1, 1, 1, 1, 1, 1], [1, 1, 1, 0, 0, 0]])  # Eq. 45
    assert check_p(partial).failed[0] == 0
    assert check_p_minus(partial).ok
    too_many = _m([[1, 0], [0, 1], [1, 1]])
    assert 0 in check_p_minus(too_many).failed
    with pytest.raises(ValueError, match="unknown condition"):
        check(partial, (7,))


def test_condition_table_single_matrix_and_shapes() -> None:
    eye = np.eye(4, dtype=bool)
    assert condition_table(eye).shape == (1, 7)
    assert condition_table(eye[:3]).tolist()[0][0] is False
    with pytest.raises(ValueError):
        condition_table(np.zeros(3))


def test_permuted_identity_is_valid_for_every_permutation() -> None:
    for perm in itertools.permutations(range(4)):
        assert check_p(_m(np.eye(4, dtype=int)[list(perm)].tolist())).ok
