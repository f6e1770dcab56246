"""The axis and the child's frame in the accelerometer's frame, fused with the gyro's reading."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bodyschema.kinematics.least_squares import Fit, penalized, prior_ridge, refine
from bodyschema.kinematics.results import KinematicsOptions
from bodyschema.kinematics.signals import Signals, lever_basis
from bodyschema.rigid_motion import perp_basis, rotvec, skew, tilted

__all__ = [
    "child_frame",
    "fuse",
    "gyro_frame_prior",
    "root_axis_acc",
]


def _gyro_lean_cov(u: np.ndarray, U: np.ndarray, opts: KinematicsOptions) -> np.ndarray:
    """Prior covariance (2, 2, rad²) of the lean of the axis a gyro reports, in the basis ``U``.

    The gyro reads ``S ω`` with ``S = I + diag(s) + C`` (scale errors ``s_i`` and cross-axis terms
    ``C_ij``, uniform within the datasheet's half-widths), so the axis it reports is ``S u``. Along a
    unit ``e ⊥ u`` that leans by ``Σ_i e_i s_i u_i + Σ_{i≠j} e_i C_ij u_j``, whose covariance between two
    directions ``e``, ``f`` is ``σs² Σ_i e_i f_i u_i² + σc² Σ_i e_i f_i (1 - u_i²)``.
    """
    vs, vc = opts.gyro_scale_error**2 / 3.0, opts.gyro_cross_axis**2 / 3.0
    return U.T @ np.diag(vs * u**2 + vc * (1.0 - u**2)) @ U


def fuse(
    u: np.ndarray, noise_var: float, acc: Fit, at: slice, opts: KinematicsOptions
) -> tuple[np.ndarray, float]:
    """The axis from the gyro's reading ``u`` and the accelerometers' lean of it, and its RMS error (°).

    Two estimates of the lean ``θ`` (basis :func:`perp_basis`): the gyro's, zero with its noise
    (``noise_var`` per direction) plus the prior of :func:`_gyro_lean_cov`, and the accelerometers'
    (``acc.coef[at]``, sandwich covariance plus the model error), combined by their inverse
    covariances. Where the accelerometers see the axis well the answer is theirs, in their frame; where
    they do not, it stays near the gyro's with the prior's uncertainty.

    The model error (``acc_model_error_deg`` RMS, split over the two directions) is what the
    sandwich covariance cannot know: an error of the accelerometers' lean that does not shrink with the
    recording's length, measured on simulated trees (docs/kinematics.md, "Findings").
    """
    U = perp_basis(u)
    Cg = _gyro_lean_cov(u, U, opts) + noise_var * np.eye(2)
    # the model error along the directions the accelerometers see; a direction they do not see (a zero
    # of the sandwich covariance: the fit never depended on it) stays without information
    w, V = np.linalg.eigh(acc.cov[at, at])
    seen = w > max(1e-12 * float(w.max()), 0.0)
    model = math.radians(opts.acc_model_error_deg) ** 2 / 2.0
    Pa = (V[:, seen] / (w[seen] + model)) @ V[:, seen].T
    C = np.linalg.inv(np.linalg.inv(Cg) + Pa)
    theta = C @ Pa @ acc.coef[at]
    return tilted(u, U, theta), math.degrees(math.sqrt(max(float(np.trace(C)), 0.0)))


def root_axis_acc(sig: Signals, j: int, c: int, u: np.ndarray, turning: np.ndarray, gain_std: float) -> Fit:
    """The lean of a root joint's axis the accelerometer implies (:func:`refine` over two angles).

    Gravity seen from the link turns about the true axis: ``f_c = D Rot(u, -q) g0 + b + [α]× r_t +
    [ω]×[ω]× r`` with the accelerometer's gains ``D = I + diag(δ)`` taken to first order about
    ``turning``, the part of gravity at ``q = 0`` that turns with ``q`` (the part along the axis stays,
    as does the bias: both are in ``b``). Given ``u`` it is linear in (δ, g0, b, r_t, r). The gains are
    free, yet the lean is not: ``D⁻¹`` must make the two gravity components that turn with ``q``
    perpendicular and equally long, two conditions on two gain ratios. That leaves nothing over, so
    the gains also get the datasheet's prior (``gain_std``, :func:`.prior_ridge`). A vertical axis
    (gravity never turns) leaves the lean to the gyro through a large covariance.
    """
    q = sig.rec.q[:, j]  # type: ignore[index]
    qd = sig.rec.qd[:, j]  # type: ignore[index]
    # ω = v q̇ under a root joint: [α]× = q̈ [v]×, [ω]×[ω]× = q̇² [v]×², so the band limit of every
    # regressor is that of a scalar signal times a constant matrix, for any leaned axis v
    rows = sig.band_limit(np.c_[np.ones_like(q), np.cos(q), np.sin(q), sig.derivative(qd), qd * qd])
    o, cq, sq, qdd, qd2 = (rows[:, k][:, None, None] for k in range(5))
    U = perp_basis(u)
    Y = sig.band_limit(sig.rec.acc[:, c])
    eye = np.eye(3)
    ridge: np.ndarray | None = None

    def resid(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = tilted(u, U, theta)
        vx = skew(v)
        Uv = perp_basis(v)
        Rq = cq * eye + (o - cq) * np.outer(v, v) - sq * vx  # band-limited Rot(v, -q)
        X = np.zeros((Y.shape[0], 3, 13))
        X[:, :, 0:3] = (Rq @ turning)[:, :, None] * eye
        X[:, :, 3:6] = Rq
        X[:, :, 6:9] = o * eye
        X[:, :, 9:11] = qdd * (vx @ Uv)
        X[:, :, 11:13] = qd2 * (vx @ vx @ Uv)
        return penalized(X, Y, ridge)

    stds = np.full(13, np.inf)
    stds[0:3] = gain_std
    ridge = prior_ridge(resid(np.zeros(2))[0], sig.lags, stds)
    return refine(resid, 2, 13, sig.lags)


def gyro_frame_prior(
    w: np.ndarray | None, data_var: float, noise_var: float, opts: KinematicsOptions
) -> np.ndarray:
    """The gyro's prior on a turn ``x`` (rotation vector, child frame) of the ``R0`` it read, as the rows
    (k, 3) whose product with ``x`` are its residuals, weighed against the data as :func:`prior_ridge` weighs
    (``data_var``: the data's ``κ σe²``).

    The gyro fixes ``R0`` on the directions the parent link turned about: all of it where that is two
    axes or more (``w`` None), the image ``w`` of its one axis otherwise, which leaves the turn about
    ``w`` free. Each gyro's sensitivity errors turn what it reads by at most the larger of its gain and
    cross-axis variances per direction (:func:`_gyro_lean_cov`), and ``R0`` is read by two gyros, so
    each fixed direction gets ``2 max(σs², σc²)`` plus the fit's noise. The accelerometers' search needs
    it: under a vertical root axis the parent's specific force along that axis is gravity, a constant
    its bias can trade, and the turn of ``w`` is then the biases' prior's alone (0.17 m/s² a degree)."""
    var = 2.0 * max(opts.gyro_scale_error, opts.gyro_cross_axis) ** 2 / 3.0 + noise_var
    rows = np.eye(3) if w is None else perp_basis(w / np.linalg.norm(w)).T
    return math.sqrt(data_var / var) * rows


def child_frame(
    resid: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]],
    n_linear: int,
    R: np.ndarray,
    u: np.ndarray,
    kc: tuple[np.ndarray, np.ndarray],
    sig: Signals,
    noise_var: float,
    ridge: np.ndarray,
    held: np.ndarray,
    opts: KinematicsOptions,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """A child link's accelerometer frame (:func:`.lever_child`): the axis, its std, ``R0``, the lever-arm
    plane and its regressors. ``resid(R0, axis, lever regressors, ridge)`` are the child model's
    residuals and its priors' (``n_linear`` linear parameters), ``ridge`` the priors
    (:func:`.prior_ridge`), ``held @ x`` the residuals of the gyro's prior on the turn ``x`` of ``R0``
    (:func:`gyro_frame_prior`)."""
    U = perp_basis(u)
    KcU = lever_basis(sig, kc, U)

    def lean(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, pen = resid(rotvec(x[:3]) @ R, tilted(u, U, x[3:]), KcU, ridge)
        return e, np.concatenate([pen, held @ x[:3]])

    axis, std = fuse(u, noise_var, refine(lean, 5, n_linear, sig.lags), slice(3, 5), opts)
    U = perp_basis(axis)
    KcU = lever_basis(sig, kc, U)

    def turned(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, pen = resid(rotvec(x) @ R, axis, KcU, ridge)
        return e, np.concatenate([pen, held @ x])

    return axis, std, rotvec(refine(turned, 3, n_linear, 0).coef) @ R, U, KcU
