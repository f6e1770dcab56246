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
from dataclasses import dataclass, field

import numpy as np

from bodyschema.completion import Completion, complete
from bodyschema.conditions import check_p, check_p_minus
from bodyschema.convert import matrix_to_tree
from bodyschema.depmatrix import DependencyMatrix, DependencyMatrixError
from bodyschema.outtree import DEFAULT_ROOT, OutTree
from bodyschema.tree_milp import binary_lp, nearest_tree_matrix, quiet_highs

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


# ============================================================================ search state
class _Problem:
    """Node space: node i < R is observed row i, nodes R..N-1 are hidden links (no row, no cost).

    ``mask`` switches rows off (they then cost nothing, like hidden links): used to look at the
    problem without a row whose flipped bits mislead the search.
    """

    def __init__(self, v: np.ndarray, mask: np.ndarray | None = None) -> None:
        self.r, self.n = v.shape
        self.v = v
        self.mask = np.ones(self.r, dtype=bool) if mask is None else mask
        pad = np.zeros((self.n, self.n), dtype=bool)
        pad[: self.r] = v
        self.pad = pad
        self.omega = np.zeros(self.n)
        self.omega[: self.r] = self.mask
        self.vm = (v & self.mask[:, None]).astype(np.int64)  # masked rows, for the re-pairings

    def without(self, row: int) -> _Problem:
        mask = self.mask.copy()
        mask[row] = False
        return _Problem(self.v, mask)

    def cost(self, col: np.ndarray, t: np.ndarray) -> int:
        diff = self.pad[: self.r][:, col] != t[: self.r]
        return int(np.count_nonzero(diff[self.mask]))


@dataclass
class _State:
    parent: np.ndarray  # parent node, -1 = root
    col: np.ndarray  # column (joint) of each node
    t: np.ndarray = field(init=False)  # t[r, a]: node a is on the root path of r (r itself included)
    cost: int = field(init=False)

    def finish(self, pb: _Problem) -> _State:
        n = len(self.parent)
        t = np.zeros((n, n), dtype=bool)
        depth = np.full(n, -1)
        order: list[int] = []
        children: list[list[int]] = [[] for _ in range(n)]
        roots = []
        for i, p in enumerate(self.parent):
            (roots if p < 0 else children[p]).append(i)
        stack = roots[:]
        while stack:
            x = stack.pop()
            order.append(x)
            stack.extend(children[x])
        if len(order) != n:
            raise AssertionError("search state is not a tree")
        for x in order:
            p = self.parent[x]
            if p >= 0:
                t[x] = t[p]
                depth[x] = depth[p] + 1
            t[x, x] = True
        self.t = t
        self.cost = pb.cost(self.col, t)
        return self

    def key(self) -> bytes:
        return self.parent.tobytes() + self.col.tobytes()

    def matrix(self, pb: _Problem) -> np.ndarray:
        """The (R, N) observed rows of this tree's matrix, in the problem's column order."""
        m = np.zeros((pb.r, pb.n), dtype=bool)
        m[:, self.col] = self.t[: pb.r]
        return m


def _new(pb: _Problem, parent: np.ndarray, col: np.ndarray) -> _State:
    return _State(parent.copy(), col.copy()).finish(pb)


def _with(pb: _Problem, parent: np.ndarray, col: np.ndarray, t: np.ndarray) -> _State:
    """A state whose ancestor matrix is already known (cheaper than :meth:`_State.finish`)."""
    s = _State(parent, col)
    s.t = t
    s.cost = pb.cost(col, t)
    return s


