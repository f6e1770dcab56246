"""Exact nearest tree matrix: a MILP over the matrix itself, with lazily added tree constraints.

Why this is exact: an R x N binary matrix (R <= N) is a tree matrix, or completes to one, exactly when it
satisfies P⁻ = {no all-0 row, no two equal rows, any two column sets nested or disjoint} (Thm 2/3; for a
square matrix P⁻ implies P: the smallest column set holding a row is then a bijection between rows and
columns, which is the pairing). Each of the three conditions is linear in the cells M[i, j]:

* a row is non-empty: ``sum_j M[i, j] >= 1``;
* rows i and h differ: ``sum_j z_j >= 1`` with ``z_j <= M[i, j] + M[h, j]`` and
  ``z_j <= 2 - M[i, j] - M[h, j]`` (z_j can only be 1 where exactly one of the two rows has a 1);
* columns k and l are nested or disjoint: binaries ``u`` (S_k ⊆ S_l) and ``w`` (S_l ⊆ S_k) with, for
  every row a, ``M[a, k] <= M[a, l] + 1 - u``, ``M[a, l] <= M[a, k] + 1 - w`` and
  ``M[a, k] + M[a, l] <= 1 + u + w``.

Minimising the Hamming distance ``sum (1 - 2 D) M + |D|`` under all of them is the exact problem, but
there are O(R^2 + N^2) pairs. So the pairs come in lazily (constraint generation): solve with the
constraints collected so far — a relaxation, so its optimum is a lower bound — check the answer, add the
pairs it breaks, solve again. The first answer that satisfies P⁻ is optimal. To keep each solve small,
a column pair is written only for the rows where D or an answer has a 1 in either column (more rows
join when an answer crosses on others), and only cells some constraint mentions are variables: the
rest stay as in D, which is optimal for them, except that a row may switch on one of them (one
aggregate variable) to be non-empty. To keep the rounds few, a row that an answer changed joins every
pair, and a row that took a 1 making two columns cross gets pairs between each of its columns and
every other column (otherwise it would try one column per solve).

With a known distance ``upper`` (from the local search) the solves look only for matrices strictly
closer (a cut-off row), so an infeasible solve certifies ``upper``. The work is capped by ``rounds``,
by ``max_pairs`` (default 20 N) and by HiGHS's branch-and-bound node limit ``max_nodes``: all
deterministic, so results do not depend on machine speed; when a cap is hit the result says so and
carries the best lower bound proven. The cost grows with the number of wrong bits: a few per row solve
in well under a second for N = 40, 10 % of all bits do not (the caller decides when to try).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ExactResult", "binary_lp", "nearest_tree_matrix", "p_minus_violations", "quiet_highs"]


@dataclass(frozen=True)
class ExactResult:
    """Outcome of :func:`nearest_tree_matrix`.

    ``matrix``: a P⁻ matrix strictly closer than ``upper`` (None when there is none, or none was found
    within the caps). ``lower``: a proven lower bound on the distance of every tree matrix to D.
    ``optimal``: the bound is attained — by ``matrix``, or by ``upper`` when ``matrix`` is None.
    ``rounds``: solves used.
    """

    matrix: np.ndarray | None
    lower: int
    optimal: bool
    rounds: int


def p_minus_violations(m: np.ndarray) -> tuple[list[int], list[tuple[int, int]], list[tuple[int, int]]]:
    """The P⁻ failures of binary ``m``: all-0 rows, pairs of equal rows, crossing column pairs (k < l)."""
    mi = m.astype(np.int64)
    zero = np.flatnonzero(mi.sum(axis=1) == 0).tolist()
    same = np.triu((mi @ mi.T == mi.sum(axis=1)[:, None]) & (mi @ mi.T == mi.sum(axis=1)[None, :]), k=1)
    inter = mi.T @ mi
    size = np.diag(inter)
    cross = np.triu((inter > 0) & (inter < size[:, None]) & (inter < size[None, :]), k=1)
    return (
        zero,
        [(int(a), int(b)) for a, b in zip(*np.nonzero(same), strict=True)],
        [(int(a), int(b)) for a, b in zip(*np.nonzero(cross), strict=True)],
    )


def binary_lp(
    cost: np.ndarray,
    integer: Sequence[bool],
    row_lower: np.ndarray,
    row_upper: np.ndarray,
    a: Any,
    *,
    offset: float = 0.0,
    maximize: bool = False,
) -> Any:
    """A HiGHS model over columns in [0, 1] (``integer`` marks the binaries) with rows
    ``row_lower <= a @ x <= row_upper`` (``a``: any scipy sparse matrix), handed over as arrays.

    Arrays rather than pulp: pulp builds a Python object per variable, which dominates the time on
    the N x N models of the correction."""
    import highspy

    a = a.tocsc()
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = a.shape[1], a.shape[0]
    if maximize:
        lp.sense_ = highspy.ObjSense.kMaximize
    lp.col_cost_ = np.asarray(cost, dtype=np.float64)
    lp.offset_ = offset
    lp.col_lower_ = np.zeros(a.shape[1])
    lp.col_upper_ = np.ones(a.shape[1])
    lp.row_lower_ = np.asarray(row_lower, dtype=np.float64)
    lp.row_upper_ = np.asarray(row_upper, dtype=np.float64)
    lp.integrality_ = [
        highspy.HighsVarType.kInteger if t else highspy.HighsVarType.kContinuous for t in integer
    ]
    if a.shape[0]:
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = a.indptr
        lp.a_matrix_.index_ = a.indices
        lp.a_matrix_.value_ = a.data
    return lp


def quiet_highs() -> Any:
    """A HiGHS solver that prints nothing and runs on one thread.

    One thread for every solver made here, not only some: HiGHS starts one task scheduler per process,
    sized by the first solve that needs it, and a later solver asking for another thread count fails
    with an error status instead of solving. The correction's Eq. 22 solve ran on the default (all
    cores) and the exact stage after it asked for one thread, which left a drawn 6 x 6 case uncertified.
    """
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("threads", 1)
    return h


class _Model:
    """Sparse rows for HiGHS, collected as (row, column, value) triples."""

    def __init__(self) -> None:
        self.ri: list[np.ndarray] = []
        self.ci: list[np.ndarray] = []
        self.va: list[np.ndarray] = []
        self.lo: list[float] = []
        self.hi: list[float] = []

    def row(self, cols: np.ndarray, vals: np.ndarray, low: float, up: float) -> None:
        self.ri.append(np.full(len(cols), len(self.lo)))
        self.ci.append(np.asarray(cols, dtype=np.int64))
        self.va.append(np.asarray(vals, dtype=float))
        self.lo.append(low)
        self.hi.append(up)

    def matrix(self, n_cols: int) -> Any:
        """The rows so far as a scipy sparse matrix with ``n_cols`` columns."""
        from scipy.sparse import coo_matrix

        m_rows = len(self.lo)
        if not m_rows:
            return coo_matrix((0, n_cols))
        return coo_matrix(
            (np.concatenate(self.va), (np.concatenate(self.ri), np.concatenate(self.ci))),
            shape=(m_rows, n_cols),
        )


def _solve(
    d: np.ndarray,
    rows: set[tuple[int, int]],
    cols: dict[tuple[int, int], np.ndarray],
    upper: int | None,
    max_nodes: int,
) -> tuple[str, np.ndarray | None, float]:
    """One relaxation: ('optimal', M, value) | ('infeasible', None, upper) | ('limit', M or None, bound).

    Only the cells some pair constraint mentions are variables ("active"); the others stay as in D, which
    is optimal for them in this relaxation, except that a row whose 1s all lie in active cells may switch
    on one inactive 0 at cost 1 (one aggregate variable per row) to be non-empty.
    """
    import highspy

    act = _active_cells(d, rows, cols)
    idx = np.full(d.shape, -1, dtype=np.int64)
    nx = int(act.sum())
    idx[act] = np.arange(nx)
    v = _Vars(list(1.0 - 2.0 * d[act]), [True] * nx)
    mdl = _Model()
    fill = _add_nonempty_rows(mdl, v, d, act, idx)
    _add_distinct_rows(mdl, v, rows, idx)
    _add_nested_columns(mdl, v, cols, idx)
    c = np.array(v.cost)
    offset = float(d[act].sum())  # an inactive cell equals D and costs nothing
    if upper is not None:  # cut-off: strictly closer than upper
        mdl.row(np.flatnonzero(c), c[c != 0], -highspy.kHighsInf, upper - 1 - offset)
    lp = binary_lp(c, v.integer, np.array(mdl.lo), np.array(mdl.hi), mdl.matrix(v.n), offset=offset)
    h = _run_highs(lp, max_nodes)
    status = h.getModelStatus()
    if status == highspy.HighsModelStatus.kInfeasible:
        return "infeasible", None, float(upper if upper is not None else np.inf)
    info = h.getInfo()
    m = None
    if info.primal_solution_status == 2:  # a feasible solution exists
        m = _answer(h, d, act, nx, fill)
    if status == highspy.HighsModelStatus.kOptimal and m is not None:
        return "optimal", m, float(info.objective_function_value)
    bound = info.mip_dual_bound
    return "limit", m, float(bound) if np.isfinite(bound) else 0.0


@dataclass
class _Vars:
    """The model's columns as they are added: cost and integrality of each."""

    cost: list[float]
    integer: list[bool]

    @property
    def n(self) -> int:
        return len(self.cost)

    def add(self, k: int, cost: float, integer: bool) -> np.ndarray:
        """Append ``k`` columns alike; return their indices."""
        first = self.n
        self.cost.extend([cost] * k)
        self.integer.extend([integer] * k)
        return np.arange(first, first + k)


