"""Local search over trees for the nearest tree matrix (the search stage of :mod:`bodyschema.correction`).

A search state is a tree over N nodes (observed rows first, then hidden links) and the joint of each
node; its cost is the Hamming distance of its matrix to the observed rows. Steepest descent runs over
two moves whose cost change is computed for all candidates at once (re-hanging a subtree, swapping the
joints of two links); at a local minimum the pairing is re-solved exactly, and the best ends get a
deeper look (the least-bad moves, parent/child rotations, a re-solve without each worst-fitting row).
Starts: the star, greedy trees by rows and by columns, and Alg. 3's trellis (:func:`trellis_states`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bodyschema.completion import complete
from bodyschema.depmatrix import DependencyMatrix

__all__ = [
    "Pool",
    "Problem",
    "State",
    "column_greedy",
    "complete_pairing",
    "from_matrix",
    "row_greedy",
    "search",
    "star",
    "trellis_states",
]


class Problem:
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

    def without(self, row: int) -> Problem:
        mask = self.mask.copy()
        mask[row] = False
        return Problem(self.v, mask)

    def cost(self, col: np.ndarray, t: np.ndarray) -> int:
        diff = self.pad[: self.r][:, col] != t[: self.r]
        return int(np.count_nonzero(diff[self.mask]))


@dataclass
class State:
    parent: np.ndarray  # parent node, -1 = root
    col: np.ndarray  # column (joint) of each node
    t: np.ndarray = field(init=False)  # t[r, a]: node a is on the root path of r (r itself included)
    cost: int = field(init=False)

    def finish(self, pb: Problem) -> State:
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

    def matrix(self, pb: Problem) -> np.ndarray:
        """The (R, N) observed rows of this tree's matrix, in the problem's column order."""
        m = np.zeros((pb.r, pb.n), dtype=bool)
        m[:, self.col] = self.t[: pb.r]
        return m


def _new(pb: Problem, parent: np.ndarray, col: np.ndarray) -> State:
    return State(parent.copy(), col.copy()).finish(pb)


def _with(pb: Problem, parent: np.ndarray, col: np.ndarray, t: np.ndarray) -> State:
    """A state whose ancestor matrix is already known (cheaper than :meth:`State.finish`)."""
    s = State(parent, col)
    s.t = t
    s.cost = pb.cost(col, t)
    return s


def _moves(pb: Problem, s: State) -> tuple[np.ndarray, np.ndarray]:
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


def _apply(pb: Problem, s: State, kind: int, i: int, j: int) -> State:
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
class Pool:
    """States at the best cost so far, one per distinct observed matrix, at most ``beam``."""

    beam: int
    best: int = 1 << 60
    states: dict[bytes, State] = field(default_factory=dict)
    truncated: bool = False

    def offer(self, pb: Problem, s: State) -> bool:
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


def _descend(pb: Problem, starts: list[State], pool: Pool, budget: int) -> list[State]:
    """Steepest descent with ties: improving moves reset the frontier; equal ones widen it (budget).

    Returns the states at the lowest cost this descent reached (at most ``pool.beam``).
    """
    best = min(s.cost for s in starts)
    frontier = [s for s in starts if s.cost == best]
    seen = {s.key() for s in frontier}
    reached: dict[bytes, State] = {s.key(): s for s in frontier}
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


def _repair(pb: Problem, s: State) -> State:
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


def _repair_nodes(pb: Problem, s: State) -> State:
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


def _escape(pb: Problem, s: State, tries: int, deep: int = 12) -> list[State]:
    """Look one move past a local minimum: the ``tries`` least-bad moves, each followed by an optimal
    re-pairing (both kinds); for the first ``deep`` of them that do not help at once, a full descent
    from there. Returns the states found below ``s.cost`` (empty when none)."""
    rehang, swap = _moves(pb, s)
    flat = np.concatenate([rehang.ravel(), swap.ravel()])
    k = min(tries, int(np.isfinite(flat).sum()))
    if k == 0:
        return []
    pick = np.argpartition(flat, k - 1)[:k]
    out: dict[bytes, State] = {}
    _escape_by_moves(pb, s, rehang, swap, pick, deep, out)
    _escape_by_rotations(pb, s, out)
    return list(out.values())


def _keep_below(out: dict[bytes, State], ys: tuple[State, ...], cost: int) -> None:
    """Record in ``out`` (keyed by state) each of ``ys`` that costs less than ``cost``, in order."""
    for y in ys:
        if y.cost < cost:
            out[y.key()] = y


def _escape_by_moves(
    pb: Problem,
    s: State,
    rehang: np.ndarray,
    swap: np.ndarray,
    pick: np.ndarray,
    deep: int,
    out: dict[bytes, State],
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


def _escape_by_rotations(pb: Problem, s: State, out: dict[bytes, State]) -> None:
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


def _quick(pb: Problem, s: State) -> State:
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


def _leave_out(pb: Problem, s: State, rows: int) -> list[State]:
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
        for x0 in (_with(pr, s.parent, s.col, s.t), column_greedy(pr)):
            x = _quick(pr, x0)
            y = _quick(pb, _with(pb, x.parent, x.col, x.t))
            if y.cost < s.cost:
                return [y]
    return []


def search(
    pb: Problem,
    starts: list[State],
    pool: Pool,
    budget: int,
    tries: int,
    leave: int = 8,
    rounds: list[int] | None = None,
) -> list[State]:
    """Alternate descent and optimal re-pairing (fixed joint tree, fixed link tree); at a local minimum
    look one move further (:func:`_escape`); stop when nothing gets below the best cost."""
    states = starts
    while True:
        reached = _descend(pb, states, pool, budget)
        if not reached:
            return states
        cost = reached[0].cost
        better: dict[bytes, State] = {}
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


def star(pb: Problem, col: np.ndarray) -> State:
    return _new(pb, np.full(pb.n, -1), col)


def row_greedy(pb: Problem, rng: np.random.Generator | None = None) -> State:
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


def column_greedy(pb: Problem, rng: np.random.Generator | None = None) -> State:
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


def trellis_states(pb: Problem, col: np.ndarray, beam: int) -> tuple[int, list[State]]:
    """Alg. 3 in node space: level by level, dilate depth-1 leaves, keep the best ``beam`` states."""
    start = star(pb, col)
    level = [start]
    best, kept = start.cost, [start]
    while True:
        children: dict[bytes, State] = {}
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


def complete_pairing(pb: Problem, row_cols: np.ndarray) -> np.ndarray:
    """Extend the rows' columns to all N nodes: hidden links take the unused columns in order."""
    used = set(row_cols.tolist())
    free = [j for j in range(pb.n) if j not in used]
    return np.concatenate([row_cols, np.array(free, dtype=np.int64)]).astype(np.int64)


def from_matrix(pb: Problem, m: np.ndarray, D: DependencyMatrix) -> State:
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
