"""Correcting an erroneous dependency matrix (paper III-H: MILP Eq. 22, trellis Alg. 3).

A matrix learned from noisy data may be no tree matrix at all (Eq. 20). :func:`correct` returns the
tree matrices nearest to it in Hamming distance:

1. **Pairing** — the permutation matrix I that shares the most 1s with D (Eq. 22), solved as a MILP
   (HiGHS through highspy in memory, or pulp with its bundled CBC). Every tree matrix contains its
   own permutation matrix (Thm 1), so I fixes a first guess of which link hangs on which joint.
2. **Trellis** — Alg. 3: from I, dilate depth-1 leaves one step at a time, keeping the matrices at the
   smallest distance (at most ``beam`` of them), until the distance stops falling.
3. **Local search** — the trellis can only add joints to rows and keeps the pairing of step 1, so a
   wrong early choice is never undone and it often stops above the optimum. Its result, the star I,
   two greedy trees (rows by depth, as Alg. 1 with a tolerance; joints by column-set containment) and
   ``restarts`` randomised greedy trees are each taken down by steepest descent over two moves whose
   cost change is computed for all candidates at once with a few matrix products: re-hanging a whole
   subtree under another node or the root (an absorption followed by a dilation, for subtrees), and
   swapping the joints of two links. At a local minimum the pairing is re-solved exactly twice (an
   assignment problem with the joint tree fixed, and with the link tree fixed). The best ``polish``
   end points then get a deeper look, at most ``max_rounds`` times in all: the least-bad moves and
   every parent/child rotation followed by re-pairing and descent, and a re-solve without each of the
   worst-fitting rows (a few flipped bits in one row can pin the search). Every distinct tree reached
   at the best distance is kept, up to ``beam``; ties are explored up to ``budget`` moves.

4. **Exact stage** — the search alone is a heuristic (the problem contains the NP-hard minimum-flip
   tree fitting) and it can stop above the optimum: on random trees with N/4 flipped bits it did in 4
   of 650 runs for N = 17..40 (e.g. N = 40 with 10 flips stopped at 12): the truth differed by a chain
   of links in another order, 3 or 4 joints passing round a cycle, plus re-hung subtrees, and every
   single move from there costs more. So :func:`bodyschema.tree_milp.nearest_tree_matrix` then looks
   for a tree matrix strictly closer than the search's best: a MILP over the matrix cells whose tree
   constraints (non-empty rows, distinct rows, nested-or-disjoint columns: P⁻) are added lazily as
   answers break them. It either proves the search's distance minimal (``Correction.certified``) or
   returns a closer tree, whose ties the search then gathers. Its work grows with the number of wrong
   bits, so it runs while that distance is at most N/2 and within fixed caps; past them the answer
   stays the search's, uncertified.

With it, all of those 650 runs (and 300 with N = 4..16) came back within the flips and certified, and
for N <= 5 the distance equals brute force over all trees (tests).

**Partial matrices** (R < N rows, links without sensors): the tree still has N links; the N - R hidden
links have no row and cost nothing, so the search may use them freely as intermediate nodes. (The
paper fills the missing rows with zeros and corrects the square matrix, which charges every hidden link
its depth and biases them toward the root; we do not.) Each candidate is then the corrected R x N
matrix — it satisfies P⁻ — and :meth:`Correction.completions` / :meth:`Correction.trees` give the
completed N x N matrices and trees (often several per candidate: see :mod:`bodyschema.completion`).
For partial input, ``permutation`` is R x N with one 1 per row and at most one per column.

Example (Eq. 20)
----------------
>>> from bodyschema.depmatrix import DependencyMatrix
>>> D = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
>>> fix = correct(D)
>>> fix.distance, len(fix.candidates), fix.certified
(2, 12, True)
>>> all(D.hamming(c) == 2 for c in fix.candidates)
True
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bodyschema.completion import Completion, complete
from bodyschema.conditions import check_p, check_p_minus
from bodyschema.convert import matrix_to_tree
from bodyschema.depmatrix import DependencyMatrix, DependencyMatrixError
from bodyschema.outtree import DEFAULT_ROOT, OutTree
from bodyschema.tree_milp import binary_lp, nearest_tree_matrix, quiet_highs
from bodyschema.tree_search import (
    Pool,
    Problem,
    State,
    column_greedy,
    complete_pairing,
    from_matrix,
    row_greedy,
    search,
    star,
    trellis_states,
)

__all__ = ["SOLVERS", "Correction", "correct", "nearest_permutation", "trellis"]

#: Solvers for Eq. 22: MILP through pulp, or the assignment problem it reduces to through scipy.
SOLVERS: tuple[str, ...] = ("highs", "cbc", "hungarian")


# ============================================================================ Eq. 22
def _assignment(v: np.ndarray, solver: str) -> np.ndarray:
    """col[i] for each row i of the (R, N) matrix v: the Eq. 22 optimum."""
    r, n = v.shape
    if solver == "hungarian":
        from scipy.optimize import linear_sum_assignment

        rows, cols = linear_sum_assignment(v.astype(np.int64), maximize=True)
        out = np.empty(r, dtype=np.int64)
        out[rows] = cols
        return out
    if solver not in ("highs", "cbc"):
        raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    if solver == "highs":
        return _highs_eq22(v)
    import pulp

    prob = pulp.LpProblem("nearest_permutation", pulp.LpMaximize)
    x = [[pulp.LpVariable(f"I_{i}_{j}", cat=pulp.LpBinary) for j in range(n)] for i in range(r)]
    # W_ij <= D_ij: where D is 0 the overlap W is 0, so only the W of D's ones are variables
    w = {
        (i, j): pulp.LpVariable(f"W_{i}_{j}", lowBound=0, upBound=1)
        for i in range(r)
        for j in range(n)
        if v[i, j]
    }
    prob += pulp.lpSum(w.values())
    for i in range(r):
        prob += pulp.lpSum(x[i]) == 1
    for j in range(n):
        col = pulp.lpSum(x[i][j] for i in range(r))
        prob += (col == 1) if r == n else (col <= 1)
    for (i, j), wij in w.items():
        prob += wij <= x[i][j]
    status = prob.solve(pulp.PULP_CBC_CMD(msg=False))
    if pulp.LpStatus[status] != "Optimal":
        raise RuntimeError(f"Eq. 22 solver {solver!r} ended with status {pulp.LpStatus[status]}")
    out = np.empty(r, dtype=np.int64)
    for i in range(r):
        out[i] = max(range(n), key=lambda j: x[i][j].value() or 0.0)
    return out


def _highs_eq22(v: np.ndarray) -> np.ndarray:
    """Eq. 22 handed to HiGHS (highspy) as arrays: the same MILP as the pulp model, built without
    pulp's per-variable Python objects, which dominate the time at N = 80."""
    import highspy
    from scipy.sparse import coo_matrix

    r, n = v.shape
    ones_i, ones_j = np.nonzero(v)
    n_i, n_w = r * n, len(ones_i)
    # columns: I (row-major, r*n binaries), then W for every 1 of D; rows: row sums, column sums, W <= I
    i_idx = np.arange(n_i)
    rr = np.concatenate([i_idx // n, r + i_idx % n, r + n + np.arange(n_w), r + n + np.arange(n_w)])
    cc = np.concatenate([i_idx, i_idx, n_i + np.arange(n_w), ones_i * n + ones_j])
    vals = np.concatenate([np.ones(2 * n_i), np.ones(n_w), -np.ones(n_w)])
    a = coo_matrix((vals, (rr, cc)), shape=(r + n + n_w, n_i + n_w))
    lp = binary_lp(
        np.concatenate([np.zeros(n_i), np.ones(n_w)]),
        [True] * n_i + [False] * n_w,
        np.concatenate([np.ones(r), np.full(n, 1.0 if r == n else 0.0), np.full(n_w, -np.inf)]),
        np.concatenate([np.ones(r + n), np.zeros(n_w)]),
        a,
        maximize=True,
    )
    h = quiet_highs()
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        raise RuntimeError(f"Eq. 22: HiGHS ended with {h.modelStatusToString(h.getModelStatus())}")
    x = np.asarray(h.getSolution().col_value[:n_i]).reshape(r, n)
    return np.argmax(x, axis=1).astype(np.int64)


def nearest_permutation(D: DependencyMatrix, solver: str = "highs") -> DependencyMatrix:
    """The permutation matrix sharing the most 1s with ``D`` (Eq. 22).

    ``solver``: ``"highs"`` (the MILP handed to HiGHS through highspy, in memory), ``"cbc"`` (the
    MILP built with pulp and solved by its bundled CBC; pulp writes the model to a temporary file) or
    ``"hungarian"`` (scipy's assignment solver: Eq. 22 is an assignment problem, whose LP relaxation
    is integral, so the optimum value is the same). For an R x N matrix (R < N) every row gets one
    column and every column at most one row.

    >>> from bodyschema.depmatrix import DependencyMatrix
    >>> D = DependencyMatrix([[1, 1], [0, 1]], ["a", "b"], ["e1", "e2"])
    >>> nearest_permutation(D).values.astype(int).tolist()
    [[1, 0], [0, 1]]
    """
    _check_shape(D)
    col = _assignment(D.values, solver)
    v = np.zeros(D.shape, dtype=bool)
    v[np.arange(D.shape[0]), col] = True
    return D.with_values(v)


def _check_shape(D: DependencyMatrix) -> None:
    r, n = D.shape
    if r > n:
        raise DependencyMatrixError(
            f"{r} rows but only {n} joints: merge duplicate rows (sensors on one link) first"
        )
    if n == 0:
        raise DependencyMatrixError("a matrix without joints has nothing to correct")


# ============================================================================ Alg. 3 alone
def trellis(D: DependencyMatrix, beam: int = 64, solver: str = "highs") -> tuple[int, list[DependencyMatrix]]:
    """Alg. 3 alone: the nearest permutation (Eq. 22), then one-step dilations while the distance falls.

    Returns the distance reached and the matrices at it (at most ``beam``). It keeps the pairing of
    Eq. 22 and never undoes a dilation, so it can stop above the optimum; :func:`correct` uses it as
    one start of its search.
    """
    _check_shape(D)
    pb = Problem(D.values)
    col = complete_pairing(pb, _assignment(D.values, solver))
    best, states = trellis_states(pb, col, beam)
    return best, [D.with_values(s.matrix(pb)) for s in states]


# ============================================================================ public API
@dataclass(frozen=True)
class Correction:
    """Result of :func:`correct`.

    ``candidates``: tree matrices at the minimal Hamming ``distance`` found, same labels and shape as
    the input (R x N candidates of a partial input satisfy P⁻, square ones satisfy P); at most ``beam``
    of them, ``truncated`` says more ties existed. ``permutation``: the Eq. 22 matrix. ``trellis_distance``:
    where Alg. 3 alone stopped, for comparison. ``certified``: ``distance`` is proven minimal (by the
    exact stage, :mod:`bodyschema.tree_milp`, or because the input is a tree matrix); ``lower_bound``:
    the distance no tree matrix can beat (equals ``distance`` when certified).
    """

    candidates: list[DependencyMatrix]
    distance: int
    permutation: DependencyMatrix
    truncated: bool = False
    trellis_distance: int | None = None
    certified: bool = False
    lower_bound: int = 0

    @property
    def best(self) -> DependencyMatrix:
        """The first candidate (candidates are ordered deterministically)."""
        return self.candidates[0]

    def completions(self) -> list[Completion]:
        """One :class:`~bodyschema.completion.Completion` per candidate (trivial for square input)."""
        return [complete(c) for c in self.candidates]

    def trees(self, limit: int | None = None, root: str = DEFAULT_ROOT) -> Iterator[OutTree]:
        """Every tree at the minimal distance: each candidate's completions, at most ``limit`` in all."""
        produced = 0
        for c in self.candidates:
            if c.is_square:
                trees: Iterator[OutTree] = iter([matrix_to_tree(c, root=root)])
            else:
                trees = complete(c).trees(root=root)
            for t in trees:
                yield t
                produced += 1
                if limit is not None and produced >= limit:
                    return


def correct(
    D: DependencyMatrix,
    beam: int = 64,
    solver: str = "highs",
    budget: int | None = None,
    restarts: int = 4,
    seed: int | np.random.Generator = 0,
    polish: int = 3,
    max_rounds: int = 6,
    exact: bool = True,
    exact_rounds: int = 40,
    exact_max_distance: int | None = None,
) -> Correction:
    """The tree matrices nearest to ``D`` in Hamming distance (Eq. 22 + Alg. 3 + local search).

    ``D`` is R x N with R <= N (rows missing for links without sensors; see the module notes for what
    a partial input returns). ``beam`` caps the candidates kept per distance level and the width of the
    search; ``budget`` caps the moves explored along ties (default ``2 * beam``). ``solver`` picks the
    Eq. 22 solver (:data:`SOLVERS`). An input that already is a tree matrix (P, or P⁻ when partial)
    comes back unchanged at distance 0.

    ``exact``: after the search, :func:`bodyschema.tree_milp.nearest_tree_matrix` looks for a tree
    matrix strictly closer than the search's best: it either proves the search's distance minimal
    (``certified``) or returns a closer tree, from which the search then gathers the ties. Its work
    grows with the number of wrong bits, so it runs only while the search's distance is at most
    ``exact_max_distance`` (default N // 2, at least 2: sparse errors, the case of a learned matrix
    with a few wrong entries), for at most ``exact_rounds`` HiGHS solves of bounded size; heavier
    noise keeps the search's answer uncertified.
    """
    _check_shape(D)
    if beam < 1:
        raise ValueError("beam must be >= 1")
    perm_cols = _assignment(D.values, solver)
    pm = np.zeros(D.shape, dtype=bool)
    pm[np.arange(D.shape[0]), perm_cols] = True
    permutation = D.with_values(pm)
    valid = check_p(D).ok if D.is_square else check_p_minus(D).ok
    if valid:
        return Correction([D], 0, permutation, False, 0, certified=True, lower_bound=0)
    pb = Problem(D.values)
    col = complete_pairing(pb, perm_cols)
    budget = 2 * beam if budget is None else budget
    tries = min(2 * pb.n, 48)
    trellis_best, trellis_kept = trellis_states(pb, col, min(beam, 4))
    pool = Pool(beam)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    starts = [column_greedy(pb), row_greedy(pb), trellis_kept[0], star(pb, col)]
    starts += [column_greedy(pb, rng) if k % 2 == 0 else row_greedy(pb, rng) for k in range(restarts)]
    ends: list[State] = []
    for start in starts:  # cheap descents from every start ...
        ends.append(search(pb, [start], pool, budget, 0, 0)[0])
    rounds = [max_rounds]
    for start in sorted(ends, key=lambda x: x.cost)[:polish]:  # ... the deeper look only from the best ends
        search(pb, [start], pool, budget, tries, rounds=rounds)
    certified, lower = False, 0
    limit = max(2, pb.n // 2) if exact_max_distance is None else exact_max_distance
    if exact and pool.best <= limit:
        res = nearest_tree_matrix(D.values, upper=pool.best, rounds=exact_rounds)
        certified, lower = res.optimal, res.lower
        if res.matrix is not None:  # strictly closer than the search: start the search's tie walk there
            s = from_matrix(pb, res.matrix, D)
            if s.cost != res.lower:
                raise AssertionError(f"exact tree at {s.cost}, MILP said {res.lower}")
            search(pb, [s], pool, budget, 0, 0)
    cands = sorted(pool.states.values(), key=lambda s: s.matrix(pb).tobytes(), reverse=True)
    out = [D.with_values(s.matrix(pb)) for s in cands]
    return Correction(out, pool.best, permutation, pool.truncated, trellis_best, certified, lower)
