"""IMU lever arms: the accelerometer models of a root joint's link and of a child link (package docstring)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bodyschema.kinematics.acc_frame import child_frame, gyro_frame_prior
from bodyschema.kinematics.least_squares import (
    hac_fit,
    penalized,
    prior_residuals,
    prior_ridge,
    refine,
    residuals,
    solve,
)
from bodyschema.kinematics.results import KinematicsOptions
from bodyschema.kinematics.signals import Signals, kmats, lever_basis, stack_design
from bodyschema.rigid_motion import perp_basis, rotation_about, skew

__all__ = [
    "CHILD_COLS",
    "ChildInputs",
    "LeverFit",
    "lever_child",
    "lever_root",
]


@dataclass(frozen=True)
class LeverFit:
    r: np.ndarray
    std_m: float
    d: np.ndarray | None = None
    M0: np.ndarray | None = None  # R0 refined by the accelerometers
    up: np.ndarray | None = None  # root joint: the specific force at q = 0 (gravity's tilt, bias in it)
    turning: np.ndarray | None = None  # root joint: the part of it that turns with q (G1)
    r_tangential: np.ndarray | None = None  # the lever arm the tangential term alone implies
    axis: np.ndarray | None = None  # child joint: the axis in the accelerometer's frame
    axis_std_deg: float = math.nan
    force: np.ndarray | None = None  # the model's specific force (T, 3) at the aligned rate, noise-free
    turn_std_deg: float = math.nan  # under a one-axis parent: the std of R0's turn about that axis


def lever_root(sig: Signals, j: int, c: int, u: np.ndarray, omega_c: np.ndarray) -> LeverFit:
    """Root joint, fixed base: ``f_c = G0 + G1 cos q + G2 sin q + [α]× r_t + [ω]×[ω]× r`` with ``r ⊥ u``."""
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    U = perp_basis(u)
    Ka, Kw = kmats(sig, omega_c)
    rows = sig.band_limit(np.c_[np.ones_like(q), np.cos(q), np.sin(q)])
    X = stack_design(rows, [sig.band_limit(Ka @ U), sig.band_limit(Kw @ U)])
    f = hac_fit(X, sig.band_limit(r.acc[:, c]), sig.lags)
    cov_r = U @ f.cov[-2:, -2:] @ U.T
    G = f.coef[:9].reshape(3, 3)
    Xa = stack_design(np.c_[np.ones_like(q), np.cos(q), np.sin(q)], [Ka @ U, Kw @ U])
    return LeverFit(
        r=U @ f.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        up=G[:, 0] + G[:, 1],
        turning=G[:, 1],
        r_tangential=U @ f.coef[-4:-2],
        force=np.einsum("tmp,p->tm", Xa, f.coef),
    )


#: The child model's linear parameters (:func:`lever_child`): δ_c 0:3, b_c 3:6, b_p 6:9, δ_p 9:12,
#: d_t 12:15, d 15:18, r_t 18:20, r 20:22; the gains are δ_c and δ_p.
CHILD_COLS = 22
CHILD_GAINS = [0, 1, 2, 9, 10, 11]
CHILD_BIASES = [3, 4, 5, 6, 7, 8]


@dataclass(frozen=True)
class _Modulated:
    """The child model's regressors ``(R(q) f_p, gain columns, K_p, 1)`` modulated by ``1, cos q, sin q``
    (index m), stacked so that :meth:`_ChildModel.build` turns each block with one matrix product over
    the three modulations' ``P_m`` at once rather than a sum of three batched 3 x 3 products."""

    F: np.ndarray  # (T, 9): F_m[t, j] at column 3 m + j
    G: np.ndarray  # (T, 9) the same for the gain columns
    G3: np.ndarray  # (T, 3, 3): G_m[t, j] at [t, m, j]
    K: np.ndarray  # (9, T * 6): K_m[t, j, k] at [3 m + j, 6 t + k]
    o: np.ndarray  # (T, 3): the modulations themselves, o_m[t] at [t, m]

    @classmethod
    def of(
        cls, F_: list[np.ndarray], G_: list[np.ndarray], K_: list[np.ndarray], o_: list[np.ndarray]
    ) -> _Modulated:
        T = F_[0].shape[0]
        G3 = np.stack(G_, axis=1)
        K = np.stack(K_).transpose(0, 2, 1, 3).reshape(9, T * K_[0].shape[2])
        return cls(F=np.concatenate(F_, axis=1), G=G3.reshape(T, 9), G3=G3, K=K, o=np.stack(o_, axis=1))


