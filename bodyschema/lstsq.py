"""Least squares on scaled columns, the one solver behind health's and kinematics' linear fits.

Columns are scaled to unit RMS so that the normal matrix is well enough conditioned to be solved
directly, and pseudo-inverted so that a rank-deficient design (a frozen encoder, a nuisance block the
data do not excite) gets the minimum-norm solution, leaving the identifiable parameters unchanged.
The small (p x p) normal matrix is far cheaper than an SVD of the tall (n x p) design.

>>> import numpy as np
>>> X = np.c_[np.arange(5.0), np.ones(5)]
>>> fit = scaled_lstsq(X, 2 * np.arange(5.0) + 1)
>>> np.round(fit.coef, 9).tolist()
[2.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ScaledFit", "scaled_lstsq"]


@dataclass(frozen=True)
class ScaledFit:
    """A fit of :func:`scaled_lstsq`: the scaled design ``Xs`` (n, p), the column ``scale`` (p,), the
    inverse normal matrix ``Gi`` (p, p) and the scaled coefficients ``beta`` (p,) or (p, k)."""

    Xs: np.ndarray
    scale: np.ndarray
    Gi: np.ndarray
    beta: np.ndarray

    @property
    def coef(self) -> np.ndarray:
        """The coefficients of the unscaled design."""
        return self.beta / (self.scale if self.beta.ndim == 1 else self.scale[:, None])


def scaled_lstsq(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None = None) -> ScaledFit:
    """``Y ≈ X β`` for X (n, p) and Y (n,) or (n, k); ``ridge`` (p,) adds ``Σ ridge_i β_i²`` (unscaled
    coefficients) to the squared residuals."""
    scale = np.sqrt(np.einsum("ij,ij->j", X, X) / X.shape[0])  # the columns' RMS, without a copy of X
    scale[scale < 1e-12] = 1.0
    Xs = X / scale
    G = Xs.T @ Xs
    if ridge is not None:
        G = G + np.diag(ridge / scale**2)
    Gi = np.linalg.pinv(G, rcond=1e-10, hermitian=True)
    return ScaledFit(Xs=Xs, scale=scale, Gi=Gi, beta=Gi @ (Xs.T @ Y))
