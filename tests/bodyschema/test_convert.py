"""Tree <-> matrix (Lemma 1, Alg. 1), tree <-> topology JSON, tree -> networkx, and the matrix type."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings

from bodyschema.conditions import InvalidMatrixError
from bodyschema.convert import (
    matrix_to_tree,
    topology_to_tree,
    tree_to_matrix,
    tree_to_networkx,
    tree_to_topology,
)
from bodyschema.depmatrix import DependencyMatrix, DependencyMatrixError
from bodyschema.outtree import OutTree, OutTreeError
from bodyschema.topology import Topology
from tests.builders import chain_and_branch, trees


def test_tree_to_matrix_known_tree() -> None:
    D = tree_to_matrix(chain_and_branch())
    assert D.rows == ("a", "b", "c", "d") and D.cols == ("j1", "j2", "j3", "j4")
    assert D.values.astype(int).tolist() == [[1, 0, 0, 0], [1, 1, 0, 0], [1, 0, 1, 0], [1, 1, 0, 1]]


@settings(max_examples=150, deadline=None)
@given(trees())
def test_tree_matrix_tree_is_identity(t: OutTree) -> None:
    D = tree_to_matrix(t)
    assert matrix_to_tree(D) == t
    # row sums are depths (Property 4), and a row/column shuffle is the same matrix (Property 1)
    assert D.depth() == {n: t.depth(n) for n in t.nodes}
    shuffled = D.reorder(rows=list(reversed(D.rows)), cols=sorted(D.cols))
    assert shuffled == D and matrix_to_tree(shuffled) == t


def test_matrix_to_tree_rejects_invalid_and_partial() -> None:
    bad = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
    with pytest.raises(InvalidMatrixError) as err:
        matrix_to_tree(bad)
    assert err.value.report.failed == (5,)
    partial = DependencyMatrix(
        [
            [1, 0],
        ],
        ["a"],
        ["e1", "e2"],
    )
    with pytest.raises(InvalidMatrixError) as err:
        matrix_to_tree(partial)
    assert 0 in err.value.report.failed


def test_partial_rows_of_a_tree() -> None:
    D = tree_to_matrix(chain_and_branch(), rows=["d", "a"])
    assert D.rows == ("d", "a") and D.row_set("d") == ("j1", "j2", "j4")


def test_topology_round_trip_with_imus_on_base_and_shared_links() -> None:
    topo = Topology(
        joint_parent={"j1": None, "j2": "j1", "j3": "j1"},
        imu_joint={"imu0": "j1", "imu1": "j2", "imu2": "j2", "imu3": None},
    )
    t = topology_to_tree(topo)
    # j3's link has no IMU: placeholder label; j2's link is named by its first IMU
    assert t.node_of_joint == {"j1": "imu0", "j2": "imu1", "j3": "link:j3"}
    assert t.sensors["imu1"] == ("imu1", "imu2") and t.sensors["base"] == ("imu3",)
    back = tree_to_topology(t, method="test")
    assert back.same_structure(topo) and back.method == "test"


def test_tree_to_topology_with_explicit_imu_map() -> None:
    t = chain_and_branch()
    topo = tree_to_topology(t, {"s1": "a", "s2": "d", "s3": None, "s4": "base"})
    assert topo.imu_joint == {"s1": "j1", "s2": "j4", "s3": None, "s4": None}
    assert topo.joint_parent == {"j1": None, "j2": "j1", "j3": "j1", "j4": "j2"}
    with pytest.raises(OutTreeError, match="unknown node"):
        tree_to_topology(t, {"s1": "zz"})


def test_default_imu_map_skips_placeholder_links() -> None:
    t = OutTree.from_parents({"j1": None, "j2": "j1"}, {"j1": "imu7", "j2": "link:j2"})
    assert tree_to_topology(t).imu_joint == {"imu7": "j1"}


def test_networkx_graph() -> None:
    g = tree_to_networkx(chain_and_branch())
    assert g.graph["root"] == "base"
    assert set(g.edges(data="joint")) == {
        ("base", "a", "j1"),
        ("a", "b", "j2"),
        ("a", "c", "j3"),
        ("b", "d", "j4"),
    }
    assert g.nodes["d"]["depth"] == 3 and g.nodes["base"]["kind"] == "root"
    import networkx as nx

    assert nx.is_arborescence(g)


# ------------------------------------------------------------------ the matrix type
def test_matrix_rejects_bad_input() -> None:
    with pytest.raises(DependencyMatrixError, match="binary"):
        DependencyMatrix([[0, 2]], ["a"], ["j1", "j2"])
    with pytest.raises(DependencyMatrixError, match="binary"):
        DependencyMatrix([[0.0, np.nan]], ["a"], ["j1", "j2"])
    with pytest.raises(DependencyMatrixError, match="shape"):
        DependencyMatrix([[0, 1]], ["a", "b"], ["j1", "j2"])
    with pytest.raises(DependencyMatrixError, match="duplicate"):
        DependencyMatrix([[0, 1]], ["a"], ["j1", "j1"])
    with pytest.raises(DependencyMatrixError, match="2-D"):
        DependencyMatrix([0, 1], ["a"], ["j1", "j2"])
    with pytest.raises(DependencyMatrixError, match="unknown joint"):
        DependencyMatrix.from_sets({"a": ["j9"]}, ["j1"])


def test_matrix_values_are_read_only_copies() -> None:
    src = np.array([[1, 0], [1, 1]])
    D = DependencyMatrix(src, ["a", "b"], ["j1", "j2"])
    src[0, 1] = 1
    assert not D.values[0, 1]
    with pytest.raises(ValueError):
        D.values[0, 0] = False


def test_matrix_equality_hamming_and_merge() -> None:
    D = DependencyMatrix([[1, 0], [1, 1]], ["a", "b"], ["j1", "j2"])
    E = DependencyMatrix([[1, 1], [0, 1]], ["b", "a"], ["j2", "j1"])
    assert D == E and hash(D) == hash(E)
    F = E.with_values([[1, 1], [1, 1]])
    assert D.hamming(F) == 1 and D != F
    assert D["b", "j2"] and not D["a", "j2"]
    m = DependencyMatrix([[1, 0], [0, 0], [1, 0]], ["x", "y", "z"], ["j1", "j2"]).merge_rows()
    assert m.matrix.rows == ("x",) and m.groups == {"x": ("x", "z")} and m.base_rows == ("y",)
    assert "1" in D.to_text() and D.from_sets(D.to_sets(), D.cols) == D