@dataclass(frozen=True)
class _ChildModel:
    """The child model's regressors, modulated by ``1, cos q, sin q`` and band-limited once, and the
    fits :func:`lever_child` searches over ``R0`` and the axis with."""

    raw: _Modulated  # (R(q) f_p, gain columns, K_p) regressors at the aligned rate
    banded: _Modulated  # the same through the common band, then the bands of the modulations
    Y: np.ndarray
    u: np.ndarray
    KcU: np.ndarray
    stds: np.ndarray
    lags: int

    @classmethod
    def of(
        cls,
        sig: Signals,
        j: int,
        c: int,
        p: int,
        u: np.ndarray,
        kc: tuple[np.ndarray, np.ndarray],
        f: ChildInputs,
    ) -> _ChildModel:
        r = sig.rec
        q = r.q[:, j]  # type: ignore[index]
        mods = [np.ones_like(q), np.cos(q), np.sin(q)]
        fp = r.acc[:, p]
        Kp = np.concatenate(kmats(sig, f.omega_p), axis=2)  # (T, 3, 6): d_t then d
        # the regressors at the aligned rate (the model's prediction below) and through the common band
        raw = (
            [m[:, None] * fp for m in mods],
            [m[:, None] * (fp if f.fp_model is None else f.fp_model) for m in mods],
            [m[:, None, None] * Kp for m in mods],
        )
        Fm, Gm, Km = ([sig.band_limit(x) for x in xs] for xs in raw)
        ones = [sig.band_limit(m) for m in mods]
        return cls(
            raw=_Modulated.of(*raw, mods),
            banded=_Modulated.of(Fm, Gm, Km, ones),
            Y=sig.band_limit(r.acc[:, c]),
            u=u,
            KcU=lever_basis(sig, kc, perp_basis(u)),
            stds=_child_prior_stds(f.opts),
            lags=sig.lags,
        )

    @staticmethod
    def build(
        R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, a: _Modulated
    ) -> tuple[np.ndarray, np.ndarray]:
        """Design (T, 3, 22) and the known part ``R(q) f_p`` (T, 3) from the modulated regressors."""
        uu, ux = np.outer(axis, axis), skew(axis)
        P = np.stack((uu @ R, (np.eye(3) - uu) @ R, -ux @ R))  # P_m[i, j] at [m, i, j]
        Pt = P.transpose(0, 2, 1).reshape(9, 3)  # P_m[i, j] at [3 m + j, i]
        T = a.F.shape[0]
        RF, RG = a.F @ Pt, a.G @ Pt
        X = np.zeros((T, 3, CHILD_COLS))
        for i in range(3):
            X[:, i, i] = RG[:, i]
            X[:, i, 3 + i] = a.o[:, 0]
            X[:, :, 9 + i] = a.G3[:, :, i] @ P[:, :, i]
        X[:, :, 6:9] = (a.o @ P.reshape(3, 9)).reshape(T, 3, 3)
        X[:, :, 12:18] = (P.transpose(1, 0, 2).reshape(3, 9) @ a.K).reshape(3, T, 6).transpose(1, 0, 2)
        X[:, :, 18:22] = kcu
        return X, RF

    def design(
        self, R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, ridge: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The design and what it leaves to fit, less the gains' product with the rest of the specific
        force the child feels, as a fit without it and with the gains' prior tells them
        (:func:`_felt_beyond`)."""
        X, RF = self.build(R, axis, kcu, self.banded)
        _, scale, _, beta, _ = solve(X, self.Y - RF, ridge)
        return X, self.Y - RF - _felt_beyond(X, beta / scale)

    def resid(
        self, R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, ridge: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The residuals of :meth:`design` with the priors ``ridge`` in both fits, which share one
        factorization: the second moves the first's residuals ``e`` by the product ``p`` less its
        projection onto the design, and its coefficients by ``p``'s fit; and the priors' residuals
        (:func:`prior_residuals`) of the second's coefficients."""
        X, RF = self.build(R, axis, kcu, self.banded)
        Xs, scale, Gi, beta, e = solve(X, self.Y - RF, ridge)
        flat = Xs.reshape(-1, CHILD_COLS)
        p = _felt_beyond(X, beta / scale).reshape(-1)
        moved = Gi @ (flat.T @ p)
        e2 = e - (p - flat @ moved).reshape(e.shape)
        return e2, prior_residuals(ridge, (beta - moved) / scale)

    def gains_prior(self, R: np.ndarray) -> np.ndarray:
        """The gains' datasheet prior (:func:`prior_ridge`) against the residuals of the fit without it
        at ``R``: the product needs plausible gains where the data leave some freedom."""
        X, RF = self.build(R, self.u, self.KcU, self.banded)
        return prior_ridge(residuals(X, self.Y - RF), self.lags, self.stds)

    def fit(self, R: np.ndarray, ridge: np.ndarray | None = None) -> float:
        """The linear fit's objective without the product (the turn's search only has to find the well
        that the accelerometers' frame then refines): the residual sum of squares, plus the priors'
        ``Σ ridge β²`` when the priors ``ridge`` are given (:func:`penalized`)."""
        X, RF = self.build(R, self.u, self.KcU, self.banded)
        e, pen = penalized(X, self.Y - RF, ridge)
        return float(np.sum(e * e) + np.sum(pen * pen))

    def judged(self, R: np.ndarray) -> float:
        return self.fit(R, self.gains_prior(R))


@dataclass(frozen=True)
class ChildInputs:
    """What :func:`lever_child` reads besides the signals: the two links' rebuilt angular velocities,
    the gyro's ``R0`` and how many axes the parent turned about, the parent's modelled force."""

    omega_c: np.ndarray
    omega_p: np.ndarray
    R0: np.ndarray
    span_rank: int
    parent_axis: np.ndarray
    opts: KinematicsOptions
    noise_var: float
    fp_model: np.ndarray | None = None


def lever_child(sig: Signals, j: int, c: int, p: int, u: np.ndarray, f: ChildInputs) -> LeverFit:
    """Child of a link with an IMU: the accelerometer model with ``R(q) = Rot(u, -q) R0`` a rotation.

    ``f_c = s_c + δ_c ⊙ s_c + b_c`` with ``s_c = R(q) (f_p + δ_p ⊙ f_p + b_p + K_p d) + K_c r``, the
    specific force the child feels: the two accelerometers' gains to first order (``δ``, a few %) and
    their biases, the parent's seen through the turning joint. Given ``R0`` it is linear but for the
    product of ``δ_c`` with the rest (:func:`_felt_beyond`), taken by one step of alternating least
    squares in every evaluation of the residual. The gyro fixes ``R0`` on the directions the parent
    turned about; a one-axis parent's remaining turn is the accelerometers' (:func:`_turn_about_parent`).
    With ``opts.accelerometer_frame`` the accelerometers then decide the child's frame
    (:func:`~bodyschema.kinematics.acc_frame.child_frame`).

    Why so: the gain columns use ``fp_model``, the parent's modelled force, because its noisy reading
    makes an errors-in-variables fit that leans the axis; the gains scale ``s_c``, not ``R(q) f_p``; and
    they keep their datasheet prior even in the final fit (docs/kinematics.md, "Findings", records the
    measurements behind each choice).
    """
    opts = f.opts
    kc = kmats(sig, f.omega_c)
    m = _ChildModel.of(sig, j, c, p, u, kc, f)
    stds, KcU, U = m.stds, m.KcU, perp_basis(u)
    one_axis = f.span_rank == 1
    R = f.R0 if not one_axis else _turn_about_parent(m.fit, m.judged, f.R0, f.R0 @ f.parent_axis)
    R_gyro, axis, axis_std = R, u, math.nan
    ridge = m.gains_prior(R)
    if opts.accelerometer_frame:
        # the gyro's prior on R0, weighed against the data as the gains' prior is
        held = gyro_frame_prior(
            None if not one_axis else R @ f.parent_axis,
            ridge[CHILD_GAINS[0]] * stds[CHILD_GAINS[0]] ** 2,
            f.noise_var,
            opts,
        )
        axis, axis_std, R, U, KcU = child_frame(
            m.resid, CHILD_COLS, R_gyro, u, kc, sig, f.noise_var, ridge, held, opts
        )
    turn_std = (
        math.nan if not one_axis else _turn_std(m.resid, R, axis, KcU, ridge, R @ f.parent_axis, sig.lags)
    )
    X, Yr = m.design(R, axis, KcU, ridge)
    fit = hac_fit(X, Yr, sig.lags)
    cov_r = U @ fit.cov[-2:, -2:] @ U.T
    kca = np.concatenate([kc[0] @ U, kc[1] @ U], axis=2)
    Xa, RFa = m.build(R, axis, kca, m.raw)
    return LeverFit(
        r=U @ fit.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        d=fit.coef[15:18],
        M0=R,
        r_tangential=U @ fit.coef[-4:-2],
        axis=axis,
        axis_std_deg=axis_std,
        force=RFa + _felt_beyond(Xa, fit.coef) + Xa @ fit.coef,
        turn_std_deg=turn_std,
    )


def _child_prior_stds(opts: KinematicsOptions) -> np.ndarray:
    """The child model's priors (:func:`prior_ridge`): the datasheet's gains and biases of both accelerometers
    (uniform within their half-widths), none on the rest.

    The biases' prior matters where the data leave a bias free to take more than a bias: under a
    vertical root axis the parent's specific force is a constant gravity in its own frame, and
    ``R(q) b_p`` can trade it for any other constant, which frees ``R0`` to turn the image of the
    parent's axis, which the gyro had fixed. The MPU-6050's zero-g offset is at most 80 mg; turning
    gravity by θ takes ``2 g sin(θ/2)``, 0.17 m/s² a degree."""
    stds = np.full(CHILD_COLS, np.inf)
    stds[CHILD_GAINS] = opts.acc_scale_error / math.sqrt(3.0)
    stds[CHILD_BIASES] = opts.acc_bias / math.sqrt(3.0)
    return stds


def _felt_beyond(X: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """``δ_c ⊙ (s_c - R(q) f_p)`` (T, 3) of the child model (:func:`lever_child`) with design ``X`` and
    coefficients ``coef`` (:data:`CHILD_COLS`): the child's gains times the rest of the specific force
    it feels, ``R(q) (δ_p ⊙ f_p + b_p + K_p d) + K_c r``, which are the columns after its bias."""
    return coef[0:3] * (X[:, :, 6:] @ coef[6:])


def _turn_about_parent(
    fit: Callable[[np.ndarray], float], judged: Callable[[np.ndarray], float], R0: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """``R0`` turned about ``w``, the image of a root parent's one axis, by the angle that minimises the
    child model's accelerometer residual (``fit(R)``, its residual sum of squares).

    The gyro fixed ``R0`` on the parent's axis only: the turn about its image is the accelerometers'.
    A half turn fits as well with gains of -1 (the parent's specific force flipped across its axis),
    and often better: those gains drop the parent's noisy reading for its modelled force in the gain
    columns, and its noise from the residual. So the two wells half a turn apart are both refined (a
    coarse grid, then a bounded search) and the one the gains' datasheet prior favours kept:
    ``judged(R)``, the fit's residual sum of squares plus the prior's penalty on its gains, each fitted
    with that prior. The largest gain alone would not do: the parent's gain along its own axis, which
    the data do not tell, would decide, and a kept flipped well turns ``rotation_from_parent`` and the
    gains' product (:func:`_felt_beyond`) by half a turn (docs/kinematics.md, "Findings")."""
    from scipy.optimize import minimize_scalar

    turn = lambda phi: rotation_about(w, np.array([phi]))[0] @ R0  # noqa: E731
    grid = np.linspace(-np.pi, np.pi, 36, endpoint=False)
    h = grid[1] - grid[0]
    rss = np.array([fit(turn(g)) for g in grid])
    half = len(grid) // 2
    best = int(np.argmin(rss))
    other = (best + half - 2) + int(
        np.argmin([rss[(best + half + k) % len(grid)] for k in (-2, -1, 0, 1, 2)])
    )
    found = []
    for start in (grid[best], grid[other % len(grid)]):
        phi = minimize_scalar(lambda x: fit(turn(x)), bounds=(start - h, start + h), method="bounded").x
        found.append((judged(turn(float(phi))), float(phi)))
    return turn(min(found)[1])


def _turn_std(
    resid: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]],
    R: np.ndarray,
    axis: np.ndarray,
    kcu: np.ndarray,
    ridge: np.ndarray,
    w: np.ndarray,
    lags: int,
) -> float:
    """The std (degrees) of the turn of ``R`` about ``w``, a one-axis parent's axis in the child's frame."""
    w = w / np.linalg.norm(w)

    def about(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return resid(rotation_about(w, x)[0] @ R, axis, kcu, ridge)

    return math.degrees(math.sqrt(max(float(refine(about, 1, CHILD_COLS, lags).cov[0, 0]), 0.0)))
