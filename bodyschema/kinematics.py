"""Beyond topology: each joint's axis and each IMU's lever arm, from gyros, accelerometers and encoders.

The topology (:mod:`bodyschema.estimate`) says which joint moves each IMU's link and which joint hangs
under which. Given that tree, the geometry follows from linear least squares on the same band-limited
signals the fast estimator compares (:mod:`bodyschema.timing`: encoders moved onto IMU time by the
estimated lag, every signal and every regressor through one low-pass band, so that linear models stay
exact sample by sample).

**Axis.** A revolute joint turns its child link about the unit axis ``u`` (child IMU frame) by ``q``.
With ``ω_p`` the parent link's angular velocity (parent IMU frame) and ``R0`` the rotation from the
parent IMU frame into the child IMU frame at ``q = 0``, the child gyro reads::

    ω_c = Rot(u, -q) R0 ω_p + u q̇ + b
        = A ω_p + B ω_p cos q + C ω_p sin q + a q̇ + b,
    A = u uᵀ R0,  B = (I - u uᵀ) R0,  C = -[u]× R0,  a = u

(``b`` the gyro bias). The model is linear in (A, B, C, a, b): one least-squares fit per gyro axis.
``u = a / |a|`` (``|a|`` is the gyro's gain along the axis), ``A + B = R0`` on the directions the
parent link turned about, and ``R0ᵀ u`` is the axis in the parent IMU's frame. A root joint on the
fixed base has ``ω_p = 0``: ``ω_c = a q̇ + b``. The regressor ``ω_p`` is the parent's angular
velocity rebuilt from the encoders (below), so neither gyro's bias nor gain enters it.

**Lever arm.** The child IMU sits at ``r`` from the foot ``o`` of its perpendicular on the axis. With
the link's angular velocity ``ω`` and acceleration ``α`` (child IMU frame), its specific force is::

    f_c = f_o + [α]× r + [ω]×[ω]× r

Moving ``o`` along the axis changes nothing but ``r``'s component along it, so that component is
unobservable from one joint and ``r`` is solved in the plane perpendicular to ``u`` (the *lever
arm*). ``f_o`` is what a point on the axis feels:

* root joint, fixed base: gravity seen from the turning frame plus the accelerometer bias,
  ``f_o = G0 + G1 cos q + G2 sin q`` (three unknown constant vectors; they absorb the accelerometer's
  gains too);
* otherwise, from the parent IMU ``p`` with ``d`` the position of ``o`` in its frame (the joint
  origin): ``f_o = R(q) (f_p + [α_p]× d + [ω_p]×[ω_p]× d)`` with the rotation ``R(q) = Rot(u, -q) R0``,
  plus first-order corrections for the two accelerometers' gains and intercepts ``b0 + b1 cos q + b2
  sin q`` for their biases seen through the joint (:func:`_lever_child`).

``ω`` and ``α`` are not read from the gyro: it is biased by up to tens of °/s and its gain is off by a
few %, and a lever arm scales with it. They are rebuilt down the tree from the encoders with the
fitted axes and rotations, ``ω_c = Rot(u, -q) R0 ω_p + u q̇`` (``ω = u q̇`` under a root joint), and
``α`` is their band-limited derivative. The tangential terms ``[α]× r`` (and ``[α_p]× d``) get lever
arms of their own and ``r`` (and ``d``) are read from the centripetal terms, which need ``ω`` alone: a
gain error of the differentiated ``α`` (a filter mismatch; or a simulator whose accelerometer follows
its forward-dynamics acceleration while its implicit integrator moves the joints slightly
differently) would otherwise scale the lever arm.

**Uncertainty.** The residuals of band-limited signals are autocorrelated, so the covariance of every
fit is the heteroscedasticity-and-autocorrelation-consistent (Newey-West) sandwich, with a Bartlett
window as long as the band's correlation time. ``axis_std_deg`` is the RMS angular error of ``u``,
``lever_arm_std_m`` the RMS error of ``r``. Both count noise only: a gyro's cross-axis sensitivity
(up to 2 % on an MPU-6050) tilts the axis it reports by up to about a degree, and no single IMU can tell
that from its mounting. An answer is ``converged`` when the joint moved enough, the axis gain is
plausible and both stds are within :class:`KinematicsOptions` bounds.

Example
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> from bodyschema.topology import Topology
>>> t = np.arange(3000) / 100.0
>>> q = np.c_[0.8 * np.sin(1.3 * t) + 0.4 * np.sin(3.1 * t)]
>>> qd = np.gradient(q[:, 0], t)
>>> u = np.array([0.0, 0.6, 0.8])
>>> gyro = (u * qd[:, None])[:, None, :]
>>> rec = Recording(t=t, joint_names=["j1"], q=q, imu_names=["imu1"], gyro=gyro,
...                 acc=np.zeros((3000, 1, 3)))
>>> kin = estimate_kinematics(rec, Topology({"j1": None}, {"imu1": "j1"}))
>>> np.round(kin.imus["imu1"].axis, 3).tolist(), bool(kin.imus["imu1"].axis_std_deg < 0.1)
([0.0, 0.6, 0.8], True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.recording import Recording
from bodyschema.timing import DLPF_GYRO, choose_band, edge_margin, lowpass, median_rate
from bodyschema.topology import Topology

__all__ = [
    "ImuKinematics",
    "JointKinematics",
    "Kinematics",
    "KinematicsOptions",
    "SameLink",
    "estimate_kinematics",
    "project_rotation",
    "rotation_about",
]

#: What one joint's data cannot tell, stated with every answer.
UNOBSERVABLE: tuple[str, ...] = (
    "the IMU's position along its joint's axis (only the perpendicular lever arm is observable)",
    "for a root joint on a fixed base: the axis's direction about gravity (yaw) and its position",
    "a gyro's cross-axis misalignment, indistinguishable from its mounting rotation",
)


@dataclass(frozen=True)
class KinematicsOptions:
    """Settings of :func:`estimate_kinematics`.

    ``band_hz`` is the common band (None: :func:`bodyschema.timing.choose_band`, 10 Hz at most).
    ``min_qd_rms`` (rad/s, in band) is the joint motion below which nothing is claimed. An answer is
    converged when ``axis_std_deg`` ≤ ``max_axis_std_deg``, ``lever_arm_std_m`` ≤ ``max_lever_std_m`` and
    the gyro's gain along the axis lies within ``gain_range``.
    """

    band_hz: float | None = None
    min_qd_rms: float = 0.05
    max_axis_std_deg: float = 1.0
    max_lever_std_m: float = 0.005
    gain_range: tuple[float, float] = (0.8, 1.25)
    imu_bandwidth_hz: float | None = DLPF_GYRO[3][0]


@dataclass(frozen=True)
class ImuKinematics:
    """One IMU's joint, that joint's axis and the IMU's lever arm, in the IMU's own frame.

    ``axis`` is the unit axis (sign: positive ``q``), ``lever_arm`` the perpendicular vector from the axis
    to the IMU origin (m). ``rotation_from_parent`` (3×3) maps vectors of ``parent_imu``'s frame into
    this IMU's frame at ``q = 0``; ``joint_origin_in_parent`` is the foot of the lever arm on the axis
    in ``parent_imu``'s frame (m); ``up_at_zero`` (root joints) the specific force at ``q = 0``, which
    gives the link's tilt. ``reason`` says why an answer is not converged.
    """

    imu: str
    joint: str | None
    parent_imu: str | None = None
    axis: np.ndarray | None = None
    lever_arm: np.ndarray | None = None
    axis_std_deg: float = math.inf
    lever_arm_std_m: float = math.inf
    gain: float = math.nan
    rotation_from_parent: np.ndarray | None = None
    axis_in_parent: np.ndarray | None = None
    joint_origin_in_parent: np.ndarray | None = None
    up_at_zero: np.ndarray | None = None
    converged: bool = False
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        def vec(x: np.ndarray | None, nd: int = 6) -> list[float] | None:
            return None if x is None else [round(float(v), nd) for v in np.ravel(x)]

        out: dict[str, Any] = {
            "joint": self.joint,
            "parent_imu": self.parent_imu,
            "axis": vec(self.axis),
            "lever_arm": vec(self.lever_arm),
            "axis_std_deg": _finite(self.axis_std_deg),
            "lever_arm_std_m": _finite(self.lever_arm_std_m),
            "gain": _finite(self.gain),
            "converged": self.converged,
        }
        if self.rotation_from_parent is not None:
            out["rotation_from_parent"] = [vec(row) for row in self.rotation_from_parent]
        if self.joint_origin_in_parent is not None:
            out["joint_origin_in_parent"] = vec(self.joint_origin_in_parent)
        if self.reason:
            out["reason"] = self.reason
        return out


@dataclass(frozen=True)
class JointKinematics:
    """A joint's IMUs, its axis in the frame of each IMU on its parent link (``{imu: unit axis}``; none
    under a root joint, whose base IMU cannot see it turn) and the range of ``q`` the data visited.

    ``ref_imu`` is the IMU whose frame stands for the link's: the parent IMU of the joints below and
    the one the other IMUs on the link are related to (:class:`SameLink`).
    """

    joint: str
    parent: str | None
    imus: tuple[str, ...]
    ref_imu: str | None = None
    axis_in_parent: dict[str, np.ndarray] = field(default_factory=dict)
    q_range: tuple[float, float] = (0.0, 0.0)
    converged: bool = False

    def to_json(self) -> dict[str, Any]:
        return {
            "parent": self.parent,
            "imus": list(self.imus),
            "reference_imu": self.ref_imu,
            "q_range": [round(x, 6) for x in self.q_range],
            "axis_in_parent": {k: [round(float(x), 6) for x in v] for k, v in self.axis_in_parent.items()},
            "converged": self.converged,
        }


@dataclass(frozen=True)
class SameLink:
    """Two IMUs on one link: ``rotation`` maps vectors of ``b``'s frame into ``a``'s frame."""

    a: str
    b: str
    rotation: np.ndarray
    std_deg: float

    def to_json(self) -> dict[str, Any]:
        return {
            "imus": [self.a, self.b],
            "rotation": [[round(float(x), 6) for x in row] for row in self.rotation],
            "std_deg": _finite(self.std_deg),
        }


@dataclass(frozen=True)
class Kinematics:
    """Everything :func:`estimate_kinematics` found; :meth:`to_json` is the CLI's JSON."""

    imus: dict[str, ImuKinematics]
    joints: dict[str, JointKinematics]
    same_link: tuple[SameLink, ...]
    band_hz: float
    lag_ms: float
    samples: int
    topology: Topology

    def to_json(self) -> dict[str, Any]:
        return {
            "imus": {k: v.to_json() for k, v in self.imus.items()},
            "joints": {k: v.to_json() for k, v in self.joints.items()},
            "same_link": [s.to_json() for s in self.same_link],
            "band_hz": round(self.band_hz, 3),
            "lag_ms": round(self.lag_ms, 3),
            "samples": self.samples,
            "unobservable": list(UNOBSERVABLE),
        }


