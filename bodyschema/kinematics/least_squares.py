"""Least squares with a Newey-West covariance, zero-mean priors and variable projection: every fit of
the kinematics (band-limited residuals are autocorrelated, so the sandwich needs a Bartlett window)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bodyschema.lstsq import scaled_lstsq

__all__ = [
    "Fit",
    "hac_fit",
    "newey_west",
    "penalized",
    "per_axis",
    "prior_residuals",
    "prior_ridge",
    "refine",
    "residuals",
    "solve",
    "variances",
]


@dataclass(frozen=True)
class Fit:
    coef: np.ndarray
    cov: np.ndarray
    resid: np.ndarray


def hac_fit(X: np.ndarray, Y: np.ndarray, lags: int, ridge: np.ndarray | None = None) -> Fit:
    """Stacked least squares ``Y[t] ≈ X[t] @ β`` with X (T, m, p), Y (T, m) and its Newey-West covariance.

    Columns are scaled for conditioning; a rank-deficient design (a nuisance block that the data do
    not excite) gets the minimum-norm solution, which leaves the identifiable parameters unchanged.
    ``ridge`` (p,) adds ``Σ ridge_k β_k²`` to the squared residuals: zero-mean priors (:func:`prior_ridge`).
    """
    T, m, p = X.shape
    Xs, scale, Gi, beta, e = solve(X, Y, ridge)
    g = np.einsum("tmi,tm->ti", Xs, e)
    dof = max(T * m - p, 1)
    cov = Gi @ newey_west(g, lags) @ Gi * (T * m / dof)
    return Fit(coef=beta / scale, cov=cov / np.outer(scale, scale), resid=e)


def solve(
    X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The least squares of :func:`hac_fit` without its covariance: scaled design, column scales, inverse
    normal matrix, scaled coefficients and residuals (T, m). Flat matrix products keep it on BLAS."""
    T, m, p = X.shape
    y = Y.reshape(T * m)
    fit = scaled_lstsq(X.reshape(T * m, p), y, ridge)
    e = (y - fit.Xs @ fit.beta).reshape(T, m)
    return fit.Xs.reshape(T, m, p), fit.scale, fit.Gi, fit.beta, e


def residuals(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None = None) -> np.ndarray:
    """The residuals (T, m) of :func:`hac_fit`'s fit, all that a variable projection needs."""
    return solve(X, Y, ridge)[4]


def newey_west(g: np.ndarray, lags: int) -> np.ndarray:
    """The long-run covariance of the scores ``g`` (T, p): Bartlett-weighted autocovariances to ``lags``."""
    S = g.T @ g
    for k in range(1, lags + 1):
        w = 1.0 - k / (lags + 1)
        Gk = g[k:].T @ g[:-k]
        S += w * (Gk + Gk.T)
    return S


def prior_ridge(e: np.ndarray, lags: int, stds: np.ndarray) -> np.ndarray:
    """The ridge of :func:`hac_fit` for zero-mean priors of std ``stds`` (p,) on the coefficients (``inf``:
    none).

    Weighed against the data, whose residuals ``e`` (T, m) have the variance ``σe²`` and are
    correlated over about ``κ`` samples (Newey-West long-run variance over the plain one): the data
    count as ``Σ e² / (κ σe²)``, a prior as ``β² / std²``, so its ridge is ``κ σe² / std²``.
    """
    var = float(np.mean(e * e))
    long_run = float(np.mean([newey_west(e[:, i : i + 1], lags)[0, 0] for i in range(e.shape[1])]))
    kappa = long_run / max(var * e.shape[0], 1e-300)
    return kappa * var / np.asarray(stds, dtype=float) ** 2


def penalized(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The residuals (T, m) of :func:`hac_fit`'s fit and its priors' ``sqrt(ridge_k) β_k`` (k,) for the
    coefficients that have one: together, all that a variable projection (:func:`refine`) needs."""
    _, scale, _, beta, e = solve(X, Y, ridge)
    return e, prior_residuals(ridge, beta / scale)


def prior_residuals(ridge: np.ndarray | None, coef: np.ndarray) -> np.ndarray:
    """``sqrt(ridge_k) β_k`` for the coefficients ``coef`` with a prior: the priors as residuals."""
    if ridge is None:
        return np.zeros(0)
    has = ridge > 0
    return np.sqrt(ridge[has]) * coef[has]


def refine(
    residual: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], n: int, n_linear: int, lags: int
) -> Fit:
    """Nonlinear least squares over ``n`` small parameters (radians), from zero, and their covariance.

    ``residual(x)`` returns the (T, m) residuals left once the model's ``n_linear`` linear parameters
    are fitted for ``x`` (variable projection), and the residuals of those parameters' priors
    (:func:`prior_residuals`). The objective is the sum of both's squares: the priors' residuals belong
    in it, as the linear fit itself weighs them. Without them a search could trade the data's
    residual for a coefficient the prior rules out (docs/kinematics.md, "Findings"). The covariance is
    the Newey-West sandwich of the Jacobian at the solution, as in :func:`hac_fit`, with the priors in
    its bread and only the data in its meat. ``coef`` is the solution, ``resid`` its residuals.
    """
    from scipy.optimize import least_squares

    e0, _ = residual(np.zeros(n))
    T, m = e0.shape
    sol = least_squares(
        lambda x: np.concatenate([r.ravel() for r in residual(x)]),
        np.zeros(n),
        x_scale=0.01,
        diff_step=1e-4,
        ftol=1e-6,
        xtol=1e-4,
    )
    e = sol.fun[: T * m].reshape(T, m)
    J = sol.jac[: T * m].reshape(T, m, n)
    Hi = np.linalg.pinv(sol.jac.T @ sol.jac, rcond=1e-10, hermitian=True)
    g = np.einsum("tmi,tm->ti", J, e)
    dof = max(T * m - n - n_linear, 1)
    return Fit(coef=sol.x, cov=Hi @ newey_west(g, lags) @ Hi * (T * m / dof), resid=e)


def per_axis(X: np.ndarray, Y: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Y (T, 3) ≈ X (T, p) @ coef (p, 3), one fit per column; returns coef and each column's
    covariance (3, p, p)."""
    coef = np.empty((X.shape[1], Y.shape[1]))
    cov = np.empty((Y.shape[1], X.shape[1], X.shape[1]))
    for i in range(Y.shape[1]):
        f = hac_fit(X[:, None, :], Y[:, i : i + 1], lags)
        coef[:, i] = f.coef
        cov[i] = f.cov
    return coef, cov


def variances(cov: np.ndarray) -> np.ndarray:
    """The (p, 3) coefficient variances of :func:`per_axis`'s covariances."""
    return np.diagonal(cov, axis1=1, axis2=2).T
