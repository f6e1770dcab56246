"""The regressors of the exact hinge gyro model, shared by the fast estimator, health and kinematics.

A gyro on a link turned by a revolute joint reads, sample by sample (docs/design.md, 'Science notes')::

    ω_c = A ω_p + B ω_p cos q + C ω_p sin q + a q̇ + (bias terms)

with ``ω_p`` the parent link's angular velocity (absent under a root joint on the fixed base). The
model is linear in its matrices, so every method that compares a gyro with an encoder regresses on
the same columns; they differ only in the bias terms that follow ``q̇``: a constant (``"one"``) for the
child gyro's bias, ``cos q`` and ``sin q`` for the parent's bias seen through the joint.

>>> import numpy as np
>>> q, qd = np.array([0.0, np.pi / 2]), np.array([1.0, 2.0])
>>> hinge_design(None, q, qd).tolist()
[[1.0, 1.0], [2.0, 1.0]]
>>> hinge_design(np.ones((2, 3)), q, qd, tail=("qd",)).shape
(2, 10)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["TAIL_COLUMNS", "hinge_design", "hinge_features"]

#: The columns that may follow the nine ``ω_p`` columns, by name.
TAIL_COLUMNS: tuple[str, ...] = ("cos", "sin", "qd", "one")


def hinge_features(
    wh: np.ndarray | None,
    c: np.ndarray,
    s: np.ndarray,
    qd: np.ndarray,
    tail: Sequence[str] = ("cos", "sin", "qd"),
) -> np.ndarray:
    """Regressors (..., p, T), rows first: ``ω_h``, ``ω_h cos q``, ``ω_h sin q`` (with a parent gyro
    ``wh`` (3, T)), then the ``tail`` rows in order (:data:`TAIL_COLUMNS`). ``c``, ``s`` and ``qd``
    are ``cos q``, ``sin q`` and ``q̇``, (..., T): a leading batch axis fits every joint at once."""
    bad = [name for name in tail if name not in TAIL_COLUMNS]
    if bad:
        raise ValueError(f"unknown hinge column {bad[0]!r}: expected one of {', '.join(TAIL_COLUMNS)}")
    lead, T = c.shape[:-1], c.shape[-1]
    off = 0 if wh is None else 9
    F = np.empty((*lead, off + len(tail), T))
    if wh is not None:
        F[..., 0:3, :] = wh
        np.multiply(wh, c[..., None, :], out=F[..., 3:6, :])
        np.multiply(wh, s[..., None, :], out=F[..., 6:9, :])
    rows = {"cos": c, "sin": s, "qd": qd}
    for k, name in enumerate(tail):
        F[..., off + k, :] = 1.0 if name == "one" else rows[name]
    return F


def hinge_design(
    omega_p: np.ndarray | None, q: np.ndarray, qd: np.ndarray, tail: Sequence[str] = ("qd", "one")
) -> np.ndarray:
    """The design matrix (T, p) of one joint: :func:`hinge_features` of the parent's angular velocity
    ``omega_p`` (T, 3; None under a root joint on the fixed base), ``q`` and ``qd`` (T,), one row per
    sample, C-contiguous."""
    wh = None if omega_p is None else np.asarray(omega_p).T
    return np.ascontiguousarray(hinge_features(wh, np.cos(q), np.sin(q), qd, tail).T)
