"""Completing a partially observed dependency matrix (paper III-F/G, Alg. 2, Thm 3).

Links that carry no sensor have no row: the K x N matrix ``D⁻`` (K < N) of such a robot must be
filled up to an N x N matrix satisfying P before it names a tree. ``D⁻`` can be filled iff it satisfies
P⁻ = {1, 3, 5} (Thm 3); :func:`complete` runs Alg. 2 and says how many completions there are.

Hidden links are labelled ``link:<joint>`` after the joint that carries them (:func:`link_label`).

How many completions (``count``)? Group the columns by their column set S_c:

* a class of m columns with the same non-empty S_c is a run of m consecutive joints on one path, in any
  of m! orders (only the lowest one's child link can carry the sensor row of the class);
* a joint with an all-0 column carries a sensor-less subtree that can hang anywhere: z such joints
  attach to the n0 = N - z + 1 other nodes (root included) and to each other in n0 (N + 1)^(z - 1) ways.

So ``count = prod(m!) * [z > 0] n0 (N+1)^(z-1)``, counting distinct joint trees: completions that differ
only by which placeholder label sits on which hidden link are the same robot. The paper counts
labelled completions, where the N - K new rows carry arbitrary labels; that is ``labelled_count =
count * (N - K)!``. Thm 3 says the filling is unique "when N - K = 1 and one J_Sc is empty"; that
misses the all-0 column (its J_Sc is empty too, yet its link can hang under any of the N nodes), so
``unique`` here is ``count == 1``, checked against brute force, and :attr:`Completion.theorem3_unique`
keeps the paper's verdict for comparison.

Alg. 2 as printed sets row v to 1 in every column c' with S_c ⊆ S_c'. That gives duplicate rows when
c has duplicate columns; the worked example (Appendix O) uses "c and every proper superset", which is
what is done here. For an all-0 column that rule would put v under every non-empty column, which
breaks condition 5 on a branching tree, so such a link is hung on the root instead.

Example (Appendix O, Eq. 45)
----------------------------
>>> from bodyschema.depmatrix import DependencyMatrix
>>> D = DependencyMatrix([[1, 1, 1, 1, 1, 1], [1, 1, 1, 0, 0, 0]], ["a", "b"],
...                      ["c1", "c2", "c3", "c4", "c5", "c6"])
>>> c = complete(D)
>>> c.count, c.unique, c.labelled_count
(36, False, 864)
>>> c.matrix.row_set("link:c6")
('c1', 'c2', 'c3', 'c5', 'c6')
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from bodyschema.conditions import InvalidMatrixError, check_p, check_p_minus, unique_element_sets
from bodyschema.convert import matrix_to_tree, tree_to_matrix
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.outtree import DEFAULT_ROOT, OutTree, link_label

__all__ = ["Completion", "complete", "count_completions"]


@dataclass(frozen=True)
class _Classes:
    """Columns grouped by column set: the skeleton every completion shares."""

    sets: list[frozenset[str]]  # distinct non-empty column sets
    members: list[list[str]]  # columns of each class, in matrix column order
    sensor: list[str | None]  # the row whose J_Sc this class is (None: all hidden)
    parent: list[int | None]  # index of the smallest strict superset class
    zero: list[str]  # columns with an all-0 column set


def _classes(D: DependencyMatrix) -> _Classes:
    col_sets = {c: frozenset(D.col_set(c)) for c in D.cols}
    j_sets = unique_element_sets(D)
    sets: list[frozenset[str]] = []
    members: list[list[str]] = []
    sensor: list[str | None] = []
    index: dict[frozenset[str], int] = {}
    zero: list[str] = []
    for c in D.cols:
        s = col_sets[c]
        if not s:
            zero.append(c)
            continue
        if s not in index:
            index[s] = len(sets)
            sets.append(s)
            members.append([])
            sensor.append(None)
        k = index[s]
        members[k].append(c)
        if j_sets[c]:
            sensor[k] = next(iter(j_sets[c]))
    parent: list[int | None] = []
    for s in sets:
        sup = [k for k, t in enumerate(sets) if s < t]
        parent.append(min(sup, key=lambda k: len(sets[k])) if sup else None)
    return _Classes(sets, members, sensor, parent, zero)


def _count(cl: _Classes, n: int) -> int:
    total = 1
    for m in cl.members:
        total *= math.factorial(len(m))
    z = len(cl.zero)
    if z:
        n0 = n - z + 1
        total *= n0 * (n + 1) ** (z - 1)
    return total


def count_completions(partial: DependencyMatrix) -> int:
    """Number of distinct joint trees that complete ``partial`` (see the module notes); 0 if none."""
    if not check_p_minus(partial).ok:
        return 0
    if partial.is_square:
        return 1 if check_p(partial).ok else 0
    return _count(_classes(partial), partial.shape[1])


@dataclass(frozen=True)
class Completion:
    """The result of :func:`complete`.

    ``matrix`` is the N x N completion Alg. 2 builds (observed rows first, then one ``link:<joint>`` row
    per hidden link, in the order of their joints); ``count`` the number of distinct completions (joint
    trees) and ``unique`` whether that is 1; ``labelled_count`` the paper's count with labelled hidden
    rows; ``hidden`` the labels of the added rows. :meth:`enumerate` lists completions lazily.
    """

    partial: DependencyMatrix
    matrix: DependencyMatrix
    count: int
    hidden: tuple[str, ...]
    _classes: _Classes = field(repr=False)

    @property
    def unique(self) -> bool:
        return self.count == 1

    @property
    def labelled_count(self) -> int:
        return self.count * math.factorial(len(self.hidden))

    @property
    def theorem3_unique(self) -> bool:
        """Thm 3's verdict taken literally: N - K = 1 and some column has an empty J_Sc."""
        if len(self.hidden) == 0:
            return True
        js = unique_element_sets(self.partial)
        return len(self.hidden) == 1 and any(not j for j in js.values())

    def tree(self, root: str = DEFAULT_ROOT) -> OutTree:
        """The out-tree of :attr:`matrix`."""
        return matrix_to_tree(self.matrix, root=root)

    def trees(self, limit: int | None = None, root: str = DEFAULT_ROOT) -> Iterator[OutTree]:
        """Every completion as an out-tree (at most ``limit``), each exactly once."""
        cl = self._classes
        cols = self.partial.cols
        rank = {c: k for k, c in enumerate(cols)}
        produced = 0
        orders = [itertools.permutations(m) for m in cl.members]
        for perm in itertools.product(*orders):
            jp: dict[str, str | None] = {}
            node: dict[str, str] = {}
            bottom = [p[-1] for p in perm]
            for k, chain in enumerate(perm):
                par = cl.parent[k]
                above: str | None = None if par is None else bottom[par]
                for c in chain:
                    jp[c] = above
                    node[c] = link_label(c)
                    above = c
                if cl.sensor[k] is not None:
                    node[chain[-1]] = cl.sensor[k]  # type: ignore[assignment]
            for attach in _forests(cl.zero, list(jp)):
                full = {**jp, **attach}
                nodes = {**node, **{c: link_label(c) for c in cl.zero}}
                ordered = sorted(full, key=rank.__getitem__)
                yield OutTree.from_parents(
                    {c: full[c] for c in ordered}, {c: nodes[c] for c in ordered}, root=root
                )
                produced += 1
                if limit is not None and produced >= limit:
                    return

    def enumerate(self, limit: int | None = None) -> Iterator[DependencyMatrix]:
        """Every completion as an N x N matrix, at most ``limit``.

        Rows: the observed ones first, then that completion's hidden links in joint order. Which joints
        carry hidden links can differ between completions (a sensor row may sit below any joint of its
        class), so the hidden row labels can differ too.
        """
        observed = set(self.partial.rows)
        for t in self.trees(limit):
            rows = (*self.partial.rows, *(n for n in t.nodes if n not in observed))
            yield tree_to_matrix(t, rows=rows)