def _moves(pb: _Problem, s: _State) -> tuple[np.ndarray, np.ndarray]:
    """Cost changes of every move from ``s``: (N, N+1) re-hangs (last column = root), (N, N) swaps.

    Invalid moves are +inf. With W = omega (1 - 2A) the cost is const + sum(T * W), so moving the
    subtree of a under b changes it by sum over the subtree of W on b's path minus W on a's old path.
    """
    n = pb.n
    a = pb.pad[:, s.col].astype(float)
    w = pb.omega[:, None] * (1.0 - 2.0 * a)
    t = s.t.astype(float)
    g = t.T @ w  # g[a, x]: sum of W[r, x] over the subtree r of a
    strict = t - np.eye(n)
    base = (g * strict).sum(axis=1)
    rehang = np.empty((n, n + 1))
    rehang[:, :n] = g @ t.T - base[:, None]
    rehang[:, n] = -base
    rehang[:, :n][s.t.T] = np.inf  # b inside the subtree of a (includes b == a)
    cur = np.where(s.parent < 0, n, s.parent)
    rehang[np.arange(n), cur] = np.inf  # no-op
    c = (pb.omega[:, None] * a).T @ t  # c[x, y] = sum_r omega A[r, x] T[r, y]
    d = np.diag(c)
    swap = 2.0 * (d[:, None] + d[None, :] - c.T - c)
    swap[np.tril_indices(n)] = np.inf
    return rehang, swap


def _apply(pb: _Problem, s: _State, kind: int, i: int, j: int) -> _State:
    if kind == 1:  # swap the joints of links i and j: the link tree (and t) stays
        col = s.col.copy()
        col[i], col[j] = col[j], col[i]
        return _with(pb, s.parent, col, s.t)
    parent = s.parent.copy()
    parent[i] = -1 if j == pb.n else j
    t = s.t.copy()
    sub = s.t[:, i]  # links in the subtree of i
    keep = ~s.t[i]
    keep[i] = True  # rows below i keep i and what lies under it, lose i's old ancestors
    new_top = s.t[j] if j < pb.n else np.zeros(pb.n, dtype=bool)
    t[sub] = (s.t[sub] & keep) | new_top
    return _with(pb, parent, s.col, t)


@dataclass
class _Pool:
    """States at the best cost so far, one per distinct observed matrix, at most ``beam``."""

    beam: int
    best: int = 1 << 60
    states: dict[bytes, _State] = field(default_factory=dict)
    truncated: bool = False

    def offer(self, pb: _Problem, s: _State) -> bool:
        if s.cost < self.best:
            self.best, self.states, self.truncated = s.cost, {}, False
        if s.cost > self.best:
            return False
        k = s.matrix(pb).tobytes()
        if k in self.states:
            return False
        if len(self.states) >= self.beam:
            self.truncated = True
            return False
        self.states[k] = s
        return True


def _descend(pb: _Problem, starts: list[_State], pool: _Pool, budget: int) -> list[_State]:
    """Steepest descent with ties: improving moves reset the frontier; equal ones widen it (budget).

    Returns the states at the lowest cost this descent reached (at most ``pool.beam``).
    """
    best = min(s.cost for s in starts)
    frontier = [s for s in starts if s.cost == best]
    seen = {s.key() for s in frontier}
    reached: dict[bytes, _State] = {s.key(): s for s in frontier}
    for s in frontier:
        pool.offer(pb, s)
    plateau = 0
    while frontier:
        s = frontier.pop(0)
        rehang, swap = _moves(pb, s)
        dmin = min(float(rehang.min()), float(swap.min()))
        if not np.isfinite(dmin):
            continue
        target = s.cost + round(dmin)
        if target < best:
            best, frontier, plateau, reached = target, [], 0, {}
        elif target > best or s.cost != best or plateau >= budget:
            continue
        else:
            plateau += 1
        moves = [(0, int(i), int(j)) for i, j in zip(*np.nonzero(rehang == dmin), strict=True)]
        moves += [(1, int(i), int(j)) for i, j in zip(*np.nonzero(swap == dmin), strict=True)]
        improving = s.cost > best or dmin < 0
        created = 0
        for kind, i, j in moves:
            if created >= (8 if improving else 16) or (not improving and len(reached) >= pool.beam):
                break
            nxt = _apply(pb, s, kind, i, j)
            k = nxt.key()
            if k in seen:
                continue
            seen.add(k)
            created += 1
            pool.offer(pb, nxt)
            if nxt.cost == best and len(reached) < pool.beam:
                reached[k] = nxt
                frontier.append(nxt)
    return list(reached.values())