def _active_cells(
    d: np.ndarray, rows: set[tuple[int, int]], cols: dict[tuple[int, int], np.ndarray]
) -> np.ndarray:
    """The cells some pair constraint mentions: whole rows of row pairs, the pair's rows of column pairs."""
    act = np.zeros(d.shape, dtype=bool)
    for a, b in rows:
        act[[a, b]] = True
    for (k, l), rs in cols.items():
        act[rs, k] = True
        act[rs, l] = True
    return act


def _add_nonempty_rows(
    mdl: _Model, v: _Vars, d: np.ndarray, act: np.ndarray, idx: np.ndarray
) -> dict[int, int]:
    """A row with no inactive 1 needs one of its active cells, or its aggregate "switch on an inactive 0"
    variable, set; returns row -> that aggregate variable."""
    import highspy

    fill: dict[int, int] = {}
    base = (d & ~act).sum(axis=1)
    for i in np.flatnonzero(base == 0):
        vs = idx[i][act[i]]
        coef = np.ones(len(vs))
        if (~act[i]).any():  # an inactive 0 is available to switch on
            fill[int(i)] = v.n
            vs = np.append(vs, v.add(1, 1.0, True))
            coef = np.append(coef, 1.0)
        mdl.row(vs, coef, 1.0, highspy.kHighsInf)
    return fill


