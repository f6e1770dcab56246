"""The shared hinge design and scaled least squares give what each method's own copy gave.

The references below are the three design matrices and the two scaled solvers as the fast estimator,
the health checks and the kinematics wrote them before they were shared, and the child lever-arm
model's design as the sums it is defined by; random inputs, fixed seeds.
The new code does the same floating-point operations in the same order, so the bound is round-off
(1e-12 relative), not a tolerance of the model.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.fast_core import _hop_features
from bodyschema.hinge import hinge_design, hinge_features
from bodyschema.joint_motion import _lstsq_residual
from bodyschema.kinematics.least_squares import solve
from bodyschema.kinematics.lever_arm import CHILD_COLS, _ChildModel, _Modulated
from bodyschema.lstsq import scaled_lstsq
from bodyschema.rigid_motion import rotvec, skew

RTOL = 1e-12


def _ref_fast(wh: np.ndarray | None, c: np.ndarray, s: np.ndarray, qd: np.ndarray) -> np.ndarray:
    B, T = c.shape
    off = 0 if wh is None else 9
    F = np.empty((B, off + 3, T))
    if wh is not None:
        F[:, 0:3] = wh
        np.multiply(wh, c[:, None, :], out=F[:, 3:6])
        np.multiply(wh, s[:, None, :], out=F[:, 6:9])
    F[:, off] = c
    F[:, off + 1] = s
    F[:, off + 2] = qd
    return F


def _ref_health(parent_gyro: np.ndarray | None, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    ones = np.ones((q.shape[0], 1))
    if parent_gyro is None:
        return np.c_[qd, ones]
    c, s = np.cos(q)[:, None], np.sin(q)[:, None]
    return np.c_[parent_gyro, parent_gyro * c, parent_gyro * s, qd, ones]


def _ref_kinematics(omega_p: np.ndarray | None, q: np.ndarray, qd: np.ndarray, measured: bool) -> np.ndarray:
    if omega_p is None:
        return np.c_[qd, np.ones_like(qd)]
    X = np.c_[omega_p, omega_p * np.cos(q)[:, None], omega_p * np.sin(q)[:, None], qd, np.ones_like(qd)]
    return np.c_[X, np.cos(q), np.sin(q)] if measured else X


def _ref_health_fit(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, float]:
    scale = np.sqrt(np.mean(X**2, axis=0))
    scale[scale < 1e-12] = 1.0
    Xs = X / scale
    coef = np.linalg.pinv(Xs.T @ Xs, rcond=1e-10, hermitian=True) @ (Xs.T @ Y)
    return coef / scale[:, None], float(np.sum((Y - Xs @ coef) ** 2))


def _ref_solve(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None) -> tuple[np.ndarray, ...]:
    T, m, p = X.shape
    flat = X.reshape(T * m, p)
    scale = np.sqrt(np.mean(flat * flat, axis=0))
    scale[scale < 1e-12] = 1.0
    Xs = flat / scale
    G = Xs.T @ Xs
    if ridge is not None:
        G = G + np.diag(ridge / scale**2)
    Gi = np.linalg.pinv(G, rcond=1e-10, hermitian=True)
    beta = Gi @ (Xs.T @ Y.reshape(T * m))
    e = (Y.reshape(T * m) - Xs @ beta).reshape(T, m)
    return Xs.reshape(T, m, p), scale, Gi, beta, e


def _close(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * max(float(np.max(np.abs(b))), 1.0))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("parent", [False, True])
def test_hinge_design_equals_each_former_copy(seed: int, parent: bool) -> None:
    rng = np.random.default_rng(seed)
    T, B = 257, 4
    q, qd = rng.uniform(-3, 3, T), rng.normal(0, 2, T)
    omega = rng.normal(0, 1, (T, 3)) if parent else None
    _close(hinge_design(omega, q, qd), _ref_health(omega, q, qd))
    for measured in (False, True):
        tail = ("qd", "one", "cos", "sin") if measured and parent else ("qd", "one")
        _close(hinge_design(omega, q, qd, tail), _ref_kinematics(omega, q, qd, measured))
    qs, qds = rng.uniform(-3, 3, (B, T)), rng.normal(0, 2, (B, T))
    wh = None if omega is None else omega.T
    c, s = np.cos(qs), np.sin(qs)
    _close(_hop_features(wh, c, s, qds), _ref_fast(wh, c, s, qds))
    _close(hinge_features(wh, c, s, qds), _ref_fast(wh, c, s, qds))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scaled_lstsq_equals_each_former_copy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T, m, p = 300, 3, 8
    X = rng.normal(0, 1, (T * m, p)) * rng.uniform(1e-3, 1e3, p)
    X[:, -1] = X[:, 0] * 2.0  # collinear columns: the pseudo-inverse's minimum-norm branch
    Y = rng.normal(0, 1, (T * m, 3))
    coef, rss = _ref_health_fit(X, Y)
    _close(scaled_lstsq(X, Y).coef, coef)
    assert _lstsq_residual(X, Y) == pytest.approx(rss, rel=RTOL)
    for ridge in (None, rng.uniform(0, 10, p)):
        new = solve(X.reshape(T, m, p), Y[:, 0].reshape(T, m), ridge)
        old = _ref_solve(X.reshape(T, m, p), Y[:, 0].reshape(T, m), ridge)
        for a, b in zip(new, old, strict=True):
            _close(a, b)


def test_unknown_hinge_column_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown hinge column 'bias'"):
        hinge_design(None, np.zeros(3), np.zeros(3), ("qd", "bias"))


def _ref_child_design(
    R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, *arrays: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The child model's design written as the sums over the three modulations it is defined by."""
    F_, G_, K_, o_ = arrays
    uu = np.outer(axis, axis)
    P = (uu @ R, (np.eye(3) - uu) @ R, -skew(axis) @ R)
    RF = sum(F @ Pm.T for Pm, F in zip(P, F_, strict=True))
    RG = sum(F @ Pm.T for Pm, F in zip(P, G_, strict=True))
    X = np.zeros((RF.shape[0], 3, CHILD_COLS))
    X[:, :, 0:3] = RG[:, :, None] * np.eye(3)
    X[:, :, 3:6] = o_[0][:, None, None] * np.eye(3)
    X[:, :, 6:9] = sum(Pm[None, :, :] * o[:, None, None] for Pm, o in zip(P, o_, strict=True))
    X[:, :, 9:12] = sum(Pm[None, :, :] * F[:, None, :] for Pm, F in zip(P, G_, strict=True))
    X[:, :, 12:18] = sum(np.matmul(Pm, K) for Pm, K in zip(P, K_, strict=True))
    X[:, :, 18:22] = kcu
    return X, RF


@pytest.mark.parametrize("seed", [0, 1])
def test_stacked_child_design_equals_its_sums_over_the_modulations(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = 50
    F_, G_ = ([rng.normal(size=(T, 3)) for _ in range(3)] for _ in range(2))
    K_ = [rng.normal(size=(T, 3, 6)) for _ in range(3)]
    o_ = [rng.normal(size=T) for _ in range(3)]
    R = rotvec(rng.normal(size=3))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    kcu = rng.normal(size=(T, 3, 4))
    X, RF = _ChildModel.build(R, axis, kcu, _Modulated.of(F_, G_, K_, o_))
    X0, RF0 = _ref_child_design(R, axis, kcu, F_, G_, K_, o_)
    _close(X, X0)
    _close(RF, RF0)