def _repair(pb: _Problem, s: _State) -> _State:
    """Keep the joint tree of ``s``, re-pair rows with joints optimally (an assignment problem).

    Row r placed on joint j costs ``|D_r xor path(j)|``; hidden links take the joints left over.
    """
    from scipy.optimize import linear_sum_assignment

    n, r = pb.n, pb.r
    jparent = np.full(n, -1)
    has = s.parent >= 0
    jparent[s.col[has]] = s.col[s.parent[has]]
    path = np.zeros((n, n), dtype=bool)  # path[j, k]: joint k on the root path of joint j
    path[np.ix_(s.col, s.col)] = s.t
    v = pb.vm
    cost = v.sum(axis=1)[:, None] + path.sum(axis=1)[None, :] - 2 * (v @ path.T.astype(np.int64))
    cost[~pb.mask] = 0
    rows, cols = linear_sum_assignment(cost)
    phi = np.empty(r, dtype=np.int64)
    phi[rows] = cols
    used = set(phi.tolist())
    col = np.concatenate([phi, np.array([j for j in range(n) if j not in used], dtype=np.int64)])
    node_at = np.empty(n, dtype=np.int64)
    node_at[col] = np.arange(n)
    parent = np.where(jparent[col] < 0, -1, node_at[np.maximum(jparent[col], 0)])
    return _with(pb, parent, col, path[np.ix_(col, col)])


def _repair_nodes(pb: _Problem, s: _State) -> _State:
    """Keep the link tree of ``s``, re-pair links with joints optimally (an assignment problem).

    Giving joint j to link a puts j on the path of every row below a, which costs
    ``sum over r in subtree(a) of (1 - 2 D[r, j])``.
    """
    from scipy.optimize import linear_sum_assignment

    t_obs = (s.t[: pb.r] & pb.mask[:, None]).astype(np.int64)  # (R, N) t[r, a], masked rows off
    v = pb.vm
    cost = t_obs.sum(axis=0)[:, None] - 2 * (t_obs.T @ v)  # (nodes, joints)
    rows, cols = linear_sum_assignment(cost)
    col = np.empty(pb.n, dtype=np.int64)
    col[rows] = cols
    return _with(pb, s.parent, col, s.t)


def _escape(pb: _Problem, s: _State, tries: int, deep: int = 12) -> list[_State]:
    """Look one move past a local minimum: the ``tries`` least-bad moves, each followed by an optimal
    re-pairing (both kinds); for the first ``deep`` of them that do not help at once, a full descent
    from there. Returns the states found below ``s.cost`` (empty when none)."""
    rehang, swap = _moves(pb, s)
    flat = np.concatenate([rehang.ravel(), swap.ravel()])
    k = min(tries, int(np.isfinite(flat).sum()))
    if k == 0:
        return []
    pick = np.argpartition(flat, k - 1)[:k]
    out: dict[bytes, _State] = {}
    _escape_by_moves(pb, s, rehang, swap, pick, deep, out)
    _escape_by_rotations(pb, s, out)
    return list(out.values())


def _keep_below(out: dict[bytes, _State], ys: tuple[_State, ...], cost: int) -> None:
    """Record in ``out`` (keyed by state) each of ``ys`` that costs less than ``cost``, in order."""
    for y in ys:
        if y.cost < cost:
            out[y.key()] = y


def _escape_by_moves(
    pb: _Problem,
    s: _State,
    rehang: np.ndarray,
    swap: np.ndarray,
    pick: np.ndarray,
    deep: int,
    out: dict[bytes, _State],
) -> None:
    """The move half of :func:`_escape`: apply each picked move (flat index over rehang then swap),
    re-pair both ways, and while nothing has helped yet descend fully from the best of them (at most
    ``deep`` times)."""
    for f in pick:
        if f < rehang.size:
            x = _apply(pb, s, 0, *(int(u) for u in np.unravel_index(f, rehang.shape)))
        else:
            x = _apply(pb, s, 1, *(int(u) for u in np.unravel_index(f - rehang.size, swap.shape)))
        ys = (x, _repair(pb, x), _repair_nodes(pb, x), _repair_nodes(pb, _repair(pb, x)))
        _keep_below(out, ys, s.cost)
        if not out and deep > 0:
            deep -= 1
            _keep_below(out, (_quick(pb, min(ys, key=lambda z: z.cost)),), s.cost)


