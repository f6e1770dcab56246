"""A joint's axis from the exact hinge gyro model (package docstring), and the gyros' own reading of it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bodyschema.hinge import hinge_design
from bodyschema.kinematics.least_squares import per_axis, variances
from bodyschema.kinematics.signals import Signals
from bodyschema.rigid_motion import project_rotation
from bodyschema.timing import lowpass

__all__ = [
    "AxisFit",
    "GyroReading",
    "axis_fit",
    "gyro_reading",
    "span_axes",
    "span_projector",
]


@dataclass(frozen=True)
class AxisFit:
    axis: np.ndarray
    gain: float
    std_deg: float
    H: np.ndarray | None  # A + B: R0 (times the gyro's gain) on the span the parent's motion excites
    span: np.ndarray | None  # projector onto that span
    coef: np.ndarray  # the per-output-axis fit (p, 3) and its covariances (3, p, p)
    cov: np.ndarray
    backlash_deg: float = math.nan  # the dead band the encoder's steps at reversals tell (drift reading)
    backlash_std_deg: float = math.nan


def span_axes(span: np.ndarray) -> tuple[int, np.ndarray]:
    """How many directions a :func:`span_projector` projector holds, and its strongest direction."""
    return round(float(np.trace(span))), np.linalg.eigh(span)[1][:, -1]


def span_projector(x: np.ndarray, rel: float = 1e-3) -> np.ndarray:
    """Projector onto the directions a (T, 3) signal excites (second-moment eigenvalues above ``rel``)."""
    lam, V = np.linalg.eigh(x.T @ x)
    V = V[:, lam > rel * max(float(lam[-1]), 1e-300)]
    return V @ V.T


def axis_fit(sig: Signals, j: int, c: int, omega_p: np.ndarray | None, measured: bool = False) -> AxisFit:
    """Fit the exact gyro model of the module docstring for child IMU ``c`` of joint ``j``.

    ``omega_p`` is the parent link's angular velocity rebuilt from the encoders (no gyro bias or gain
    in it); None under a root joint on the fixed base. ``measured`` is the drift reading
    (:func:`gyro_reading`): ``omega_p`` is the parent gyro's reading instead, whose bias, seen through
    the turning joint, needs the intercepts ``cos q`` and ``sin q`` too, and whose noise floor a
    direction of the parent's motion must clear (1 % of the strongest's power) to count as excited; and
    the encoder's steps at reversals, a dead band's, get a regressor of their own (:func:`_band_side`).
    """
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    qd = r.qd[:, j]  # type: ignore[index]
    # the parent gyro's bias turns with the joint: a measured parent needs cos q and sin q intercepts
    tail = ("qd", "one", "cos", "sin") if measured and omega_p is not None else ("qd", "one")
    X = hinge_design(omega_p, q, qd, tail)
    Yb = sig.band_limit(r.gyro[:, c])
    Xb = sig.band_limit(X)
    if measured:
        rate = _link_rate(sig, X, Xb, r.gyro[:, c], Yb, 0 if omega_p is None else 9)
        side = sig.band_limit(sig.derivative(_band_side(sig, rate))[:, None])
        Xb = np.c_[Xb, side]
    coef, cov = per_axis(Xb, Yb, sig.lags)
    var = variances(cov)
    ia = 0 if omega_p is None else 9
    a = coef[ia]
    gain = float(np.linalg.norm(a))
    u = a / gain if gain > 0 else np.array([0.0, 0.0, 1.0])
    P = np.eye(3) - np.outer(u, u)
    var_perp = float(np.sum(np.diag(P) * var[ia])) / max(gain, 1e-12) ** 2
    H = span = None
    if omega_p is not None:
        # a gyro's bias is a constant the intercepts take: only the motion about it spans directions
        span = (
            span_projector(Xb[:, :3] - Xb[:, :3].mean(axis=0), 1e-2)
            if measured
            else span_projector(Xb[:, :3])
        )
        H = (coef[0:3] + coef[3:6]).T @ span
    backlash = backlash_std = math.nan
    if measured:  # ω = u (q̇_enc - (b/2) ṡ): the side's coefficient is -(b/2) a
        backlash = -2.0 * float(coef[-1] @ u) / max(gain, 1e-12)
        backlash_std = 2.0 * math.sqrt(float(np.sum(u * u * var[-1]))) / max(gain, 1e-12)
    return AxisFit(
        axis=u,
        gain=gain,
        std_deg=math.degrees(math.sqrt(var_perp)),
        H=H,
        span=span,
        coef=coef,
        cov=cov,
        backlash_deg=math.degrees(backlash),
        backlash_std_deg=math.degrees(backlash_std),
    )


def _link_rate(
    sig: Signals, X: np.ndarray, Xb: np.ndarray, gyro: np.ndarray, Yb: np.ndarray, ia: int
) -> np.ndarray:
    """The joint's rate as the gyros see the link turn, in the common band: the gyro model fitted
    (on the band-limited ``Xb``, ``Yb``) without the encoder's dead-band steps, everything but its ``q̇``
    column taken out of the child's ``gyro`` and the rest read along the axis. Unlike the encoder's
    velocity it turns where the link turns."""
    coef, _ = per_axis(Xb, Yb, sig.lags)
    a = coef[ia]
    gain = max(float(np.linalg.norm(a)), 1e-12)
    others = [k for k in range(X.shape[1]) if k != ia]
    rest = gyro - X[:, others] @ coef[others]
    return lowpass(rest @ (a / gain**2), sig.rate, sig.band)


def _band_side(sig: Signals, rate: np.ndarray) -> np.ndarray:
    """The side of its dead band a joint's encoder is on, +1 or -1 per sample.

    Through a dead band of width ``b`` the motor, and its encoder, lead the link by ``b/2`` in the
    direction of motion, and where the link rests they stay on the side they last moved to: the encoder
    reads ``q_link + (b/2) s`` and steps by ``b`` at each reversal, which the gyros never see. ``s`` is
    the sign of the link's ``rate`` (:func:`_link_rate`) where that exceeds 5 % of its RMS, and the
    last such sign where it does not (+1 before the first motion); each change of side is put at the
    rate's last zero crossing before it, where the link turned.
    """
    v = rate
    moving = np.abs(v) > 0.05 * math.sqrt(float(np.mean(v * v)))
    idx = np.where(moving, np.arange(len(v)), -1)
    np.maximum.accumulate(idx, out=idx)
    side = np.where(idx >= 0, np.sign(v)[np.maximum(idx, 0)], 1.0)
    changes = np.flatnonzero(np.diff(side)) + 1
    crossings = np.flatnonzero(np.diff(np.sign(v))) + 1
    before = np.searchsorted(crossings, changes, side="right") - 1
    out = side.copy()
    for k, i in zip(changes, before, strict=True):
        if i >= 0:
            out[crossings[i] : k] = side[k]
    return out


#: Draws of the gyro fit's coefficients behind :func:`_in_parent_std` (the RMS of 400 draws is within
#: about 4 % of the distribution's); fixed seed: the same data give the same std.
_DRAWS = 400


def _in_parent_std(coef: np.ndarray, cov: np.ndarray, span: np.ndarray, ref: np.ndarray) -> float:
    """The std (deg, RMS angle) of the gyro's axis in the parent's frame, ``R0ᵀ u``.

    Both factors come from the one gyro fit (``u`` from the ``q̇`` column, ``R0`` the rotation nearest
    ``A + B`` on the span the parent turned about), so its error is the fit's covariance carried through
    that nonlinear map. With a parent that turned mostly about one axis and a little about another, the
    rotation about the weak direction is barely fixed, and the axis in the parent's frame moves with it
    by far more than ``u``'s own std: the coefficients are drawn from their Gaussian (each output axis's
    fit on its own, as fitted) and the map applied to each draw; ``ref`` is the map of the fit itself.
    """
    rng = np.random.default_rng(0)
    p = coef.shape[0]
    draws = np.empty((_DRAWS, p, 3))
    for i in range(3):
        lam, V = np.linalg.eigh(cov[i])  # positive semi-definite: a design the data leave rank-deficient
        L = V * np.sqrt(np.clip(lam, 0.0, None))
        draws[:, :, i] = coef[:, i] + rng.standard_normal((_DRAWS, p)) @ L.T
    a = draws[:, 9]
    u = a / np.linalg.norm(a, axis=1, keepdims=True)
    H = np.swapaxes(draws[:, 0:3] + draws[:, 3:6], 1, 2) @ span
    v = np.einsum("kji,kj->ki", project_rotation(H), u)
    cos = np.clip(v @ ref, -1.0, 1.0)
    return math.degrees(math.sqrt(float(np.mean(np.arccos(cos) ** 2))))


@dataclass(frozen=True)
class GyroReading:
    """A child IMU's joint as its gyro alone reports it (:func:`gyro_reading`)."""

    fit: AxisFit
    #: the axis in the parent gyro's frame, and its std (a parent that turned about two axes or more)
    in_parent: np.ndarray | None = None
    in_parent_std_deg: float = math.inf
    parent_axis: np.ndarray | None = None  # the parent's one axis as this gyro sees it (sign arbitrary)
    parent_rank: int = 0  # how many independent axes the parent link turned about (0: a root joint)


