"""Conversions between the body-schema representations, all in one place.

* :func:`tree_to_matrix` — Lemma 1: the dependency matrix of an out-tree.
* :func:`matrix_to_tree` — Alg. 1: grow the out-tree of a matrix that satisfies P (Thm 2).
* :func:`tree_to_topology` / :func:`topology_to_tree` — the topology JSON (docs/design.md, 'Topology JSON')
  via :class:`bodyschema.topology.Topology` (joint parents + which joint carries each IMU).
* :func:`tree_to_networkx` — a ``networkx.DiGraph`` for drawing and graph algorithms.

Example
-------
>>> from bodyschema.depmatrix import DependencyMatrix
>>> D = DependencyMatrix([[1, 0], [1, 1]], rows=["imu0", "imu1"], cols=["j1", "j2"])
>>> t = matrix_to_tree(D)
>>> t.node_parent("imu1"), t.incoming("imu1")
('imu0', 'j2')
>>> tree_to_matrix(t) == D
True
>>> topo = tree_to_topology(t)
>>> topo.joint_parent, topo.imu_joint
({'j1': None, 'j2': 'j1'}, {'imu0': 'j1', 'imu1': 'j2'})
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from bodyschema.conditions import InvalidMatrixError, check_p
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import DEFAULT_ROOT, LINK_PREFIX, OutTree, OutTreeError, link_label
from bodyschema.topology import Topology

if TYPE_CHECKING:
    import networkx as nx

__all__ = [
    "matrix_to_tree",
    "topology_to_tree",
    "tree_to_matrix",
    "tree_to_networkx",
    "tree_to_topology",
]


def tree_to_matrix(tree: OutTree, rows: Sequence[str] | None = None) -> DependencyMatrix:
    """The dependency matrix of ``tree`` (Lemma 1): ``D[i, j] = 1`` iff joint j is on the path to node i.

    ``rows`` picks and orders the node rows (default: every node, in joint order); leaving rows out gives
    the partially observed matrix of a robot whose links without sensors are unobserved.
    """
    rows = tree.nodes if rows is None else tuple(rows)
    col = {j: k for k, j in enumerate(tree.joints)}
    vals = np.zeros((len(rows), tree.n), dtype=bool)
    for i, node in enumerate(rows):
        for j in tree.path(node):
            vals[i, col[j]] = True
    return DependencyMatrix(vals, rows, tree.joints)


def matrix_to_tree(D: DependencyMatrix, root: str = DEFAULT_ROOT) -> OutTree:
    """Grow the out-tree of a square matrix that satisfies P (Alg. 1).

    Rows are taken by increasing depth; a depth-1 row hangs on the root by its only joint, any other
    row hangs under the already placed row that has exactly one 1 fewer, by the joint of that extra 1.
    Raises :class:`~bodyschema.conditions.InvalidMatrixError` (with the condition report) when ``D`` is
    not square or breaks P — complete a partial matrix (:func:`bodyschema.completion.complete`) or
    correct a noisy one (:func:`bodyschema.correction.correct`) first.
    """
    report = check_p(D)
    if not report.ok:
        raise InvalidMatrixError("matrix is not the dependency matrix of an out-tree", report)
    v = D.values
    depth = v.sum(axis=1)
    placed: dict[bytes, int] = {}
    node_parent: dict[str, str | None] = {}
    joint_of_node: dict[str, str] = {}
    for i in np.argsort(depth, kind="stable"):
        row = v[i]
        ones = np.flatnonzero(row)
        if depth[i] == 1:
            node_parent[D.rows[i]] = None
            joint_of_node[D.rows[i]] = D.cols[ones[0]]
        else:
            for c in ones:
                probe = row.copy()
                probe[c] = False
                k = placed.get(probe.tobytes())
                if k is not None:
                    node_parent[D.rows[i]] = D.rows[k]
                    joint_of_node[D.rows[i]] = D.cols[c]
                    break
            else:  # unreachable under P (Thm 2); kept as a guard against a wrong condition check
                raise InvalidMatrixError(f"row {D.rows[i]!r} has no parent row", report)
        placed[row.tobytes()] = int(i)
    # keep the joints in the matrix's column order
    order = {c: k for k, c in enumerate(D.cols)}
    nodes = sorted(joint_of_node, key=lambda n: order[joint_of_node[n]])
    return OutTree.from_node_parents(
        {n: node_parent[n] for n in nodes}, {n: joint_of_node[n] for n in nodes}, root=root
    )


def _default_imu_nodes(tree: OutTree) -> dict[str, str | None]:
    if tree.sensors:
        out: dict[str, str | None] = {}
        for node, imus in tree.sensors.items():
            for imu in imus:
                out[imu] = None if node == tree.root else node
        return out
    return {n: n for n in tree.nodes if not n.startswith(LINK_PREFIX)}


def tree_to_topology(
    tree: OutTree, imu_nodes: Mapping[str, str | None] | None = None, **fields: Any
) -> Topology:
    """The topology of ``tree`` (docs/design.md, 'Topology JSON').

    ``imu_nodes`` maps each IMU to the node (link label) it rides; ``None`` or the root label means the
    base link. Without it the tree's own ``sensors`` are used, and failing those every node whose label
    is not a ``link:<joint>`` placeholder is taken as one IMU (the usual case: rows of a dependency matrix
    are IMU names). Extra keyword arguments (``unique``, ``confidence``, ``method``, ``seconds``, ...)
    go to :class:`~bodyschema.topology.Topology`.
    """
    mapping = _default_imu_nodes(tree) if imu_nodes is None else dict(imu_nodes)
    jon = tree.joint_of_node
    imu_joint: dict[str, str | None] = {}
    for imu, node in mapping.items():
        if node is None or node == tree.root:
            imu_joint[imu] = None
        elif node in jon:
            imu_joint[imu] = jon[node]
        else:
            raise OutTreeError(f"IMU {imu!r} rides unknown node {node!r}")
    return Topology(joint_parent=tree.joint_parent, imu_joint=imu_joint, **fields)


def topology_to_tree(topo: Topology, root: str = DEFAULT_ROOT) -> OutTree:
    """The out-tree of a topology.

    The child link of each joint is labelled by the first IMU riding it (in ``imu_joint`` order) or
    ``link:<joint>`` when it carries none; ``sensors`` keeps every IMU per link (base IMUs under the
    root), so ``tree_to_topology(topology_to_tree(t))`` gives ``t``'s structure back.
    """
    riders: dict[str | None, list[str]] = {}
    for imu, j in topo.imu_joint.items():
        riders.setdefault(j, []).append(imu)
    node_of_joint = {j: (riders[j][0] if riders.get(j) else link_label(j)) for j in topo.joint_parent}
    sensors = {node_of_joint[j]: tuple(riders[j]) for j in topo.joint_parent if riders.get(j)}
    if riders.get(None):
        sensors[root] = tuple(riders[None])
    return OutTree.from_parents(topo.joint_parent, node_of_joint, root=root, sensors=sensors)


def tree_to_networkx(tree: OutTree) -> nx.DiGraph:
    """A ``networkx.DiGraph``: nodes are the root and the links, edges point parent -> child.

    Node attributes: ``kind`` (``"root"`` or ``"link"``), ``depth``, ``sensors``; edge attribute
    ``joint`` (the joint label). Graph attribute ``root``.

    >>> t = OutTree.from_parents({"j1": None, "j2": "j1"}, {"j1": "a", "j2": "b"})
    >>> g = tree_to_networkx(t)
    >>> sorted(g.edges(data="joint"))
    [('a', 'b', 'j2'), ('base', 'a', 'j1')]
    """
    import networkx as nx  # imported here: only callers who want a graph pay for networkx

    g = nx.DiGraph(root=tree.root)
    sensors = tree.sensors
    g.add_node(tree.root, kind="root", depth=0, sensors=sensors.get(tree.root, ()))
    for n in tree.nodes:
        g.add_node(n, kind="link", depth=tree.depth(n), sensors=sensors.get(n, ()))
    for n in tree.nodes:
        p = tree.node_parent(n)
        g.add_edge(tree.root if p is None else p, n, joint=tree.incoming(n))
    return g