def _escape_by_rotations(pb: _Problem, s: _State, out: dict[bytes, _State]) -> None:
    """The rotation half of :func:`_escape`: each link trades places with its parent (two variants),
    then re-pairing; a full descent from the best of them when nothing has helped yet."""
    for c in np.flatnonzero(s.parent >= 0):  # rotations: a link trades places with its parent p
        p = int(s.parent[c])
        for others_move, kids_move in ((False, True), (False, False)):
            parent = s.parent.copy()
            if others_move:  # p's other children follow p's old place (now c's)
                parent[s.parent == p] = c
            if kids_move:  # c's children follow c's old place (now p's)
                parent[s.parent == c] = p
            parent[c], parent[p] = s.parent[p], c
            x = _new(pb, parent, s.col)
            ys = (x, _repair(pb, x), _repair_nodes(pb, x))
            _keep_below(out, ys, s.cost)
            low = min(ys, key=lambda z: z.cost)
            if not out and low.cost <= s.cost + 1:
                _keep_below(out, (_quick(pb, low),), s.cost)


def _quick(pb: _Problem, s: _State) -> _State:
    """Plain steepest descent (one best move at a time, then re-pairing) to a local minimum."""
    while True:
        rehang, swap = _moves(pb, s)
        if min(float(rehang.min()), float(swap.min())) < 0:
            if rehang.min() <= swap.min():
                i, j = np.unravel_index(int(np.argmin(rehang)), rehang.shape)
                s = _apply(pb, s, 0, int(i), int(j))
            else:
                i, j = np.unravel_index(int(np.argmin(swap)), swap.shape)
                s = _apply(pb, s, 1, int(i), int(j))
            continue
        y = min((_repair(pb, s), _repair_nodes(pb, s)), key=lambda z: z.cost)
        if y.cost >= s.cost:
            return s
        s = y


def _leave_out(pb: _Problem, s: _State, rows: int) -> list[_State]:
    """Re-solve without each of the ``rows`` worst-fitting rows, then with it again.

    A few flipped bits in one row can pin the search (its spurious 1s make a joint look higher up than
    it is); without that row the rest of the matrix decides, and putting it back costs only its own
    mismatches. Returns the states found below ``s.cost``.
    """
    diff = (pb.pad[: pb.r][:, s.col] != s.t[: pb.r]) & pb.mask[:, None]
    bad = diff.sum(axis=1)
    # worst-fitting rows first, but rows that fit perfectly count too: a row whose own flipped bits
    # pulled the tree its way fits that tree exactly and leaves the mismatches to the others
    order = [int(i) for i in np.argsort(-bad, kind="stable")[:rows]]
    for i in order:
        pr = pb.without(i)
        for x0 in (_with(pr, s.parent, s.col, s.t), _column_greedy(pr)):
            x = _quick(pr, x0)
            y = _quick(pb, _with(pb, x.parent, x.col, x.t))
            if y.cost < s.cost:
                return [y]
    return []


def _search(
    pb: _Problem,
    starts: list[_State],
    pool: _Pool,
    budget: int,
    tries: int,
    leave: int = 8,
    rounds: list[int] | None = None,
) -> list[_State]:
    """Alternate descent and optimal re-pairing (fixed joint tree, fixed link tree); at a local minimum
    look one move further (:func:`_escape`); stop when nothing gets below the best cost."""
    states = starts
    while True:
        reached = _descend(pb, states, pool, budget)
        if not reached:
            return states
        cost = reached[0].cost
        better: dict[bytes, _State] = {}
        for s in reached[:8]:
            for x in (_repair(pb, s), _repair_nodes(pb, s)):
                if x.cost < cost:
                    better[x.key()] = x
        deep_ok = rounds is None or rounds[0] > 0
        if not better and tries and deep_ok:
            if rounds is not None:
                rounds[0] -= 1
            better.update((x.key(), x) for x in _escape(pb, reached[0], tries))
        if not better and leave and deep_ok:
            better.update((x.key(), x) for x in _leave_out(pb, reached[0], leave))
        if not better:
            return reached
        low = min(x.cost for x in better.values())
        states = [x for x in better.values() if x.cost == low]