def _finite(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None


# ------------------------------------------------------------------------------------ rotations
def skew(v: np.ndarray) -> np.ndarray:
    """``[v]×`` for (..., 3) vectors: (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def rotation_about(u: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations by ``angle`` (T,) about the unit axis ``u``, (T, 3, 3).

    >>> np.round(rotation_about(np.array([0.0, 0, 1]), np.array([np.pi / 2]))[0] @ [1, 0, 0], 6).tolist()
    [0.0, 1.0, 0.0]
    """
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    uu = np.outer(u, u)
    return c * np.eye(3) + (1.0 - c) * uu + s * skew(u)


def project_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest ``M`` (Frobenius), by SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _perp_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2): two orthonormal vectors perpendicular to ``u``."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], axis=1)


# ---------------------------------------------------------------------------------- least squares
@dataclass(frozen=True)
class _Fit:
    coef: np.ndarray
    cov: np.ndarray
    resid: np.ndarray


def _ls(X: np.ndarray, Y: np.ndarray, lags: int) -> _Fit:
    """Stacked least squares ``Y[t] ≈ X[t] @ β`` with X (T, m, p), Y (T, m) and its Newey-West covariance.

    Columns are scaled for conditioning; a rank-deficient design (a nuisance block that the data do
    not excite) gets the minimum-norm solution, which leaves the identifiable parameters unchanged.
    """
    T, m, p = X.shape
    scale = np.sqrt(np.mean(X**2, axis=(0, 1)))
    scale[scale < 1e-12] = 1.0
    Xs = X / scale
    G = np.einsum("tmi,tmj->ij", Xs, Xs)
    Gi = np.linalg.pinv(G, rcond=1e-10, hermitian=True)
    beta = Gi @ np.einsum("tmi,tm->i", Xs, Y)
    e = Y - Xs @ beta
    g = np.einsum("tmi,tm->ti", Xs, e)
    S = g.T @ g
    for k in range(1, lags + 1):
        w = 1.0 - k / (lags + 1)
        Gk = g[k:].T @ g[:-k]
        S += w * (Gk + Gk.T)
    dof = max(T * m - p, 1)
    cov = Gi @ S @ Gi * (T * m / dof)
    return _Fit(coef=beta / scale, cov=cov / np.outer(scale, scale), resid=e)