def _forests(free: list[str], fixed: list[str]) -> Iterator[dict[str, str | None]]:
    """Every way to hang the ``free`` joints under the root, a ``fixed`` joint or each other (no cycles)."""
    if not free:
        yield {}
        return
    choices: list[str | None] = [None, *fixed, *free]
    for pick in itertools.product(choices, repeat=len(free)):
        m = dict(zip(free, pick, strict=True))
        if any(m[c] == c for c in free):
            continue
        ok = True
        for c in free:  # follow parents among free joints; a repeat is a cycle
            seen = {c}
            cur = m[c]
            while cur in m:
                if cur in seen:
                    ok = False
                    break
                seen.add(cur)
                cur = m[cur]
            if not ok:
                break
        if ok:
            yield m


def complete(partial: DependencyMatrix, rng: np.random.Generator | None = None) -> Completion:
    """Fill a K x N matrix (K <= N) that satisfies P⁻ to an N x N matrix that satisfies P (Alg. 2).

    Alg. 2 picks one column per distinct non-empty J_Sc and gives every other column c a new hidden
    row with 1s in c and in every column whose set is a proper superset of S_c (see the module notes).
    Picks and order are the first in column order, or random when ``rng`` is given (any choice gives a
    valid completion). Raises :class:`~bodyschema.conditions.InvalidMatrixError` when ``partial``
    breaks P⁻ (or, when square, P).
    """
    report = check_p_minus(partial)
    if not report.ok:
        raise InvalidMatrixError("matrix cannot be completed (it breaks P-, Thm 3)", report)
    n = partial.shape[1]
    cl = _classes(partial)
    if partial.is_square:
        rep = check_p(partial)
        if not rep.ok:
            raise InvalidMatrixError("square matrix with no rows missing is not a dependency matrix", rep)
        return Completion(partial, partial, 1, (), cl)
    v = partial.values
    col = {c: k for k, c in enumerate(partial.cols)}
    picked: set[str] = set()
    for k, mem in enumerate(cl.members):
        if cl.sensor[k] is not None:
            js = unique_element_sets(partial)
            with_j = [c for c in mem if js[c]]
            picked.add(with_j[0] if rng is None else with_j[int(rng.integers(len(with_j)))])
    rest = [c for c in partial.cols if c not in picked]
    if rng is not None:
        rest = [rest[i] for i in rng.permutation(len(rest))]
    cur = v.copy()
    new_rows: list[np.ndarray] = []
    for c in rest:
        cur_all = np.vstack([cur, *new_rows]) if new_rows else cur
        s_c = cur_all[:, col[c]]
        row = np.zeros(n, dtype=bool)
        row[col[c]] = True
        if s_c.any():
            sizes = cur_all.sum(axis=0)
            contains = (cur_all[s_c].all(axis=0)) & (sizes > s_c.sum())  # proper supersets of S_c
            row |= contains
        new_rows.append(row)
    hidden = tuple(link_label(c) for c in rest)
    order = sorted(range(len(rest)), key=lambda i: col[rest[i]])
    full = np.vstack([v, *[new_rows[i] for i in order]])
    hidden_sorted = tuple(hidden[i] for i in order)
    matrix = DependencyMatrix(full, (*partial.rows, *hidden_sorted), partial.cols)
    return Completion(partial, matrix, _count(cl, n), hidden_sorted, cl)