# ============================================================================ starts
def _star(pb: _Problem, col: np.ndarray) -> _State:
    return _new(pb, np.full(pb.n, -1), col)


def _row_greedy(pb: _Problem, rng: np.random.Generator | None = None) -> _State:
    """Alg. 1 made tolerant: rows by depth; each under the placed row whose path it matches best.

    Row r goes under p (or the root) minimising ``|path(p)| - 2 |D_r and path(p)|`` and takes an unused
    joint it has a 1 in (any unused one if none); leftover joints become hidden links on the root.
    """
    n, r = pb.n, pb.r
    v = pb.v
    tie = rng.random(max(r, n)) if rng is not None else np.zeros(max(r, n))
    order = sorted(range(r), key=lambda i: (int(v[i].sum()), tie[i], i))
    used = np.zeros(n, dtype=bool)
    path = np.zeros((r, n), dtype=bool)
    parent = np.full(n, -1)
    col = np.full(n, -1, dtype=np.int64)
    placed: list[int] = []
    for i in order:
        if placed:
            pl = np.array(placed)
            score = path[pl].sum(axis=1) - 2 * (path[pl] & v[i]).sum(axis=1)
            k = int(np.argmin(score + 0.5 * tie[pl]))
            p = int(pl[k]) if score[k] < 0 else -1
        else:
            p = -1
        base = path[p] if p >= 0 else np.zeros(n, dtype=bool)
        free = ~used & ~base
        pick = np.flatnonzero(free & v[i])
        j = int(pick[0]) if pick.size else int(np.flatnonzero(free)[0])
        used[j] = True
        col[i], parent[i] = j, p
        path[i] = base
        path[i, j] = True
        placed.append(i)
    col[r:] = np.flatnonzero(~used)
    return _new(pb, parent, col)


def _column_greedy(pb: _Problem, rng: np.random.Generator | None = None) -> _State:
    """A joint tree from the column sets, then the best pairing for it.

    Joints go in by decreasing column size; joint j hangs under the placed joint k (or the root) that
    minimises, over the rows of S_j, the mismatches on the joints placed so far:
    ``sum over x on k's path of (|S_j| - 2 |S_j and S_x|)``.
    """
    n = pb.n
    v = pb.vm  # rows switched off by the mask do not vote
    overlap = v.T @ v  # |S_j and S_x|
    size = np.diag(overlap)
    tie = rng.random(n) if rng is not None else np.zeros(n)
    order = sorted(range(n), key=lambda j: (-size[j], tie[j], j))
    jparent = np.full(n, -1)
    path = np.zeros((n, n), dtype=bool)
    placed: list[int] = []
    for j in order:
        if placed:
            pl = np.array(placed)
            score = path[pl].astype(np.int64) @ (size[j] - 2 * overlap[j])
            k = int(np.argmin(score + 0.5 * tie[pl]))
            if score[k] < 0:
                jparent[j] = pl[k]
                path[j] = path[pl[k]]
        path[j, j] = True
        placed.append(j)
    return _repair(pb, _new(pb, jparent, np.arange(n, dtype=np.int64)))


def _trellis_states(pb: _Problem, col: np.ndarray, beam: int) -> tuple[int, list[_State]]:
    """Alg. 3 in node space: level by level, dilate depth-1 leaves, keep the best ``beam`` states."""
    start = _star(pb, col)
    level = [start]
    best, kept = start.cost, [start]
    while True:
        children: dict[bytes, _State] = {}
        g = None
        for s in level:
            rehang, _ = _moves(pb, s)
            leaf_on_root = (s.parent < 0) & (s.t.sum(axis=0) == 1)
            d = rehang[:, : pb.n].copy()
            d[~leaf_on_root] = np.inf
            m = float(d.min()) if d.size else np.inf
            if not np.isfinite(m):
                continue
            if g is None or m < g:
                g, children = m, {}
            if m > g:
                continue
            for i, j in zip(*np.nonzero(d == m), strict=True):
                if len(children) >= beam:
                    break
                nxt = _apply(pb, s, 0, int(i), int(j))
                children.setdefault(nxt.key(), nxt)
        if not children:
            break
        cost = next(iter(children.values())).cost
        if cost >= best:
            break
        best, level = cost, list(children.values())
        kept = level
    return best, kept


