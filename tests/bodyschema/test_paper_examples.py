"""The paper's worked examples, as tests: Eq. 44 / Appendix M, Eq. 45 / Appendix O, Eq. 20-21 / App. Q."""

from __future__ import annotations

from bodyschema.completion import complete
from bodyschema.conditions import check_p, check_p0
from bodyschema.convert import matrix_to_tree, tree_to_matrix
from bodyschema.correction import correct
from bodyschema.counting import count_trees, iter_trees
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import OutTree

E = ["e1", "e2", "e3", "e4", "e5"]


def test_eq44_grows_the_tree_of_appendix_m() -> None:
    D = DependencyMatrix(
        [[1, 0, 1, 1, 0], [1, 0, 0, 0, 0], [1, 0, 1, 0, 1], [1, 0, 1, 0, 0], [1, 1, 0, 0, 0]],
        rows=["a", "b", "c", "d", "f"],
        cols=E,
    )
    t = matrix_to_tree(D)
    # steps 1-5 of Appendix M: b on the root by e1; d, f under b by e3, e2; a, c under d by e4, e5
    expected = OutTree.from_node_parents(
        {"b": None, "d": "b", "f": "b", "a": "d", "c": "d"},
        {"b": "e1", "d": "e3", "f": "e2", "a": "e4", "c": "e5"},
    )
    assert t == expected
    assert [t.depth(n) for n in ["a", "b", "c", "d", "f"]] == [3, 1, 3, 2, 2]  # depths listed in App. M
    assert tree_to_matrix(t) == D


def test_eq45_is_completed_as_in_appendix_o() -> None:
    cols = ["c1", "c2", "c3", "c4", "c5", "c6"]
    D = DependencyMatrix([[1, 1, 1, 1, 1, 1], [1, 1, 1, 0, 0, 0]], ["a", "b"], cols)
    c = complete(D)
    # Appendix O picks c1 and c4, then fills c2, c3, c5, c6 with the new nodes c, d, e, f in turn:
    # c -> {c2}; d -> {c2, c3}; e -> {c1, c2, c3, c5}; f -> {c1, c2, c3, c5, c6} (Figures 22-25)
    got = c.matrix.to_sets()
    assert got["link:c2"] == ("c2",)
    assert got["link:c3"] == ("c2", "c3")
    assert got["link:c5"] == ("c1", "c2", "c3", "c5")
    assert got["link:c6"] == ("c1", "c2", "c3", "c5", "c6")
    assert got["a"] == tuple(cols) and got["b"] == ("c1", "c2", "c3")
    assert check_p(c.matrix).ok  # "reader can check such matrix is under condition set P"
    # not unique (Thm 3: N - K = 4 > 1): 3! orders of {c1,c2,c3} times 3! of {c4,c5,c6}
    assert not c.unique and c.count == 36 and c.labelled_count == 36 * 24


def test_eq20_is_rejected_and_corrected() -> None:
    D = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
    assert not check_p(D).ok and not check_p0(D).ok  # "has no corresponding heterogeneous out-tree"
    fix = correct(D)
    # brute force over all 96 trees with 3 joints: the nearest ones are at distance 2
    dists = {}
    for t in iter_trees(["e1", "e2", "e3"], ["a", "b", "c"]):
        M = tree_to_matrix(t)
        dists[M] = D.hamming(M)
    assert len(dists) == count_trees(3) == 96
    best = min(dists.values())
    assert fix.distance == best == 2
    assert set(fix.candidates) == {M for M, d in dists.items() if d == best}
    assert fix.trellis_distance is not None and fix.trellis_distance >= fix.distance
    for c in fix.candidates:
        assert check_p(c).ok
        matrix_to_tree(c)