def _add_distinct_rows(mdl: _Model, v: _Vars, rows: set[tuple[int, int]], idx: np.ndarray) -> None:
    """Rows a and b differ: z_j <= M_a + M_b, z_j <= 2 - M_a - M_b, sum z >= 1."""
    import highspy

    n = idx.shape[1]
    for a, b in sorted(rows):
        z = v.add(n, 0.0, False)
        for j in range(n):
            mdl.row(
                np.array([z[j], idx[a, j], idx[b, j]]), np.array([1.0, -1.0, -1.0]), -highspy.kHighsInf, 0.0
            )
            mdl.row(
                np.array([z[j], idx[a, j], idx[b, j]]), np.array([1.0, 1.0, 1.0]), -highspy.kHighsInf, 2.0
            )
        mdl.row(z, np.ones(n), 1.0, highspy.kHighsInf)


def _add_nested_columns(
    mdl: _Model, v: _Vars, cols: dict[tuple[int, int], np.ndarray], idx: np.ndarray
) -> None:
    """Columns k, l nested (u: S_k in S_l, w: S_l in S_k) or disjoint, on the pair's rows."""
    import highspy

    inf = highspy.kHighsInf
    for (k, l), rs in sorted(cols.items()):
        u, w = (int(x) for x in v.add(2, 0.0, True))
        for a in rs:
            xk, xl = idx[a, k], idx[a, l]
            mdl.row(np.array([xk, xl, u]), np.array([1.0, -1.0, 1.0]), -inf, 1.0)
            mdl.row(np.array([xl, xk, w]), np.array([1.0, -1.0, 1.0]), -inf, 1.0)
            mdl.row(np.array([xk, xl, u, w]), np.array([1.0, 1.0, -1.0, -1.0]), -inf, 1.0)


def _run_highs(lp: Any, max_nodes: int) -> Any:
    """A solver that has run on ``lp``: exact gap (the distance is an integer), node-capped, no primal
    heuristics; raises when HiGHS reports an error."""
    import highspy

    h = quiet_highs()
    h.setOptionValue("mip_rel_gap", 0.0)
    h.setOptionValue("mip_abs_gap", 0.5)  # the distance is an integer
    h.setOptionValue("mip_max_nodes", max_nodes)
    # these models are decided at the root, where primal heuristics only cost time
    h.setOptionValue("mip_heuristic_effort", 0.0)
    h.passModel(lp)
    if h.run() == highspy.HighsStatus.kError:
        raise RuntimeError(
            f"HiGHS failed on the exact stage's model: {h.modelStatusToString(h.getModelStatus())}"
        )
    return h


def _answer(h: Any, d: np.ndarray, act: np.ndarray, nx: int, fill: dict[int, int]) -> np.ndarray:
    """The matrix of the solver's solution: D with the active cells as solved, and each row whose
    aggregate variable is on given its first inactive 0."""
    x = np.asarray(h.getSolution().col_value) > 0.5
    m = d.copy()
    m[act] = x[:nx]
    for i, v in fill.items():
        if x[v]:
            m[i, int(np.flatnonzero(~act[i] & ~d[i])[0])] = True
    return m