def trellis(D: DependencyMatrix, beam: int = 64, solver: str = "highs") -> tuple[int, list[DependencyMatrix]]:
    """Alg. 3 alone: the nearest permutation (Eq. 22), then one-step dilations while the distance falls.

    Returns the distance reached and the matrices at it (at most ``beam``). It keeps the pairing of
    Eq. 22 and never undoes a dilation, so it can stop above the optimum; :func:`correct` uses it as
    one start of its search.
    """
    _check_shape(D)
    pb = _Problem(D.values)
    col = _complete_pairing(pb, _assignment(D.values, solver))
    best, states = _trellis_states(pb, col, beam)
    return best, [D.with_values(s.matrix(pb)) for s in states]


def _complete_pairing(pb: _Problem, row_cols: np.ndarray) -> np.ndarray:
    """Extend the rows' columns to all N nodes: hidden links take the unused columns in order."""
    used = set(row_cols.tolist())
    free = [j for j in range(pb.n) if j not in used]
    return np.concatenate([row_cols, np.array(free, dtype=np.int64)]).astype(np.int64)


def _from_matrix(pb: _Problem, m: np.ndarray, D: DependencyMatrix) -> _State:
    """The search state of a P⁻ matrix ``m`` (R x N): completed to N x N first when rows are missing.

    In a tree matrix the smallest column set holding row i is i's own joint and the next smallest
    belongs to i's parent (the column sets on a root path are strictly nested).
    """
    full = m if pb.r == pb.n else complete(D.with_values(m)).matrix.values
    size = full.sum(axis=0)
    col = np.empty(pb.n, dtype=np.int64)
    above = np.full(pb.n, -1, dtype=np.int64)  # the parent's joint
    for i in range(pb.n):
        js = np.flatnonzero(full[i])
        js = js[np.argsort(size[js], kind="stable")]
        col[i] = js[0]
        if len(js) > 1:
            above[i] = js[1]
    node_at = np.empty(pb.n, dtype=np.int64)
    node_at[col] = np.arange(pb.n)
    parent = np.where(above < 0, -1, node_at[np.maximum(above, 0)])
    return _new(pb, parent, col)


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
    pb = _Problem(D.values)
    col = _complete_pairing(pb, perm_cols)
    budget = 2 * beam if budget is None else budget
    tries = min(2 * pb.n, 48)
    trellis_best, trellis_states = _trellis_states(pb, col, min(beam, 4))
    pool = _Pool(beam)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    starts = [_column_greedy(pb), _row_greedy(pb), trellis_states[0], _star(pb, col)]
    starts += [_column_greedy(pb, rng) if k % 2 == 0 else _row_greedy(pb, rng) for k in range(restarts)]
    ends: list[_State] = []
    for start in starts:  # cheap descents from every start ...
        ends.append(_search(pb, [start], pool, budget, 0, 0)[0])
    rounds = [max_rounds]
    for start in sorted(ends, key=lambda x: x.cost)[:polish]:  # ... the deeper look only from the best ends
        _search(pb, [start], pool, budget, tries, rounds=rounds)
    certified, lower = False, 0
    limit = max(2, pb.n // 2) if exact_max_distance is None else exact_max_distance
    if exact and pool.best <= limit:
        res = nearest_tree_matrix(D.values, upper=pool.best, rounds=exact_rounds)
        certified, lower = res.optimal, res.lower
        if res.matrix is not None:  # strictly closer than the search: start the search's tie walk there
            s = _from_matrix(pb, res.matrix, D)
            if s.cost != res.lower:
                raise AssertionError(f"exact tree at {s.cost}, MILP said {res.lower}")
            _search(pb, [s], pool, budget, 0, 0)
    cands = sorted(pool.states.values(), key=lambda s: s.matrix(pb).tobytes(), reverse=True)
    out = [D.with_values(s.matrix(pb)) for s in cands]
    return Correction(out, pool.best, permutation, pool.truncated, trellis_best, certified, lower)
