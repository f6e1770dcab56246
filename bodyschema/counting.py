"""How many out-trees are there, and how to list or draw them (Property 5).

A heterogeneous out-tree with N joints is a rooted labelled tree on the N links plus the root — Cayley
gives ``(N+1)^(N-1)`` of them for one fixed pairing of links to joints — times the ``N!`` ways to pair
links with their incoming joints: ``(N+1)^(N-1) * N!`` trees, as many as there are N x N dependency
matrices. The joint tree alone (who hangs under whom, links unnamed) is also a rooted labelled forest
on the joints: ``(N+1)^(N-1)`` of those.

Trees are drawn and listed through Prüfer sequences over the vertices ``0..N`` (0 = root), which
makes :func:`random_tree` uniform over all trees and :func:`iter_parent_maps` exhaustive.

Example
-------
>>> count_trees(3), count_trees_per_pairing(3)
(96, 16)
>>> parents_from_prufer([0, 2], 3)
[0, 0, 2]
>>> sum(1 for _ in iter_parent_maps(["j1", "j2", "j3"]))
16
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Iterator, Sequence

import numpy as np

from bodyschema.outtree import DEFAULT_ROOT, OutTree, link_label

__all__ = [
    "count_trees",
    "count_trees_per_pairing",
    "iter_parent_maps",
    "iter_trees",
    "parents_from_prufer",
    "random_tree",
]


def count_trees(n: int) -> int:
    """Number of heterogeneous out-trees with n joints (Property 5): ``(n+1)^(n-1) * n!``."""
    if n < 0:
        raise ValueError("n must be >= 0")
    return count_trees_per_pairing(n) * math.factorial(n)


def count_trees_per_pairing(n: int) -> int:
    """Trees for one fixed link-joint pairing (Cayley, ``(n+1)^(n-1)``); also the number of joint trees."""
    if n < 0:
        raise ValueError("n must be >= 0")
    return 1 if n == 0 else (n + 1) ** (n - 1)


def parents_from_prufer(code: Sequence[int], n: int) -> list[int]:
    """Decode a Prüfer sequence (length n-1, entries in 0..n) of a tree on vertices 0..n, rooted at 0.

    Returns ``parent[v-1]`` for v = 1..n (0 = the root).
    """
    if n < 1:
        return []
    if len(code) != n - 1 or any(not 0 <= c <= n for c in code):
        raise ValueError(f"a Prüfer code for {n + 1} vertices has {n - 1} entries in 0..{n}")
    degree = [1] * (n + 1)
    for c in code:
        degree[c] += 1
    leaves = [v for v in range(n + 1) if degree[v] == 1]
    heapq.heapify(leaves)
    adj: list[list[int]] = [[] for _ in range(n + 1)]
    for c in code:
        leaf = heapq.heappop(leaves)
        adj[leaf].append(c)
        adj[c].append(leaf)
        degree[c] -= 1
        if degree[c] == 1:
            heapq.heappush(leaves, c)
    u, w = leaves
    adj[u].append(w)
    adj[w].append(u)
    parent = [-1] * (n + 1)
    stack, seen = [0], {0}
    while stack:
        x = stack.pop()
        for y in adj[x]:
            if y not in seen:
                seen.add(y)
                parent[y] = x
                stack.append(y)
    return parent[1:]


def _joint_parent(parents: Sequence[int], joints: Sequence[str]) -> dict[str, str | None]:
    return {j: (None if p == 0 else joints[p - 1]) for j, p in zip(joints, parents, strict=True)}


def iter_parent_maps(joints: Sequence[str]) -> Iterator[dict[str, str | None]]:
    """Every joint tree on ``joints`` (``joint -> parent joint``, None = base), each exactly once."""
    n = len(joints)
    if n == 0:
        yield {}
        return
    for code in itertools.product(range(n + 1), repeat=n - 1):
        yield _joint_parent(parents_from_prufer(code, n), joints)


def iter_trees(joints: Sequence[str], nodes: Sequence[str], root: str = DEFAULT_ROOT) -> Iterator[OutTree]:
    """Every out-tree with these joint and node labels: ``count_trees(len(joints))`` of them."""
    if len(nodes) != len(joints):
        raise ValueError("an out-tree has as many nodes as joints")
    for jp in iter_parent_maps(joints):
        for perm in itertools.permutations(nodes):
            yield OutTree.from_parents(jp, dict(zip(joints, perm, strict=True)), root=root)


def random_tree(
    joints: Sequence[str] | int,
    rng: np.random.Generator,
    nodes: Sequence[str] | None = None,
    root: str = DEFAULT_ROOT,
) -> OutTree:
    """A tree drawn uniformly from all out-trees with these labels (random Prüfer code and pairing).

    ``joints`` may be a count (joints are then named ``j0..j{n-1}``); ``nodes`` defaults to
    ``link:<joint>`` labels (the pairing is then the trivial one).

    >>> t = random_tree(5, np.random.default_rng(0), nodes=list("abcde"))
    >>> t.n, sorted(t.nodes)
    (5, ['a', 'b', 'c', 'd', 'e'])
    """
    names = [f"j{k}" for k in range(joints)] if isinstance(joints, int) else list(joints)
    n = len(names)
    code = rng.integers(0, n + 1, size=max(n - 1, 0)).tolist()
    jp = _joint_parent(parents_from_prufer(code, n), names)
    if nodes is None:
        node_of_joint = {j: link_label(j) for j in names}
    else:
        if len(nodes) != n:
            raise ValueError("an out-tree has as many nodes as joints")
        perm = rng.permutation(n)
        node_of_joint = {j: str(nodes[perm[k]]) for k, j in enumerate(names)}
    return OutTree.from_parents(jp, node_of_joint, root=root)
