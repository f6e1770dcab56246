"""Dilation and absorption on trees (Def. 6) and on matrices (Def. 7), and the reduction of Thm 1.

On a tree, *absorption* ``ab^{j->i}`` moves a leaf node i (parent j, not the root) with its incoming
joint onto the root; *dilation* ``di^{i->j}`` moves a depth-1 leaf i with its joint under node j. They
are inverse to each other (Lemma 2), keep the tree a tree (Cor. 1), and act on the dependency matrix
exactly as the row operations of Def. 7 do (Prop. 3):

* absorption: if rows S_i, S_j differ in exactly one entry and S_i is the longer, ``S_i := S_i xor S_j``;
* dilation:   if S_i has a single 1 and shares no 1 with S_j, ``S_i := S_i or S_j``.

The paper's Def. 7 says "otherwise do nothing"; here an inapplicable operation raises
:class:`OperationError` instead, so a caller that relies on a change cannot silently get none. Use
:func:`can_absorb` / :func:`can_dilate` to test first.

Def. 7 looks at two rows only. On a matrix that is not a tree matrix that is too weak for Thm 1: the
invalid matrix ``a={e1,e2}, b={e2,e3}, c={e1}`` becomes the valid ``a={e2}, b={e2,e3}, c={e1}`` by the
Def. 7 absorption ``ab^{c->a}``, so "reducible to a permutation matrix" would not imply "is a tree".
With ``leaf=True`` an operation also requires row i to be a leaf — the joint it gains or loses is in
no other row — which is what the tree operations of Def. 6 need; :func:`reduce_to_permutation` uses
leaf operations, and with them Thm 1 holds (tested exhaustively on 3 x 3 matrices).

Absorbing leaves deepest-first turns every tree into the depth-1 star, i.e. every dependency matrix
into a permutation matrix (Prop. 2, Thm 1); :func:`reduce_to_permutation` records the steps and
:meth:`Reduction.grow` replays the inverse dilations to get the matrix back.

Example
-------
>>> from bodyschema.depmatrix import DependencyMatrix
>>> D = DependencyMatrix([[1, 0, 0], [1, 1, 0], [1, 1, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
>>> r = reduce_to_permutation(D)
>>> r.permutation.values.astype(int).tolist()
[[1, 0, 0], [0, 1, 0], [0, 0, 1]]
>>> [(s.row, s.onto) for s in r.steps]
[('c', 'b'), ('b', 'a')]
>>> r.grow() == D
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import OutTree

__all__ = [
    "OperationError",
    "Reduction",
    "Step",
    "absorb",
    "absorb_tree",
    "can_absorb",
    "can_dilate",
    "dilate",
    "dilate_tree",
    "flatten_tree",
    "is_permutation",
    "reduce_to_permutation",
]


class OperationError(ValueError):
    """A dilation or absorption whose preconditions (Def. 6/7) do not hold."""


# ------------------------------------------------------------------------ trees (Def. 6)
def absorb_tree(tree: OutTree, node: str) -> OutTree:
    """``ab^{j->i}``: move leaf ``node`` (whose parent j is not the root) with its joint onto the root."""
    if not tree.is_leaf(node):
        raise OperationError(f"absorption needs a leaf; {node!r} has children {list(tree.children(node))}")
    if tree.node_parent(node) is None:
        raise OperationError(f"{node!r} already hangs on the root")
    jp = tree.joint_parent
    jp[tree.incoming(node)] = None
    return tree.replace(joint_parent=jp)


def dilate_tree(tree: OutTree, node: str, onto: str) -> OutTree:
    """``di^{i->j}``: move depth-1 leaf ``node`` with its joint under node ``onto``."""
    if tree.node_parent(node) is not None:
        raise OperationError(
            f"dilation needs a node on the root; {node!r} hangs under {tree.node_parent(node)!r}"
        )
    if not tree.is_leaf(node):
        raise OperationError(f"dilation needs a leaf; {node!r} has children {list(tree.children(node))}")
    if onto == node:
        raise OperationError("cannot dilate a node onto itself")
    jp = tree.joint_parent
    jp[tree.incoming(node)] = tree.incoming(onto)
    return tree.replace(joint_parent=jp)


def flatten_tree(tree: OutTree) -> tuple[OutTree, list[tuple[str, str]]]:
    """Absorb leaves deepest-first until the tree has depth 1 (Prop. 2).

    Returns the star and the ``(node, former parent)`` absorptions in order; dilating them back in
    reverse order rebuilds ``tree``.
    """
    steps: list[tuple[str, str]] = []
    cur = tree
    for node in sorted(tree.nodes, key=tree.depth, reverse=True):
        parent = cur.node_parent(node)
        if parent is not None:
            cur = absorb_tree(cur, node)
            steps.append((node, parent))
    return cur, steps


# --------------------------------------------------------------------- matrices (Def. 7)
def _rows(D: DependencyMatrix, i: str, j: str) -> tuple[int, int]:
    if i == j:
        raise OperationError("the two rows of an operation must differ")
    return D.row_index(i), D.row_index(j)


def _extra_col(v: np.ndarray, a: int, b: int) -> int:
    return int(np.flatnonzero(v[a] ^ v[b])[0])


def can_absorb(D: DependencyMatrix, i: str, j: str, leaf: bool = False) -> bool:
    """Whether ``ab^{j->i}`` applies: rows differ in one entry and row i has more ones.

    With ``leaf`` the joint row i drops must also appear in no other row (row i is a leaf).
    """
    a, b = _rows(D, i, j)
    v = D.values
    ok = int(np.count_nonzero(v[a] ^ v[b])) == 1 and int(v[a].sum()) > int(v[b].sum())
    if ok and leaf:
        ok = int(v[:, _extra_col(v, a, b)].sum()) == 1
    return ok


def can_dilate(D: DependencyMatrix, i: str, j: str, leaf: bool = False) -> bool:
    """Whether ``di^{i->j}`` applies: row i has a single one, not shared with row j.

    With ``leaf`` that single joint must also appear in no other row (row i is a leaf on the root).
    """
    a, b = _rows(D, i, j)
    v = D.values
    ok = int(v[a].sum()) == 1 and not bool((v[a] & v[b]).any())
    if ok and leaf:
        ok = int(v[:, int(np.flatnonzero(v[a])[0])].sum()) == 1
    return ok


def absorb(D: DependencyMatrix, i: str, j: str, leaf: bool = False) -> DependencyMatrix:
    """``ab^{j->i}(D)``: row i := row i xor row j (Def. 7).

    Raises :class:`OperationError` when inapplicable (see :func:`can_absorb` for ``leaf``).
    """
    if not can_absorb(D, i, j, leaf):
        raise OperationError(
            f"cannot absorb row {i!r} by row {j!r}: rows must differ in one entry, {i!r} the longer"
            + (", and the entry must be in no other row" if leaf else "")
        )
    a, b = D.row_index(i), D.row_index(j)
    v = D.values.copy()
    v[a] = v[a] ^ v[b]
    return D.with_values(v)


def dilate(D: DependencyMatrix, i: str, j: str, leaf: bool = False) -> DependencyMatrix:
    """``di^{i->j}(D)``: row i := row i or row j (Def. 7).

    Raises :class:`OperationError` when inapplicable (see :func:`can_dilate` for ``leaf``).
    """
    if not can_dilate(D, i, j, leaf):
        raise OperationError(
            f"cannot dilate row {i!r} onto row {j!r}: {i!r} needs a single 1, not shared with {j!r}"
            + (", in no other row" if leaf else "")
        )
    a, b = D.row_index(i), D.row_index(j)
    v = D.values.copy()
    v[a] = v[a] | v[b]
    return D.with_values(v)


def is_permutation(D: DependencyMatrix) -> bool:
    """True when ``D`` is square with exactly one 1 in every row and every column."""
    v = D.values
    return D.is_square and bool((v.sum(axis=0) == 1).all() and (v.sum(axis=1) == 1).all())


@dataclass(frozen=True)
class Step:
    """One absorption ``ab^{onto->row}``: row ``row`` was cut loose from row ``onto``."""

    row: str
    onto: str


@dataclass(frozen=True)
class Reduction:
    """A permutation matrix and the absorptions that led to it from ``original`` (Thm 1)."""

    original: DependencyMatrix
    permutation: DependencyMatrix
    steps: tuple[Step, ...]

    def pairing(self) -> dict[str, str]:
        """Row (node) -> column (its incoming joint), read off the permutation matrix."""
        v = self.permutation.values
        cols, rows = self.permutation.cols, self.permutation.rows
        return {r: cols[int(np.flatnonzero(v[k])[0])] for k, r in enumerate(rows)}

    def grow(self) -> DependencyMatrix:
        """Replay the inverse dilations, last absorption first: gives ``original`` back (Lemma 2)."""
        cur = self.permutation
        for s in reversed(self.steps):
            cur = dilate(cur, s.row, s.onto, leaf=True)
        return cur


def reduce_to_permutation(D: DependencyMatrix) -> Reduction:
    """Absorb leaf rows deepest-first until ``D`` is a permutation matrix (Thm 1).

    Every dependency matrix reduces (the deepest row is always a leaf whose parent row is one 1 shorter);
    a matrix that gets stuck is not one, and :class:`OperationError` says at which row.
    """
    if not D.is_square:
        raise OperationError(f"only square matrices reduce to a permutation matrix; shape is {D.shape}")
    v = D.values.copy()
    depth = v.sum(axis=1)
    steps: list[Step] = []
    for i in np.argsort(-depth, kind="stable"):
        if v[i].sum() <= 1:
            continue
        found = None
        for k in range(v.shape[0]):
            diff = v[i] ^ v[k]
            if k != i and int(np.count_nonzero(diff)) == 1 and v[k].sum() < v[i].sum():
                if int(v[:, int(np.flatnonzero(diff)[0])].sum()) == 1:  # leaf absorption only
                    found = k
                    break
        if found is None:
            raise OperationError(
                f"row {D.rows[i]!r} is no leaf with a row one entry shorter to be "
                "absorbed by; not a dependency matrix"
            )
        v[i] = v[i] ^ v[found]
        steps.append(Step(D.rows[i], D.rows[found]))
    out = D.with_values(v)
    if not is_permutation(out):
        raise OperationError(
            "absorption ended in a matrix that is not a permutation matrix; not a dependency matrix"
        )
    return Reduction(original=D, permutation=out, steps=tuple(steps))
