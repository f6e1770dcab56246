"""The heterogeneous out-tree (paper III-D, Def. 4): the robot body as a labelled tree.

Nodes are links (labelled by the sensors riding them), edges are joints. Every non-root node has exactly
one incoming edge, so there are N nodes and N edges besides the root (Property 3), and each joint names
its child link one-to-one. The tree is therefore fixed by two maps:

* ``joint_parent``: joint -> the joint it hangs under (``None`` = mounted on the root/base link), the same
  convention as :class:`bodyschema.topology.Topology`;
* ``node_of_joint``: joint -> label of its child link (defaults to :func:`link_label` of the joint).

Two trees are equal when both maps and the root label agree (structure only; ``sensors`` is carried
along for conversions but does not take part in equality).

Example
-------
>>> t = OutTree.from_parents({"j1": None, "j2": "j1", "j3": "j1"}, {"j1": "a", "j2": "b", "j3": "c"})
>>> t.nodes, t.node_parent("b"), t.path("c")
(('a', 'b', 'c'), 'a', ('j1', 'j3'))
>>> t.children(None), t.leaves()
(('a',), ('b', 'c'))
>>> OutTree.from_node_parents({"a": None, "b": "a", "c": "a"}, {"a": "j1", "b": "j2", "c": "j3"}) == t
True
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["DEFAULT_ROOT", "LINK_PREFIX", "OutTree", "OutTreeError", "link_label"]

#: Label of the root node (the base link) unless a tree names another.
DEFAULT_ROOT = "base"
#: Prefix of the label given to a link that carries no sensor: ``link:<joint>``.
LINK_PREFIX = "link:"


def link_label(joint: str) -> str:
    """Label of the child link of ``joint`` when no sensor names it.

    >>> link_label("j3")
    'link:j3'
    """
    return f"{LINK_PREFIX}{joint}"


class OutTreeError(ValueError):
    """Maps that do not form a heterogeneous out-tree (cycle, unknown joint, duplicate node label)."""


class OutTree:
    """A heterogeneous out-tree: joints as labelled edges, links as labelled nodes, one root.

    Build it with :meth:`from_parents` or :meth:`from_node_parents`. Instances are immutable and hashable.
    ``sensors`` optionally maps node labels (and the root label) to the sensors riding that link.
    """

    __slots__ = (
        "_depth",
        "_joint_of_node",
        "_joint_parent",
        "_joints",
        "_node_of_joint",
        "_root",
        "_sensors",
    )

    def __init__(
        self,
        joint_parent: Mapping[str, str | None],
        node_of_joint: Mapping[str, str] | None = None,
        root: str = DEFAULT_ROOT,
        sensors: Mapping[str, Iterable[str]] | None = None,
    ) -> None:
        joints = tuple(str(j) for j in joint_parent)
        jp = {str(j): (None if p is None else str(p)) for j, p in joint_parent.items()}
        nj = _node_labels(joints, node_of_joint)
        labels = [nj[j] for j in joints]
        _check_parents_and_labels(jp, labels, root)
        depth = _depths(joints, jp)
        sens = _sensor_map(sensors, labels, root)
        self._joints = joints
        self._joint_parent = jp
        self._node_of_joint = {j: nj[j] for j in joints}
        self._joint_of_node = {n: j for j, n in self._node_of_joint.items()}
        self._root = str(root)
        self._depth = depth
        self._sensors = sens

    # ----------------------------------------------------------- builders
    @classmethod
    def from_parents(
        cls,
        joint_parent: Mapping[str, str | None],
        node_of_joint: Mapping[str, str] | None = None,
        root: str = DEFAULT_ROOT,
        sensors: Mapping[str, Iterable[str]] | None = None,
    ) -> OutTree:
        """From ``joint -> parent joint`` (None = on the base) and ``joint -> child node label``."""
        return cls(joint_parent, node_of_joint, root=root, sensors=sensors)

    @classmethod
    def from_node_parents(
        cls,
        node_parent: Mapping[str, str | None],
        joint_of_node: Mapping[str, str],
        root: str = DEFAULT_ROOT,
        sensors: Mapping[str, Iterable[str]] | None = None,
    ) -> OutTree:
        """From ``node -> parent node`` (None or the root label = root) and ``node -> incoming joint``."""
        if set(node_parent) != set(joint_of_node):
            raise OutTreeError("node_parent and joint_of_node must name the same nodes")
        jp: dict[str, str | None] = {}
        for n, p in node_parent.items():
            if p is None or p == root:
                jp[joint_of_node[n]] = None
            elif p not in joint_of_node:
                raise OutTreeError(f"node {n!r} hangs under unknown node {p!r}")
            else:
                jp[joint_of_node[n]] = joint_of_node[p]
        joints = list(joint_of_node.values())
        if len(set(joints)) != len(joints):
            raise OutTreeError("two nodes share one incoming joint")
        return cls(jp, {j: n for n, j in joint_of_node.items()}, root=root, sensors=sensors)

    # ------------------------------------------------------------- access
    @property
    def root(self) -> str:
        return self._root

    @property
    def joints(self) -> tuple[str, ...]:
        """Edge labels, in construction order."""
        return self._joints

    @property
    def nodes(self) -> tuple[str, ...]:
        """Non-root node labels, in the order of their incoming joints."""
        return tuple(self._node_of_joint[j] for j in self._joints)

    @property
    def n(self) -> int:
        """N: number of joints = number of non-root nodes."""
        return len(self._joints)

    @property
    def joint_parent(self) -> dict[str, str | None]:
        return dict(self._joint_parent)

    @property
    def node_of_joint(self) -> dict[str, str]:
        return dict(self._node_of_joint)

    @property
    def joint_of_node(self) -> dict[str, str]:
        return dict(self._joint_of_node)

    @property
    def sensors(self) -> dict[str, tuple[str, ...]]:
        """Node label (or root label) -> sensors riding that link, where known."""
        return dict(self._sensors)

    def _joint(self, node: str) -> str:
        try:
            return self._joint_of_node[node]
        except KeyError:
            raise OutTreeError(f"unknown node {node!r}") from None

    def node_parent(self, node: str) -> str | None:
        """Parent node of ``node`` (None = the root)."""
        p = self._joint_parent[self._joint(node)]
        return None if p is None else self._node_of_joint[p]

    def node_parents(self) -> dict[str, str | None]:
        return {n: self.node_parent(n) for n in self.nodes}

    def incoming(self, node: str) -> str:
        """The joint whose child link is ``node``."""
        return self._joint(node)

    def depth(self, node: str) -> int:
        """Number of joints between the root and ``node`` (a row sum of the matrix, Property 4)."""
        return self._depth[self._joint(node)]

    def path(self, node: str) -> tuple[str, ...]:
        """Joints from the root down to ``node`` (root side first)."""
        out: list[str] = []
        cur: str | None = self._joint(node)
        while cur is not None:
            out.append(cur)
            cur = self._joint_parent[cur]
        return tuple(reversed(out))

    def ancestors(self, node: str) -> tuple[str, ...]:
        """Nodes above ``node`` up to (not including) the root, nearest first."""
        return tuple(self._node_of_joint[j] for j in reversed(self.path(node)[:-1]))

    def children(self, node: str | None) -> tuple[str, ...]:
        """Child nodes of ``node`` (None or the root label = the root), in joint order."""
        pj = None if node is None or node == self._root else self._joint(node)
        return tuple(self._node_of_joint[j] for j in self._joints if self._joint_parent[j] == pj)

    def subtree(self, node: str) -> tuple[str, ...]:
        """``node`` and every node below it (depth first)."""
        out = [node]
        for c in self.children(node):
            out.extend(self.subtree(c))
        return tuple(out)

    def is_leaf(self, node: str) -> bool:
        j = self._joint(node)
        return all(self._joint_parent[k] != j for k in self._joints)

    def leaves(self) -> tuple[str, ...]:
        parents = set(self._joint_parent.values())
        return tuple(self._node_of_joint[j] for j in self._joints if j not in parents)

    def height(self) -> int:
        """Largest depth (0 for an empty tree)."""
        return max(self._depth.values(), default=0)

    # ------------------------------------------------------------ changes
    def replace(
        self,
        joint_parent: Mapping[str, str | None] | None = None,
        node_of_joint: Mapping[str, str] | None = None,
        sensors: Mapping[str, Iterable[str]] | None = None,
    ) -> OutTree:
        """A new tree with some maps replaced (the rest kept)."""
        return OutTree(
            self._joint_parent if joint_parent is None else joint_parent,
            self._node_of_joint if node_of_joint is None else node_of_joint,
            root=self._root,
            sensors=self._sensors if sensors is None else sensors,
        )

    def relabel(
        self, nodes: Mapping[str, str] | None = None, joints: Mapping[str, str] | None = None
    ) -> OutTree:
        """Rename nodes and/or joints (names not mentioned are kept)."""
        nm = dict(nodes or {})
        jm = dict(joints or {})
        jp = {jm.get(j, j): (None if p is None else jm.get(p, p)) for j, p in self._joint_parent.items()}
        nj = {jm.get(j, j): nm.get(n, n) for j, n in self._node_of_joint.items()}
        sens = {nm.get(n, n): s for n, s in self._sensors.items()}
        return OutTree(jp, nj, root=self._root, sensors=sens)

    # ----------------------------------------------------------- identity
    def _key(self) -> tuple[Any, ...]:
        return (
            self._root,
            tuple(sorted((j, p or "") for j, p in self._joint_parent.items())),
            tuple(sorted(self._node_of_joint.items())),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OutTree):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        parts = []
        for j in self._joints:
            p = self._joint_parent[j]
            src = self._root if p is None else self._node_of_joint[p]
            parts.append(f"{src}-[{j}]->{self._node_of_joint[j]}")
        return f"OutTree({', '.join(parts)})"

    def to_text(self) -> str:
        """An indented drawing, root first.

        >>> print(OutTree.from_parents({"j1": None, "j2": "j1"}, {"j1": "a", "j2": "b"}).to_text())
        base
          -[j1]-> a
            -[j2]-> b
        """
        lines = [self._root]

        def walk(node: str | None, indent: int) -> None:
            for c in self.children(node):
                lines.append(f"{'  ' * indent}-[{self._joint(c)}]-> {c}")
                walk(c, indent + 1)

        walk(None, 1)
        return "\n".join(lines)


def _node_labels(joints: tuple[str, ...], node_of_joint: Mapping[str, str] | None) -> dict[str, str]:
    """Each joint's child node label: ``node_of_joint``'s, checked to name one per joint, or the default."""
    if node_of_joint is None:
        return {j: link_label(j) for j in joints}
    nj = {str(j): str(n) for j, n in node_of_joint.items()}
    if set(nj) != set(joints):
        missing = sorted(set(joints) - set(nj))
        extra = sorted(set(nj) - set(joints))
        raise OutTreeError(f"node_of_joint must name one node per joint (missing {missing}, extra {extra})")
    return nj


def _check_parents_and_labels(jp: dict[str, str | None], labels: list[str], root: str) -> None:
    """Raise when a joint hangs under an unknown joint or itself, or two nodes share a label."""
    for j, p in jp.items():
        if p is not None and p not in jp:
            raise OutTreeError(f"joint {j!r} hangs under unknown joint {p!r}")
        if p == j:
            raise OutTreeError(f"joint {j!r} hangs under itself")
    if len(set(labels)) != len(labels):
        dup = sorted({n for n in labels if labels.count(n) > 1})
        raise OutTreeError(f"two joints carry the same node label: {dup}")
    if str(root) in set(labels):
        raise OutTreeError(f"node label {root!r} is the root label")


def _depths(joints: tuple[str, ...], jp: dict[str, str | None]) -> dict[str, int]:
    """Each joint's depth (1: on the root); raises on a cycle."""
    depth: dict[str, int] = {}
    for j in joints:
        chain: list[str] = []
        cur: str | None = j
        while cur is not None and cur not in depth:
            if cur in chain:
                raise OutTreeError(f"joint {j!r} is on a cycle")
            chain.append(cur)
            cur = jp[cur]
        base = 0 if cur is None else depth[cur]
        for k, c in enumerate(reversed(chain)):
            depth[c] = base + k + 1
    return depth


def _sensor_map(
    sensors: Mapping[str, Iterable[str]] | None, labels: list[str], root: str
) -> dict[str, tuple[str, ...]]:
    """The sensors on each node, checked to name known nodes only."""
    sens: dict[str, tuple[str, ...]] = {}
    if sensors is not None:
        known = set(labels) | {str(root)}
        for n, s in sensors.items():
            if n not in known:
                raise OutTreeError(f"sensors given for unknown node {n!r}")
            sens[str(n)] = tuple(str(x) for x in s)
    return sens
