"""The heterogeneous dependency matrix (paper III-B, Def. 3): a labelled binary matrix.

Rows are nodes of the body out-tree (links, named by the sensors riding them), columns are joints.
``D[i, j] = 1`` iff joint ``j`` lies on the path from the root (base) to node ``i``. The labels travel
with the data: two matrices that differ only by a permutation of labelled rows and columns are the same
matrix (Property 1), so equality, hashing and :meth:`DependencyMatrix.hamming` align labels first.

A matrix with fewer rows than columns is a *partially observed* matrix (links without sensors, paper
III-F); :mod:`bodyschema.completion` fills it and :mod:`bodyschema.correction` repairs a noisy one.

Example
-------
>>> D = DependencyMatrix([[1, 0], [1, 1]], rows=["imu0", "imu1"], cols=["j1", "j2"])
>>> D.depth()
{'imu0': 1, 'imu1': 2}
>>> D == D.reorder(rows=["imu1", "imu0"], cols=["j2", "j1"])
True
>>> D.row_set("imu1")
('j1', 'j2')
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["DependencyMatrix", "DependencyMatrixError", "RowMerge"]


class DependencyMatrixError(ValueError):
    """Values or labels that cannot form a dependency matrix (shape, non-binary, duplicate names)."""


def _labels(names: Sequence[str] | Iterable[str], what: str) -> tuple[str, ...]:
    if isinstance(names, str):
        raise DependencyMatrixError(f"{what} must be a sequence of names, not a single string")
    out = tuple(str(n) for n in names)
    if len(set(out)) != len(out):
        dup = sorted({n for n in out if out.count(n) > 1})
        raise DependencyMatrixError(f"duplicate {what}: {dup}")
    return out


class DependencyMatrix:
    """A binary (R, N) matrix with row labels (nodes/sensors) and column labels (joints).

    ``values`` may be bool or 0/1 numbers; anything else (2, NaN, wrong shape) raises
    :class:`DependencyMatrixError`. The stored array is a read-only bool copy.
    """

    __slots__ = ("_cols", "_rows", "_values")

    def __init__(self, values: Any, rows: Sequence[str], cols: Sequence[str]) -> None:
        arr = np.asarray(values)
        r, c = _labels(rows, "row labels"), _labels(cols, "column labels")
        if arr.size == 0 and arr.ndim < 2:
            arr = arr.reshape(len(r), len(c))
        if arr.ndim != 2:
            raise DependencyMatrixError(f"values must be 2-D, got shape {arr.shape}")
        if arr.shape != (len(r), len(c)):
            raise DependencyMatrixError(
                f"values have shape {arr.shape} but there are {len(r)} row and {len(c)} column labels"
            )
        if arr.dtype != bool:
            if not np.issubdtype(arr.dtype, np.number):
                raise DependencyMatrixError(f"values must be bool or 0/1 numbers, got dtype {arr.dtype}")
            if not np.all(np.isin(arr, (0, 1))):
                raise DependencyMatrixError("values must be binary (0/1); found other values or NaN")
        b = np.array(arr, dtype=bool, copy=True)
        b.setflags(write=False)
        self._values, self._rows, self._cols = b, r, c

    # ----------------------------------------------------------- builders
    @classmethod
    def from_sets(cls, row_sets: Mapping[str, Iterable[str]], cols: Sequence[str]) -> DependencyMatrix:
        """Build from ``row -> joints on its root path``.

        >>> DependencyMatrix.from_sets({"a": ["j1"], "b": ["j1", "j2"]}, cols=["j1", "j2"]).values.astype(int)
        array([[1, 0],
               [1, 1]])
        """
        cols_t = _labels(cols, "column labels")
        index = {c: k for k, c in enumerate(cols_t)}
        vals = np.zeros((len(row_sets), len(cols_t)), dtype=bool)
        for i, js in enumerate(row_sets.values()):
            for j in js:
                if j not in index:
                    raise DependencyMatrixError(f"row {list(row_sets)[i]!r} names unknown joint {j!r}")
                vals[i, index[j]] = True
        return cls(vals, list(row_sets), cols_t)

    # ------------------------------------------------------------- access
    @property
    def values(self) -> np.ndarray:
        """The (R, N) read-only bool array."""
        return self._values

    @property
    def rows(self) -> tuple[str, ...]:
        return self._rows

    @property
    def cols(self) -> tuple[str, ...]:
        return self._cols

    @property
    def shape(self) -> tuple[int, int]:
        return self._values.shape  # type: ignore[return-value]

    @property
    def is_square(self) -> bool:
        return self.shape[0] == self.shape[1]

    def row_index(self, name: str) -> int:
        try:
            return self._rows.index(name)
        except ValueError:
            raise DependencyMatrixError(f"unknown row {name!r}") from None

    def col_index(self, name: str) -> int:
        try:
            return self._cols.index(name)
        except ValueError:
            raise DependencyMatrixError(f"unknown column {name!r}") from None

    def __getitem__(self, key: tuple[str, str]) -> bool:
        r, c = key
        return bool(self._values[self.row_index(r), self.col_index(c)])

    def row_set(self, name: str) -> tuple[str, ...]:
        """The joints on the root path of node ``name`` (in column order)."""
        v = self._values[self.row_index(name)]
        return tuple(c for c, x in zip(self._cols, v, strict=True) if x)

    def col_set(self, name: str) -> tuple[str, ...]:
        """Column set S_c (Def. 8): the rows below joint ``name`` (in row order)."""
        v = self._values[:, self.col_index(name)]
        return tuple(r for r, x in zip(self._rows, v, strict=True) if x)

    def depth(self) -> dict[str, int]:
        """Row sums: the depth of each node in its tree (Property 4)."""
        return {r: int(s) for r, s in zip(self._rows, self._values.sum(axis=1), strict=True)}

    # ------------------------------------------------------- derivations
    def with_values(self, values: Any) -> DependencyMatrix:
        """Same labels, new values."""
        return DependencyMatrix(values, self._rows, self._cols)

    def reorder(
        self, rows: Sequence[str] | None = None, cols: Sequence[str] | None = None
    ) -> DependencyMatrix:
        """The same matrix with rows/columns listed in another order (labels must be a permutation)."""
        rows = self._rows if rows is None else tuple(rows)
        cols = self._cols if cols is None else tuple(cols)
        if sorted(rows) != sorted(self._rows) or sorted(cols) != sorted(self._cols):
            raise DependencyMatrixError("reorder needs a permutation of the existing row and column labels")
        ri = [self.row_index(r) for r in rows]
        ci = [self.col_index(c) for c in cols]
        return DependencyMatrix(self._values[np.ix_(ri, ci)], rows, cols)

    def select_rows(self, rows: Sequence[str]) -> DependencyMatrix:
        """The sub-matrix of the named rows (a partially observed matrix when rows are left out)."""
        ri = [self.row_index(r) for r in rows]
        return DependencyMatrix(self._values[ri], list(rows), self._cols)

    def drop_rows(self, rows: Iterable[str]) -> DependencyMatrix:
        drop = set(rows)
        for r in drop:
            self.row_index(r)
        return self.select_rows([r for r in self._rows if r not in drop])

    def sorted(self) -> DependencyMatrix:
        """Canonical form: rows and columns sorted by label."""
        return self.reorder(sorted(self._rows), sorted(self._cols))

    def hamming(self, other: DependencyMatrix) -> int:
        """Number of differing entries after aligning labels (both must carry the same labels)."""
        if set(other.rows) != set(self._rows) or set(other.cols) != set(self._cols):
            raise DependencyMatrixError("hamming distance needs matrices with the same row and column labels")
        o = other.reorder(self._rows, self._cols)
        return int(np.count_nonzero(self._values != o.values))

    def merge_rows(self) -> RowMerge:
        """Merge duplicate rows (sensors on one link) and split off all-zero rows (sensors on the base).

        The merged row keeps the label of the first sensor of its group. This is the step the paper
        does before building the tree ("if we merge all the same rows ...", III-D).

        >>> D = DependencyMatrix([[1, 0], [1, 0], [0, 0], [1, 1]], ["a", "a2", "b0", "c"], ["j1", "j2"])
        >>> m = D.merge_rows()
        >>> m.matrix.rows, m.groups["a"], m.base_rows
        (('a', 'c'), ('a', 'a2'), ('b0',))
        >>> m.imu_nodes()["a2"], m.imu_nodes()["b0"]
        ('a', None)
        """
        groups: dict[bytes, list[str]] = {}
        base: list[str] = []
        for name, v in zip(self._rows, self._values, strict=True):
            if not v.any():
                base.append(name)
                continue
            groups.setdefault(v.tobytes(), []).append(name)
        keep = [g[0] for g in groups.values()]
        return RowMerge(
            matrix=self.select_rows(keep),
            groups={g[0]: tuple(g) for g in groups.values()},
            base_rows=tuple(base),
        )

    # ------------------------------------------------------------ output
    def to_sets(self) -> dict[str, tuple[str, ...]]:
        """``row -> joints on its root path`` (the inverse of :meth:`from_sets`)."""
        return {r: self.row_set(r) for r in self._rows}

    def to_text(self) -> str:
        """A small grid with labels, for logs and error messages."""
        w = max([len(r) for r in self._rows] + [1])
        head = " " * w + " " + " ".join(self._cols)
        lines = [head]
        for r, v in zip(self._rows, self._values, strict=True):
            cells = " ".join(("1" if x else ".").rjust(len(c)) for c, x in zip(self._cols, v, strict=True))
            lines.append(f"{r.rjust(w)} {cells}")
        return "\n".join(lines)

    def _key(self) -> tuple[tuple[str, ...], tuple[str, ...], bytes]:
        s = self.sorted()
        return s._rows, s._cols, s._values.tobytes()

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DependencyMatrix):
            return NotImplemented
        if set(other.rows) != set(self._rows) or set(other.cols) != set(self._cols):
            return False
        if self.shape != other.shape:
            return False
        return bool(np.array_equal(self._values, other.reorder(self._rows, self._cols).values))

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        return f"DependencyMatrix(shape={self.shape}, rows={list(self._rows)}, cols={list(self._cols)})\n" + (
            self.to_text()
        )


@dataclass(frozen=True)
class RowMerge:
    """Result of :meth:`DependencyMatrix.merge_rows`.

    ``matrix`` has one row per distinct non-zero row; ``groups`` maps each kept label to every original
    row in its group; ``base_rows`` are the all-zero rows (sensors on the base link).
    """

    matrix: DependencyMatrix
    groups: dict[str, tuple[str, ...]]
    base_rows: tuple[str, ...]

    def imu_nodes(self) -> dict[str, str | None]:
        """Original row label -> node label (None = base), the mapping ``tree_to_topology`` takes."""
        out: dict[str, str | None] = {}
        for node, members in self.groups.items():
            for m in members:
                out[m] = node
        for b in self.base_rows:
            out[b] = None
        return out
