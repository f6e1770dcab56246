"""When is a binary matrix a dependency matrix? The condition sets P, P0 and P⁻ (paper Def. 8-10).

Conditions on a binary matrix D (rows = nodes, columns = joints; S_c = rows with a 1 in column c):

1. no all-0 rows;  2. no all-0 columns;  3. no duplicate rows;  4. no duplicate columns;
5. any two column sets are nested or disjoint;  6. every column's unique element set J_Sc (Def. 9:
   S_c minus every column set that is a proper subset of S_c) has exactly one row.

``P = {1,2,3,4,5}`` and ``P0 = {1,2,5,6}`` are equivalent on square matrices (Prop. 5) and hold exactly
when D is the matrix of a heterogeneous out-tree (Thm 2). ``P⁻ = {1,3,5}`` is what a partially observed
matrix (rows missing for links without sensors) must satisfy to be completable (Thm 3).

Each check returns a :class:`ConditionReport` naming every failing condition with the rows/columns
involved, not just a bool. :func:`condition_table` evaluates all six conditions on a whole batch of
matrices at once (vectorised), for property tests and benchmarks.

Example
-------
>>> from bodyschema.depmatrix import DependencyMatrix
>>> D = DependencyMatrix([[1, 1, 0], [0, 1, 1], [1, 0, 1]], ["a", "b", "c"], ["e1", "e2", "e3"])
>>> rep = check_p(D)
>>> rep.ok, rep.failed
(False, (5,))
>>> rep.failures[0].cols
('e1', 'e2')
>>> check_p0(D).failed
(5, 6)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bodyschema.depmatrix import DependencyMatrix

__all__ = [
    "CONDITION_NAMES",
    "P0",
    "P_MINUS",
    "ConditionFailure",
    "ConditionReport",
    "InvalidMatrixError",
    "P",
    "check",
    "check_p",
    "check_p0",
    "check_p_minus",
    "column_sets",
    "condition_table",
    "unique_element_sets",
]

P: tuple[int, ...] = (1, 2, 3, 4, 5)
P0: tuple[int, ...] = (1, 2, 5, 6)
P_MINUS: tuple[int, ...] = (1, 3, 5)

CONDITION_NAMES: dict[int, str] = {
    0: "square matrix",
    1: "no all-0 rows",
    2: "no all-0 columns",
    3: "no duplicate rows",
    4: "no duplicate columns",
    5: "column sets nested or disjoint",
    6: "every unique element set J_Sc has exactly one row",
}

#: At most this many failures are listed per condition (the count is always exact).
MAX_LISTED = 25


@dataclass(frozen=True)
class ConditionFailure:
    """One violation: which condition, where (row/column labels) and a sentence saying what is wrong."""

    condition: int
    message: str
    rows: tuple[str, ...] = ()
    cols: tuple[str, ...] = ()

    def __str__(self) -> str:
        return f"condition {self.condition} ({CONDITION_NAMES[self.condition]}): {self.message}"


@dataclass(frozen=True)
class ConditionReport:
    """Outcome of checking a condition set. ``ok`` is true when no condition fails.

    ``counts`` holds the exact number of violations per failing condition; ``failures`` lists up to
    :data:`MAX_LISTED` of them per condition.
    """

    conditions: tuple[int, ...]
    failures: tuple[ConditionFailure, ...] = ()
    counts: dict[int, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def failed(self) -> tuple[int, ...]:
        """The failing condition numbers, sorted."""
        return tuple(sorted({f.condition for f in self.failures}))

    def __bool__(self) -> bool:
        return self.ok

    def __str__(self) -> str:
        if self.ok:
            return f"conditions {self.conditions} hold"
        lines = [f"conditions {self.failed} of {self.conditions} fail:"]
        lines += [f"  {f}" for f in self.failures]
        return "\n".join(lines)


class InvalidMatrixError(ValueError):
    """A matrix that breaks the conditions an operation needs; ``report`` says which and where."""

    def __init__(self, message: str, report: ConditionReport) -> None:
        super().__init__(f"{message}\n{report}")
        self.report = report


# ------------------------------------------------------------------ vectorised core
def _relations(v: np.ndarray) -> dict[str, np.ndarray]:
    """Pairwise row/column relations of a (B, R, N) bool batch, all as numpy arrays."""
    x = v.astype(np.int32)
    rs = x.sum(axis=2)  # (B, R)
    cs = x.sum(axis=1)  # (B, N)
    rr = x @ x.transpose(0, 2, 1)  # (B, R, R) common ones of two rows
    cc = x.transpose(0, 2, 1) @ x  # (B, N, N) |S_c1 ∩ S_c2|
    dup_rows = (rr == rs[:, :, None]) & (rr == rs[:, None, :])
    dup_cols = (cc == cs[:, :, None]) & (cc == cs[:, None, :])
    crossing = (cc > 0) & (cc < cs[:, :, None]) & (cc < cs[:, None, :])
    # proper[b, c', c]: S_c' is a proper subset of S_c
    proper = (cc == cs[:, :, None]) & (cs[:, :, None] < cs[:, None, :])
    covered = (x @ proper.astype(np.int32)) > 0  # (B, R, N): row r lies in some proper subset of S_c
    j_sets = v & ~covered
    return {
        "rs": rs,
        "cs": cs,
        "dup_rows": dup_rows,
        "dup_cols": dup_cols,
        "crossing": crossing,
        "j_sets": j_sets,
    }


def condition_table(batch: np.ndarray) -> np.ndarray:
    """Which of conditions 1-6 hold, for a batch of binary matrices.

    ``batch`` is (B, R, N) (or a single (R, N) matrix); the result is a (B, 7) bool array whose column k
    says whether condition k holds (column 0: the matrix is square).

    >>> import numpy as np
    >>> condition_table(np.eye(3, dtype=bool))[0].tolist()
    [True, True, True, True, True, True, True]
    """
    v = np.asarray(batch).astype(bool)
    if v.ndim == 2:
        v = v[None]
    if v.ndim != 3:
        raise ValueError(f"batch must be (B, R, N), got shape {v.shape}")
    b, r, n = v.shape
    rel = _relations(v)
    off_r = ~np.eye(r, dtype=bool)[None]
    off_n = ~np.eye(n, dtype=bool)[None]
    out = np.zeros((b, 7), dtype=bool)
    out[:, 0] = r == n
    out[:, 1] = (rel["rs"] > 0).all(axis=1)
    out[:, 2] = (rel["cs"] > 0).all(axis=1)
    out[:, 3] = ~(rel["dup_rows"] & off_r).any(axis=(1, 2))
    out[:, 4] = ~(rel["dup_cols"] & off_n).any(axis=(1, 2))
    out[:, 5] = ~rel["crossing"].any(axis=(1, 2))
    out[:, 6] = (rel["j_sets"].sum(axis=1) == 1).all(axis=1)
    return out


# ------------------------------------------------------------------ labelled reports
def column_sets(D: DependencyMatrix) -> dict[str, frozenset[str]]:
    """S_c for every column (Def. 8): the rows with a 1 in column c."""
    return {c: frozenset(D.col_set(c)) for c in D.cols}


def unique_element_sets(D: DependencyMatrix) -> dict[str, frozenset[str]]:
    """J_Sc for every column (Def. 9).

    >>> from bodyschema.depmatrix import DependencyMatrix
    >>> D = DependencyMatrix([[1, 0, 1], [0, 1, 1], [0, 0, 1]], ["r1", "r2", "r3"], ["c1", "c2", "c3"])
    >>> {c: sorted(j) for c, j in unique_element_sets(D).items()}
    {'c1': ['r1'], 'c2': ['r2'], 'c3': ['r3']}
    """
    j = _relations(D.values[None])["j_sets"][0]
    return {c: frozenset(r for r, x in zip(D.rows, j[:, k], strict=True) if x) for k, c in enumerate(D.cols)}


def check(D: DependencyMatrix, conditions: tuple[int, ...]) -> ConditionReport:
    """Check any subset of the conditions 0-6 on ``D`` and say where each one fails."""
    rel = _relations(D.values[None])
    failures: list[ConditionFailure] = []
    counts: dict[int, int] = {}
    for cond in conditions:
        if cond not in _FAILURES:
            raise ValueError(f"unknown condition {cond}; conditions are numbered 0-6")
        items = _FAILURES[cond](D, rel)
        if items:
            counts[cond] = len(items)
            failures.extend(items[:MAX_LISTED])
    return ConditionReport(conditions=tuple(conditions), failures=tuple(failures), counts=counts)


def _square(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    if D.is_square:
        return []
    return [ConditionFailure(0, f"shape is {D.shape}; P and P0 are defined on N x N matrices")]


def _zero_rows(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    rows = D.rows
    return [
        ConditionFailure(1, f"row {rows[i]!r} is all 0", rows=(rows[i],))
        for i in np.flatnonzero(rel["rs"][0] == 0)
    ]


def _zero_cols(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    cols = D.cols
    return [
        ConditionFailure(2, f"column {cols[k]!r} is all 0", cols=(cols[k],))
        for k in np.flatnonzero(rel["cs"][0] == 0)
    ]


def _equal_rows(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    rows = D.rows
    d = np.triu(rel["dup_rows"][0], 1)
    return [
        ConditionFailure(3, f"rows {rows[i]!r} and {rows[k]!r} are equal", rows=(rows[i], rows[k]))
        for i, k in zip(*np.nonzero(d), strict=True)
    ]


def _equal_cols(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    cols = D.cols
    d = np.triu(rel["dup_cols"][0], 1)
    return [
        ConditionFailure(4, f"columns {cols[i]!r} and {cols[k]!r} are equal", cols=(cols[i], cols[k]))
        for i, k in zip(*np.nonzero(d), strict=True)
    ]


def _crossing(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    v, rows, cols = D.values, D.rows, D.cols
    d = np.triu(rel["crossing"][0], 1)
    items = []
    for i, k in zip(*np.nonzero(d), strict=True):
        common = tuple(r for r, a, b in zip(rows, v[:, i], v[:, k], strict=True) if a and b)
        items.append(
            ConditionFailure(
                5,
                f"column sets of {cols[i]!r} and {cols[k]!r} overlap without nesting "
                f"(common rows {list(common)})",
                rows=common,
                cols=(cols[i], cols[k]),
            )
        )
    return items


def _unique_elements(D: DependencyMatrix, rel: dict) -> list[ConditionFailure]:
    rows, cols = D.rows, D.cols
    j = rel["j_sets"][0]
    items = []
    for k in np.flatnonzero(j.sum(axis=0) != 1):
        members = tuple(r for r, x in zip(rows, j[:, k], strict=True) if x)
        items.append(
            ConditionFailure(
                6,
                f"J_Sc of column {cols[k]!r} has {len(members)} rows {list(members)}",
                rows=members,
                cols=(cols[k],),
            )
        )
    return items


#: Where each condition fails, by its number (0 is squareness).
_FAILURES: dict[int, Callable[[DependencyMatrix, dict], list[ConditionFailure]]] = {
    0: _square,
    1: _zero_rows,
    2: _zero_cols,
    3: _equal_rows,
    4: _equal_cols,
    5: _crossing,
    6: _unique_elements,
}


def check_p(D: DependencyMatrix) -> ConditionReport:
    """Condition set P = {1,2,3,4,5} (plus squareness, reported as condition 0)."""
    return check(D, (0, *P))


def check_p0(D: DependencyMatrix) -> ConditionReport:
    """Condition set P0 = {1,2,5,6} (plus squareness, reported as condition 0)."""
    return check(D, (0, *P0))


def check_p_minus(D: DependencyMatrix) -> ConditionReport:
    """Condition set P⁻ = {1,3,5}: a K x N matrix (K <= N) that can be completed (Thm 3).

    A matrix with more rows than columns fails condition 0 here: merge duplicate rows first.
    """
    rep = check(D, P_MINUS)
    if D.shape[0] > D.shape[1]:
        extra = ConditionFailure(
            0,
            f"{D.shape[0]} rows but only {D.shape[1]} columns; merge duplicate rows "
            "(sensors on one link) before completing",
        )
        return ConditionReport(
            conditions=(0, *P_MINUS), failures=(extra, *rep.failures), counts={0: 1, **rep.counts}
        )
    return rep