def gyro_reading(sig: Signals, j: int, c: int, p: int | None) -> GyroReading:
    """The joint axis and the rotation from the parent as the two gyros alone fix them.

    The child's gyro is regressed on the parent's gyro ``p`` as it reads (None: a root joint), not on
    the parent's motion rebuilt from the encoders down the tree: that keeps every quantity of the
    reading a function of these two gyros' sensitivity matrices, which a recording of the same IMUs
    repeats, and of noise. Through a rebuilt chain every ancestor's answer would enter, with errors
    that move with the motion (docs/kinematics.md, "Findings").
    """
    if p is None:
        return GyroReading(axis_fit(sig, j, c, None, measured=True))
    fit = axis_fit(sig, j, c, sig.rec.gyro[:, p], measured=True)
    rank, p_axis = span_axes(fit.span)  # type: ignore[arg-type]
    if rank >= 2:
        in_parent = project_rotation(fit.H).T @ fit.axis
        std = _in_parent_std(fit.coef, fit.cov, fit.span, in_parent)  # type: ignore[arg-type]
        return GyroReading(fit, in_parent=in_parent, in_parent_std_deg=std, parent_rank=rank)
    seen = fit.H @ p_axis  # type: ignore[operator]
    return GyroReading(fit, parent_axis=seen / max(float(np.linalg.norm(seen)), 1e-12), parent_rank=rank)