def _per_axis(X: np.ndarray, Y: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Y (T, 3) ≈ X (T, p) @ coef (p, 3), one fit per column; returns coef and each column's variances."""
    coef = np.empty((X.shape[1], Y.shape[1]))
    var = np.empty_like(coef)
    for i in range(Y.shape[1]):
        f = _ls(X[:, None, :], Y[:, i : i + 1], lags)
        coef[:, i] = f.coef
        var[:, i] = np.diag(f.cov)
    return coef, var


# ----------------------------------------------------------------------------------------- signals
@dataclass(frozen=True)
class _Signals:
    """The aligned recording and what every fit needs: rate, band, decimation and the band filter."""

    rec: Recording
    rate: float
    band: float
    step: int
    trim: int
    lags: int
    fa: float

    def band_limit(self, x: np.ndarray) -> np.ndarray:
        """``x`` (T, ...) through the common band, decimated and trimmed at the edges."""
        flat = x.reshape(x.shape[0], -1)
        y = lowpass(flat, self.rate, self.band, step=self.step)
        y = y[self.trim : y.shape[0] - self.trim]
        return y.reshape((y.shape[0], *x.shape[1:]))

    def derivative(self, x: np.ndarray) -> np.ndarray:
        """Band-limited time derivative at the aligned rate (wide band: the common band comes later)."""
        return lowpass(x.reshape(x.shape[0], -1), self.rate, self.fa, derivative=True).reshape(x.shape)


def _signals(rec: Recording, topo: Topology, opts: KinematicsOptions) -> _Signals:
    from bodyschema.health import one_clock

    al = one_clock(rec, topo)
    if al.q is None or al.n_samples < 64:
        raise ValueError("too little data for kinematics (needs encoder positions and 64 samples)")
    rate = median_rate(al.t)
    if opts.band_hz is not None:
        band = float(opts.band_hz)
    elif rec.t_q is not None:
        band = choose_band(median_rate(rec.t), median_rate(rec.t_q), opts.imu_bandwidth_hz)
    else:
        band = choose_band(rate, rate, None)
    step = max(1, int(rate // (2.5 * band)))
    trim = math.ceil(edge_margin(band) * rate / step)
    lags = max(1, math.ceil(2.0 * rate / step / band))
    fa = min(0.4 * rate, 4.0 * band)
    if al.n_samples // step <= 2 * trim + 16:
        raise ValueError("too little data for kinematics in the chosen band")
    return _Signals(rec=al, rate=rate, band=band, step=step, trim=trim, lags=lags, fa=fa)


# ------------------------------------------------------------------------------------------ axis
@dataclass(frozen=True)
class _AxisFit:
    axis: np.ndarray
    gain: float
    std_deg: float
    H: np.ndarray | None  # A + B: R0 (times the gyro's gain) on the span the parent's motion excites
    span: np.ndarray | None  # projector onto that span


def _span(x: np.ndarray, rel: float = 1e-3) -> np.ndarray:
    """Projector onto the directions a (T, 3) signal excites (second-moment eigenvalues above ``rel``)."""
    lam, V = np.linalg.eigh(x.T @ x)
    V = V[:, lam > rel * max(float(lam[-1]), 1e-300)]
    return V @ V.T


def _axis_fit(sig: _Signals, j: int, c: int, omega_p: np.ndarray | None) -> _AxisFit:
    """Fit the exact gyro model of the module docstring for child IMU ``c`` of joint ``j``.

    ``omega_p`` is the parent link's angular velocity rebuilt from the encoders (no gyro bias or gain
    in it); None under a root joint on the fixed base.
    """
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    qd = r.qd[:, j]  # type: ignore[index]
    if omega_p is None:
        X = np.c_[qd, np.ones_like(qd)]
    else:
        X = np.c_[omega_p, omega_p * np.cos(q)[:, None], omega_p * np.sin(q)[:, None], qd, np.ones_like(qd)]
    Xb = sig.band_limit(X)
    Yb = sig.band_limit(r.gyro[:, c])
    coef, var = _per_axis(Xb, Yb, sig.lags)
    ia = 0 if omega_p is None else 9
    a = coef[ia]
    gain = float(np.linalg.norm(a))
    u = a / gain if gain > 0 else np.array([0.0, 0.0, 1.0])
    P = np.eye(3) - np.outer(u, u)
    var_perp = float(np.sum(np.diag(P) * var[ia])) / max(gain, 1e-12) ** 2
    H = span = None
    if omega_p is not None:
        span = _span(Xb[:, :3])
        H = (coef[0:3] + coef[3:6]).T @ span
    return _AxisFit(axis=u, gain=gain, std_deg=math.degrees(math.sqrt(var_perp)), H=H, span=span)


# ------------------------------------------------------------------------------------- lever arm
@dataclass(frozen=True)
class _LeverFit:
    r: np.ndarray
    std_m: float
    d: np.ndarray | None = None
    M0: np.ndarray | None = None  # R0 refined by the accelerometers
    up: np.ndarray | None = None  # root joint: the specific force at q = 0 (gravity's tilt, bias in it)
    r_tangential: np.ndarray | None = None  # the lever arm the tangential term alone implies


def _kmats(sig: _Signals, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangential ``[α]×`` and centripetal ``[ω]×[ω]×`` parts of ``K`` (each (T, 3, 3)) of a rebuilt
    angular velocity; they are fitted with separate lever arms (module docstring)."""
    w = skew(omega)
    return skew(sig.derivative(omega)), w @ w


def _stack(rows: np.ndarray, shared: list[np.ndarray]) -> np.ndarray:
    """Design (n, 3, p): ``rows`` (n, w) repeated as a block per accelerometer axis, then shared columns."""
    n, w = rows.shape
    X = np.zeros((n, 3, 3 * w + sum(s.shape[2] for s in shared)))
    for i in range(3):
        X[:, i, i * w : (i + 1) * w] = rows
    col = 3 * w
    for s in shared:
        X[:, :, col : col + s.shape[2]] = s
        col += s.shape[2]
    return X


def _lever_root(sig: _Signals, j: int, c: int, u: np.ndarray, omega_c: np.ndarray) -> _LeverFit:
    """Root joint, fixed base: ``f_c = G0 + G1 cos q + G2 sin q + [α]× r_t + [ω]×[ω]× r`` with ``r ⊥ u``."""
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    U = _perp_basis(u)
    Ka, Kw = _kmats(sig, omega_c)
    rows = sig.band_limit(np.c_[np.ones_like(q), np.cos(q), np.sin(q)])
    X = _stack(rows, [sig.band_limit(Ka @ U), sig.band_limit(Kw @ U)])
    f = _ls(X, sig.band_limit(r.acc[:, c]), sig.lags)
    cov_r = U @ f.cov[-2:, -2:] @ U.T
    G = f.coef[:9].reshape(3, 3)
    return _LeverFit(
        r=U @ f.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        up=G[:, 0] + G[:, 1],
        r_tangential=U @ f.coef[-4:-2],
    )


def _lever_child(
    sig: _Signals,
    j: int,
    c: int,
    p: int,
    u: np.ndarray,
    omega_c: np.ndarray,
    omega_p: np.ndarray,
    R0: np.ndarray,
    span_rank: int,
    parent_axis: np.ndarray,
) -> _LeverFit:
    """Child of a link with an IMU: the accelerometer model with ``R(q) = Rot(u, -q) R0`` a rotation.

    ``f_c = R(q) (f_p + δ_p ⊙ f_p + K_p d) + δ_c ⊙ R(q) f_p + b(q) + K_c r``: the two accelerometers'
    gains to first order (``δ``, a few %), intercepts ``b(q) = b0 + b1 cos q + b2 sin q`` for the biases
    seen through the turning joint. Given ``R0`` it is linear in (δ_c, b, δ_p, d, r). The gyro fixes
    ``R0`` on the directions the parent link turned about; when that is one axis (a root parent),
    the remaining turn about its image is the one that minimises the accelerometer residual (variable
    projection over one angle: a coarse grid, then a bounded search), which gravity decides unless
    the parent's axis is vertical. A general matrix in place of ``R(q)`` would keep the model linear
    but can absorb the ``K_p d`` term through the parent's own dynamics in ``f_p``.
    """
    from scipy.optimize import minimize_scalar

    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    mods = (np.ones_like(q), np.cos(q), np.sin(q))
    U = _perp_basis(u)
    Kca, Kcw = _kmats(sig, omega_c)
    KcU = np.concatenate([sig.band_limit(Kca @ U), sig.band_limit(Kcw @ U)], axis=2)
    fp = r.acc[:, p]
    Fm = [sig.band_limit(m[:, None] * fp) for m in mods]
    Kp = np.concatenate(_kmats(sig, omega_p), axis=2)  # (T, 3, 6): d_t then d
    Km = [sig.band_limit(m[:, None, None] * Kp) for m in mods]
    ones = sig.band_limit(np.stack(mods, axis=1))
    Y = sig.band_limit(r.acc[:, c])
    uu, ux = np.outer(u, u), skew(u)

    def design(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = (uu @ R, (np.eye(3) - uu) @ R, -ux @ R)
        RF = sum(np.einsum("ij,tj->ti", Pm, F) for Pm, F in zip(P, Fm, strict=True))
        Dp = sum(Pm[None, :, :] * F[:, None, :] for Pm, F in zip(P, Fm, strict=True))
        RK = sum(np.einsum("ij,tjk->tik", Pm, K) for Pm, K in zip(P, Km, strict=True))
        n = RF.shape[0]
        X = np.zeros((n, 3, 12 + 3 + 6 + 4))
        for i in range(3):
            X[:, i, 4 * i] = RF[:, i]
            X[:, i, 4 * i + 1 : 4 * i + 4] = ones
        X[:, :, 12:15] = Dp
        X[:, :, 15:21] = RK
        X[:, :, 21:25] = KcU
        return X, Y - RF

    def fit(R: np.ndarray) -> tuple[float, float]:
        """Residual sum of squares, and the largest gain correction it needed."""
        X, Yr = design(R)
        f = _ls(X, Yr, 0)
        gains = np.r_[f.coef[[0, 4, 8]], f.coef[12:15]]
        return float(np.sum(f.resid * f.resid)), float(np.max(np.abs(gains)))

    R = R0
    if span_rank == 1:
        # The gyro fixed R0 on the parent's axis only: the turn about its image w is the accelerometers'.
        # A half turn fits as well with gains of -1 (the parent's specific force flipped across its
        # axis), so the two wells half a turn apart are both refined and the one with small gains kept.
        w = R0 @ parent_axis
        turn = lambda phi: rotation_about(w, np.array([phi]))[0] @ R0  # noqa: E731
        grid = np.linspace(-np.pi, np.pi, 36, endpoint=False)
        h = grid[1] - grid[0]
        rss = np.array([fit(turn(g))[0] for g in grid])
        half = len(grid) // 2
        best = int(np.argmin(rss))
        other = (best + half - 2) + int(
            np.argmin([rss[(best + half + k) % len(grid)] for k in (-2, -1, 0, 1, 2)])
        )
        found = []
        for start in (grid[best], grid[other % len(grid)]):
            phi = minimize_scalar(
                lambda x: fit(turn(x))[0], bounds=(start - h, start + h), method="bounded"
            ).x
            found.append((fit(turn(float(phi)))[1], float(phi)))
        R = turn(min(found)[1])
    X, Yr = design(R)
    f = _ls(X, Yr, sig.lags)
    cov_r = U @ f.cov[-2:, -2:] @ U.T
    return _LeverFit(
        r=U @ f.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        d=f.coef[18:21],
        M0=R,
        r_tangential=U @ f.coef[-4:-2],
    )


# ------------------------------------------------------------------------------------ same link
def _same_link(sig: _Signals, a: int, b: int, names: tuple[str, ...]) -> SameLink | None:
    """``gyro_a = M gyro_b + bias``; the rotation is ``M`` projected, its std from M's off-diagonals."""
    gb = sig.band_limit(sig.rec.gyro[:, b])
    ga = sig.band_limit(sig.rec.gyro[:, a])
    if float(np.sqrt(np.mean((gb - gb.mean(axis=0)) ** 2))) < 1e-3:
        return None
    X = np.c_[gb, np.ones(gb.shape[0])]
    coef, var = _per_axis(X, ga, sig.lags)
    M = coef[:3].T
    v = var[:3].T
    off = float(np.sum(v) - np.sum(np.diag(v)))
    return SameLink(
        a=names[a], b=names[b], rotation=project_rotation(M), std_deg=math.degrees(math.sqrt(off / 4.0))
    )


# ------------------------------------------------------------------------------------------- main
def _order(topo: Topology) -> list[str]:
    """Joints parents first."""
    out: list[str] = []
    seen: set[str | None] = {None}
    todo = list(topo.joint_parent)
    while todo:
        rest = [j for j in todo if topo.joint_parent[j] not in seen]
        for j in todo:
            if topo.joint_parent[j] in seen:
                out.append(j)
                seen.add(j)
        if len(rest) == len(todo):
            out.extend(rest)
            break
        todo = rest
    return out


@dataclass
class _Walk:
    """What the walk down the tree has found so far (joints are visited parents first)."""

    sig: _Signals
    opts: KinematicsOptions
    topo: Topology
    on_joint: dict[str | None, list[str]]
    qd_rms: np.ndarray
    imus: dict[str, ImuKinematics] = field(default_factory=dict)
    omega: dict[str, np.ndarray] = field(default_factory=dict)  # each fitted IMU's link, own frame
    ref: dict[str, str] = field(default_factory=dict)  # joint -> the IMU whose frame is its link's
    same: dict[str, SameLink] = field(default_factory=dict)  # other IMUs on a link against its ref

    @property
    def kidx(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.sig.rec.imu_names)}


def _with_timing(rec: Recording, topology: Topology | None) -> Topology:
    """The given tree (or the fast estimator's) with the IMU-to-encoder timing a multi-rate ``rec`` needs."""
    if topology is not None and (rec.t_q is None or topology.timing):
        return topology
    from dataclasses import replace

    from bodyschema.estimate import estimate_topology

    learned = estimate_topology(rec, method="fast")
    return learned if topology is None else replace(topology, timing=dict(learned.timing))


def _fit_link(w: _Walk, jn: str, j: int) -> None:
    """Fit every IMU on joint ``jn``'s link, pick the link's reference IMU, relate the others to it."""
    pj = w.topo.joint_parent.get(jn)
    parent = None if pj is None else w.ref.get(pj)
    kids, kidx = w.on_joint.get(jn, []), w.kidx
    for imu in kids:
        if w.qd_rms[j] < w.opts.min_qd_rms:
            why = f"joint {jn} hardly moved ({w.qd_rms[j]:.3g} rad/s RMS)"
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=why)
        elif pj is not None and parent is None:
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=f"no fitted IMU on the link of {pj}")
        else:
            w.imus[imu], w.omega[imu] = _one_imu(w.sig, w.opts, j, jn, kidx[imu], imu, parent, kidx, w.omega)
    fitted = [k for k in kids if w.imus[k].axis is not None]
    if not fitted:
        return
    w.ref[jn] = next((k for k in fitted if w.imus[k].converged), fitted[0])
    for b in kids:
        if b != w.ref[jn]:
            sl = _same_link(w.sig, kidx[w.ref[jn]], kidx[b], w.sig.rec.imu_names)
            if sl is not None:
                w.same[b] = sl


def _joint_entry(w: _Walk, jn: str, j: int) -> JointKinematics:
    """Joint ``jn``'s axis in every IMU frame of its parent link (through the same-link rotations)."""
    pj = w.topo.joint_parent.get(jn)
    parent = None if pj is None else w.ref.get(pj)
    in_parent: dict[str, np.ndarray] = {}
    axis_p = w.imus[w.ref[jn]].axis_in_parent if jn in w.ref else None
    if parent is not None and axis_p is not None:
        in_parent[parent] = axis_p
        for b in w.on_joint.get(pj, []):
            if b in w.same and w.same[b].a == parent:
                in_parent[b] = w.same[b].rotation.T @ axis_p
    q = w.sig.rec.q[:, j]  # type: ignore[index]
    kids = w.on_joint.get(jn, [])
    return JointKinematics(
        joint=jn,
        parent=pj,
        imus=tuple(kids),
        ref_imu=w.ref.get(jn),
        axis_in_parent=in_parent,
        q_range=(float(np.min(q)), float(np.max(q))),
        converged=any(w.imus[k].converged for k in kids),
    )


def estimate_kinematics(
    rec: Recording, topology: Topology | None = None, options: KinematicsOptions | None = None
) -> Kinematics:
    """Joint axes, IMU lever arms and same-link rotations of ``rec`` (model in the module docstring).

    ``topology`` is the learned or given tree; without one the fast estimator learns it. A multi-rate
    recording is aligned with the lag in ``topology.timing`` (the fast estimator's; a topology without
    timing gets it from a fast fit of ``rec``).
    """
    opts = options or KinematicsOptions()
    topo = _with_timing(rec, topology)
    sig = _signals(rec, topo, opts)
    al = sig.rec
    on_joint: dict[str | None, list[str]] = {}
    for imu in al.imu_names:
        if imu in topo.imu_joint:
            on_joint.setdefault(topo.imu_joint[imu], []).append(imu)
    qd_rms = np.sqrt(np.mean(sig.band_limit(al.qd) ** 2, axis=0))  # type: ignore[arg-type]
    w = _Walk(sig=sig, opts=opts, topo=topo, on_joint=on_joint, qd_rms=qd_rms)
    for imu in on_joint.get(None, []):
        w.imus[imu] = ImuKinematics(imu=imu, joint=None, reason="on the base: no joint moves it")
    jidx = {n: i for i, n in enumerate(al.joint_names)}
    joints: dict[str, JointKinematics] = {}
    for jn in _order(topo):
        if jn in jidx:
            _fit_link(w, jn, jidx[jn])
            joints[jn] = _joint_entry(w, jn, jidx[jn])
    lag = float(topo.timing.get("lag_ms", 0.0)) if rec.t_q is not None else 0.0
    return Kinematics(
        imus={k: w.imus[k] for k in al.imu_names if k in w.imus},
        joints=joints,
        same_link=tuple(w.same.values()),
        band_hz=sig.band,
        lag_ms=lag,
        samples=al.n_samples,
        topology=topo,
    )


def _one_imu(
    sig: _Signals,
    opts: KinematicsOptions,
    j: int,
    jn: str,
    c: int,
    imu: str,
    parent: str | None,
    kidx: dict[str, int],
    omega: dict[str, np.ndarray],
) -> tuple[ImuKinematics, np.ndarray]:
    """Axis, lever arm and the rebuilt angular velocity of one IMU's link; ``parent``: the reference
    IMU of the parent link (None: a root joint on the fixed base)."""
    al = sig.rec
    q, qd = al.q[:, j], al.qd[:, j]  # type: ignore[index]
    R0 = d = None
    best_p = parent
    if parent is None:
        fit = _axis_fit(sig, j, c, None)
        om = fit.axis * qd[:, None]
        lever = _lever_root(sig, j, c, fit.axis, om)
    else:
        fit = _axis_fit(sig, j, c, omega[parent])
        u = fit.axis
        # R0 on the span of the parent's motion (all that ω_c needs), from the gyro
        Rg = project_rotation(fit.H)  # type: ignore[arg-type]
        om = np.einsum("ij,tj->ti", Rg, omega[best_p])
        om = np.einsum("tij,tj->ti", rotation_about(u, -q), om) + u * qd[:, None]
        rank = round(float(np.trace(fit.span)))  # type: ignore[arg-type]
        p_axis = np.linalg.eigh(fit.span)[1][:, -1]  # type: ignore[arg-type]
        lever = _lever_child(sig, j, c, kidx[best_p], u, om, omega[best_p], Rg, rank, p_axis)
        R0, d = lever.M0, lever.d
    lo, hi = opts.gain_range
    why = []
    if fit.std_deg > opts.max_axis_std_deg:
        why.append(f"axis std {fit.std_deg:.2f} deg > {opts.max_axis_std_deg:g}")
    if lever.std_m > opts.max_lever_std_m:
        why.append(f"lever-arm std {lever.std_m * 1e3:.1f} mm > {opts.max_lever_std_m * 1e3:g}")
    if not lo <= fit.gain <= hi:
        why.append(f"gyro gain {fit.gain:.2f} outside {lo:g}..{hi:g}")
    return (
        ImuKinematics(
            imu=imu,
            joint=jn,
            parent_imu=best_p,
            axis=fit.axis,
            lever_arm=lever.r,
            axis_std_deg=fit.std_deg,
            lever_arm_std_m=lever.std_m,
            gain=fit.gain,
            rotation_from_parent=R0,
            axis_in_parent=None if R0 is None else R0.T @ fit.axis,
            joint_origin_in_parent=d,
            up_at_zero=lever.up,
            converged=not why,
            reason="; ".join(why),
        ),
        om,
    )