def nearest_tree_matrix(
    d: np.ndarray,
    upper: int | None = None,
    rounds: int = 40,
    max_nodes: int = 500,
    max_pairs: int | None = None,
) -> ExactResult:
    """A P⁻ matrix nearest to binary ``d`` (R x N, R <= N) in Hamming distance, or a proof that none is
    closer than ``upper``. See the module notes for the method and the caps.

    >>> d = np.array([[1, 1, 0], [0, 1, 1], [1, 0, 1]], dtype=bool)  # Eq. 20: no tree matrix
    >>> r = nearest_tree_matrix(d)
    >>> r.optimal, r.lower, int((r.matrix != d).sum()), p_minus_violations(r.matrix)
    (True, 2, 2, ([], [], []))
    >>> r = nearest_tree_matrix(d, upper=2)  # nothing closer than 2: the bound is certified
    >>> r.matrix is None, r.optimal, r.lower
    (True, True, 2)
    """
    d = np.asarray(d, dtype=bool)
    rows: set[tuple[int, int]] = set()
    cols: dict[tuple[int, int], np.ndarray] = {}
    hot: set[int] = set()
    touched = np.zeros(d.shape[0], dtype=bool)
    m = d
    lower = 0
    for used in range(1, rounds + 1):
        zero, same, cross = p_minus_violations(m)
        if not (zero or same or cross):  # a tree matrix: D itself, or the optimum of the last relaxation
            dist = int((m != d).sum())
            if upper is not None and dist >= upper:  # D is a tree matrix and upper is 0
                return ExactResult(None, int(upper), True, used - 1)
            return ExactResult(m, dist, True, used - 1)
        new = _add_row_pairs(same, rows)
        pairs = _column_pairs_wanted(d, m, cross, hot)
        new = _widen_to_changed_rows(d, m, cols, touched) or new
        new = _add_column_pairs(d, m, pairs, cols, touched) or new
        if len(cols) + len(rows) > (20 * d.shape[1] if max_pairs is None else max_pairs):
            return ExactResult(None, lower, False, used - 1)
        if used > 1 and not new:
            raise AssertionError("the relaxation's answer breaks a constraint it was given")
        status, m_new, value = _solve(d, rows, cols, upper, max_nodes)
        if status == "infeasible":
            if upper is None:
                raise AssertionError("the relaxation without a cut-off cannot be infeasible")
            return ExactResult(None, int(upper), True, used)
        lower = max(lower, int(np.ceil(value - 1e-6)))
        if m_new is None or status == "limit":
            return ExactResult(None, lower, False, used)
        m = m_new
    return ExactResult(None, lower, False, rounds)


def _add_row_pairs(same: list[tuple[int, int]], rows: set[tuple[int, int]]) -> bool:
    """Collect the equal-row pairs into ``rows``; whether any was new."""
    new = False
    for pair in same:
        new |= pair not in rows
        rows.add(pair)
    return new


def _column_pairs_wanted(
    d: np.ndarray, m: np.ndarray, cross: list[tuple[int, int]], hot: set[int]
) -> set[tuple[int, int]]:
    """The crossing column pairs, plus pairs for the rows (not yet in ``hot``; added to it) that took a
    new 1 making two columns cross.

    Such a row would otherwise try its other columns one solve at a time: give every column a pair with
    each column of that row at once.
    """
    pairs = set(cross)
    added = m & ~d
    for k, l in cross:
        for i in np.flatnonzero((added[:, k] & m[:, l]) | (added[:, l] & m[:, k])):
            if i not in hot:
                hot.add(int(i))
                for o in np.flatnonzero(d[i] | m[i]).tolist():
                    pairs.update((min(j, o), max(j, o)) for j in range(d.shape[1]) if j != o)
    return pairs


def _widen_to_changed_rows(
    d: np.ndarray, m: np.ndarray, cols: dict[tuple[int, int], np.ndarray], touched: np.ndarray
) -> bool:
    """Put each row the answer changed (first time only; marked in ``touched``) into every column pair
    at once: otherwise it tries one column per solve. Whether a pair grew."""
    new = False
    fresh = np.flatnonzero((m != d).any(axis=1) & ~touched)
    if len(fresh):
        touched[fresh] = True
        for key in cols:
            cols[key] = np.union1d(cols[key], fresh)
            new = True
    return new


def _add_column_pairs(
    d: np.ndarray,
    m: np.ndarray,
    pairs: set[tuple[int, int]],
    cols: dict[tuple[int, int], np.ndarray],
    touched: np.ndarray,
) -> bool:
    """Write each pair on every row where D or the last answer has a 1 in either column (and on the
    touched rows); whether a pair was new or gained rows."""
    new = False
    for k, l in pairs:
        rs = np.flatnonzero(d[:, k] | d[:, l] | m[:, k] | m[:, l] | touched)
        old = cols.get((k, l))
        if old is None or len(np.setdiff1d(rs, old)):
            cols[(k, l)] = rs if old is None else np.union1d(old, rs)
            new = True
    return new
