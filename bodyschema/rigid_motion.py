"""Ideal IMU readings of a rigid body whose motion was measured from outside (motion capture).

A motion-capture system reports the orientation ``quat`` (wxyz, body -> world) and the position
``pos`` of a marker body. An IMU fixed to that body ideally reads the body-frame angular velocity and
the specific force ``R^T (a - g)``. These functions turn the reference motion into those readings so
that a measured IMU can be compared with what it should have said (see
:mod:`bodyschema.discrepancy`). The accelerometer reading needs the second derivative of a measured
position, which amplifies measurement noise; :func:`lowpass` is the zero-phase filter applied to the
reference *and* the measured signals alike so both see the same band.

Also here: :func:`integrate_angular_velocity` and :func:`smooth_random_motion`, the inverse
direction, used to build synthetic recordings with a known answer.
The rotation helpers of the kinematics fits (:func:`skew`, :func:`rotation_about`,
:func:`project_rotation`, :func:`perp_basis`, :func:`rotvec`, :func:`tilted`) live here too: one place
for the rotations of a rigid body, whoever reads them.

Example
-------
>>> import numpy as np
>>> t = np.arange(200) * 0.01
>>> w = np.tile([0.0, 0.0, 1.0], (200, 1))                 # 1 rad/s about body z
>>> quat = integrate_angular_velocity(t, w)
>>> np.round(angular_velocity(t, quat)[100], 6).tolist()
[0.0, 0.0, 1.0]
>>> gyro, acc = ideal_imu(t, quat, np.zeros((200, 3)), [0.0, 0.0, -9.81])
>>> np.round(acc[50], 6).tolist()                            # at rest with z up: +9.81 on z
[0.0, 0.0, 9.81]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import make_interp_spline
from scipy.signal import butter, sosfiltfilt
from scipy.spatial.transform import Rotation, RotationSpline

from bodyschema.imu_effects import specific_force
from bodyschema.recording import GRAVITY

__all__ = [
    "ReferenceMotion",
    "angular_velocity",
    "continuous_quat",
    "ideal_imu",
    "integrate_angular_velocity",
    "linear_acceleration",
    "lowpass",
    "perp_basis",
    "project_rotation",
    "quat_to_matrix",
    "reference_motion",
    "rotation_about",
    "rotvec",
    "skew",
    "smooth_random_motion",
    "tilted",
]

#: Gravity as the world frame of a reference motion sees it (z up), as a default argument.
_GRAVITY = tuple(GRAVITY.tolist())


def _check_t(t: ArrayLike, n: int) -> np.ndarray:
    tt = np.asarray(t, dtype=np.float64)
    if tt.ndim != 1 or tt.shape[0] != n:
        raise ValueError(f"t must have shape ({n},), got {tt.shape}")
    if n < 3:
        raise ValueError("a reference motion needs at least 3 samples")
    if not np.all(np.diff(tt) > 0):
        raise ValueError("t must be strictly increasing")
    return tt


def _check_quat(quat: ArrayLike) -> np.ndarray:
    q = np.asarray(quat, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"quat must have shape (T, 4) wxyz, got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("quat contains NaN or Inf; fill or mask the gaps first")
    n = np.linalg.norm(q, axis=1)
    if np.any(n < 1e-9):
        raise ValueError("quat contains zero-norm rows")
    return q / n[:, None]


def continuous_quat(quat: ArrayLike) -> np.ndarray:
    """Unit quaternions (wxyz) with signs flipped so neighbours lie in the same hemisphere.

    ``q`` and ``-q`` are the same rotation; interpolation and differentiation need them continuous.

    >>> continuous_quat([[1.0, 0, 0, 0], [-1.0, 0, 0, 0]])[:, 0].tolist()
    [1.0, 1.0]
    """
    q = _check_quat(quat).copy()
    if q.shape[0] > 1:
        flip = np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))
        flip[flip == 0] = 1.0
        q[1:] *= np.cumprod(flip)[:, None]
    return q


def quat_to_matrix(quat: ArrayLike) -> np.ndarray:
    """Rotation matrices (T, 3, 3) of wxyz quaternions (body -> world: ``v_world = R @ v_body``)."""
    return Rotation.from_quat(_check_quat(quat), scalar_first=True).as_matrix()


def angular_velocity(t: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Body-frame angular velocity (T, 3) rad/s of an orientation track, what an ideal gyro reads.

    The derivative of scipy's cubic :class:`~scipy.spatial.transform.RotationSpline` through the
    samples: on smooth motion its error is ~40x smaller than a central difference on the group
    (whose O(h²) error reads like a gyro scale error of a few 0.1 %).
    """
    q = _check_quat(quat)
    tt = _check_t(t, q.shape[0])
    return RotationSpline(tt, Rotation.from_quat(q, scalar_first=True))(tt, 1)


def linear_acceleration(t: ArrayLike, pos: ArrayLike) -> np.ndarray:
    """World-frame acceleration (T, 3) m/s² of a position track: 2nd derivative of a quintic spline.

    An interpolating spline is linear in the data, so low-passing its derivative equals
    differentiating low-passed positions; measured positions need that low-pass (:func:`lowpass`):
    every derivative amplifies noise. Twice-applied central differences would bias smooth motion by
    O(h²), which reads like an accelerometer scale error.
    """
    p = np.asarray(pos, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"pos must have shape (T, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("pos contains NaN or Inf; fill or mask the gaps first")
    tt = _check_t(t, p.shape[0])
    k = 5 if tt.shape[0] > 5 else 3
    return make_interp_spline(tt, p, k=k, axis=0)(tt, 2)


def lowpass(x: ArrayLike, rate: float, cutoff: float | None, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along time (axis 0); ``cutoff=None`` returns ``x`` unchanged.

    Zero phase matters here: a causal filter would delay the signal and look like a time offset.

    >>> x = np.ones((100, 3))
    >>> bool(np.allclose(lowpass(x, 100.0, 5.0), 1.0))
    True
    """
    a = np.asarray(x, dtype=np.float64)
    if cutoff is None:
        return a.copy()
    if not 0 < cutoff < rate / 2:
        raise ValueError(f"cutoff {cutoff} Hz must lie in (0, {rate / 2}) for a {rate} Hz signal")
    sos = butter(order, cutoff, fs=rate, output="sos")
    return sosfiltfilt(sos, a, axis=0)


@dataclass(frozen=True)
class ReferenceMotion:
    """The reference motion of one rigid body, ready for the IMU forward model.

    ``R`` (T, 3, 3) body -> world, ``omega`` (T, 3) body-frame angular velocity rad/s, ``acc_world``
    (T, 3) m/s² linear acceleration of the body origin in the world, ``gravity`` (3,) world gravity.
    """

    t: np.ndarray
    R: np.ndarray
    omega: np.ndarray
    acc_world: np.ndarray
    gravity: np.ndarray

    def select(self, index: np.ndarray | slice) -> ReferenceMotion:
        """The samples picked by ``index`` along time."""
        return ReferenceMotion(
            self.t[index], self.R[index], self.omega[index], self.acc_world[index], self.gravity
        )


def reference_motion(
    t: ArrayLike,
    quat: ArrayLike,
    pos: ArrayLike,
    gravity: ArrayLike = _GRAVITY,
    cutoff: float | None = None,
) -> ReferenceMotion:
    """Angular velocity and acceleration of a tracked rigid body, optionally low-passed at ``cutoff`` Hz.

    The orientation itself is not filtered (differences of a few tenths of a degree do not matter to
    the specific force); the angular velocity and the acceleration are.
    """
    q = continuous_quat(quat)
    tt = _check_t(t, q.shape[0])
    rate = float(1.0 / np.median(np.diff(tt)))
    omega = lowpass(angular_velocity(tt, q), rate, cutoff)
    acc = lowpass(linear_acceleration(tt, np.asarray(pos, dtype=np.float64)), rate, cutoff)
    g = np.asarray(gravity, dtype=np.float64).reshape(3)
    return ReferenceMotion(tt, quat_to_matrix(q), omega, acc, g)


def ideal_imu(
    t: ArrayLike,
    quat: ArrayLike,
    pos: ArrayLike,
    gravity: ArrayLike = _GRAVITY,
    cutoff: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro, acc)``, each (T, 3): what an ideal IMU at the body origin, aligned with the body, reads."""
    ref = reference_motion(t, quat, pos, gravity, cutoff)
    return ref.omega, specific_force(ref.R, ref.acc_world, ref.gravity)


def integrate_angular_velocity(
    t: ArrayLike, omega: ArrayLike, quat0: ArrayLike = (1.0, 0.0, 0.0, 0.0)
) -> np.ndarray:
    """Orientation track (T, 4) wxyz from a body-frame angular velocity (T, 3), midpoint rule.

    Exact for a rate that is constant over each step; for a smooth rate the error is second order
    in the step, so integrate on a finer grid than the one you sample when you need accuracy.
    """
    w = np.asarray(omega, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 3:
        raise ValueError(f"omega must have shape (T, 3), got {w.shape}")
    tt = _check_t(t, w.shape[0])
    steps = Rotation.from_rotvec(0.5 * (w[1:] + w[:-1]) * np.diff(tt)[:, None])
    rot = Rotation.from_quat(np.asarray(quat0, dtype=np.float64), scalar_first=True)
    # A sequential product: each orientation depends on the previous one (no vectorised form).
    mats = steps.as_matrix()
    R = rot.as_matrix()
    Rs = np.empty((w.shape[0], 3, 3))
    Rs[0] = R
    for k in range(mats.shape[0]):
        R = R @ mats[k]
        Rs[k + 1] = R
    out = Rotation.from_matrix(Rs).as_quat(scalar_first=True)
    return continuous_quat(out)


def smooth_random_motion(
    duration: float,
    rate: float,
    rng: np.random.Generator,
    max_rate: float = 3.0,
    max_accel: float = 2.0,
    bandwidth: float = 1.5,
    oversample: int = 8,
) -> dict[str, np.ndarray]:
    """A smooth random rigid-body motion with its exact ideal IMU readings (for tests with an answer).

    Angular velocity and position are random sums of sinusoids below ``bandwidth`` Hz, scaled to peak
    at about ``max_rate`` rad/s and ``max_accel`` m/s². The orientation is integrated on a grid
    ``oversample`` times finer than ``rate``. Returns ``t``, ``quat``, ``pos`` (the reference a motion
    capture system would see) and ``gyro``, ``acc`` (what an ideal IMU reads, computed analytically,
    not by differentiating the reference), gravity [0, 0, -9.81].

    >>> m = smooth_random_motion(2.0, 100.0, np.random.default_rng(0))
    >>> m["quat"].shape, m["acc"].shape
    ((200, 4), (200, 3))
    """
    n = round(duration * rate)
    if n < 3:
        raise ValueError("duration * rate must give at least 3 samples")
    n_comp = 6
    fw = rng.uniform(0.1, bandwidth, size=(n_comp, 3))
    pw = rng.uniform(0, 2 * np.pi, size=(n_comp, 3))
    aw = rng.normal(size=(n_comp, 3))
    fp = rng.uniform(0.1, bandwidth, size=(n_comp, 3))
    pp = rng.uniform(0, 2 * np.pi, size=(n_comp, 3))
    ap = rng.normal(size=(n_comp, 3))
    ap = ap / (2 * np.pi * fp) ** 2  # equal acceleration share per component

    def omega_at(tt: np.ndarray) -> np.ndarray:
        return np.einsum("cj,tcj->tj", aw, np.sin(2 * np.pi * fw * tt[:, None, None] + pw))

    def acc_at(tt: np.ndarray) -> np.ndarray:
        phase = np.sin(2 * np.pi * fp * tt[:, None, None] + pp)
        return -np.einsum("cj,tcj->tj", ap * (2 * np.pi * fp) ** 2, phase)

    fine = np.arange(n * oversample) / (rate * oversample)
    peak_w = np.max(np.abs(omega_at(fine)))
    aw = aw * (max_rate / peak_w)
    ap = ap * (max_accel / np.max(np.abs(acc_at(fine))))
    quat_fine = integrate_angular_velocity(fine, omega_at(fine))
    t = fine[::oversample]
    quat = quat_fine[::oversample]
    pos = np.einsum("cj,tcj->tj", ap, np.sin(2 * np.pi * fp * t[:, None, None] + pp))
    pos = pos + np.array([0.0, 0.0, 1.0])
    gravity = GRAVITY.copy()
    acc = specific_force(quat_to_matrix(quat), acc_at(t), gravity)
    return {"t": t, "quat": quat, "pos": pos, "gyro": omega_at(t), "acc": acc, "gravity": gravity}


# ------------------------------------------------------------------------------------ rotations
def skew(v: np.ndarray) -> np.ndarray:
    """``[v]×`` for (..., 3) vectors: (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))  # filled in place: the kinematics' searches call this often
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -w, y, -x
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = w, -y, x
    return out


def rotation_about(u: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations by ``angle`` (T,) about the unit axis ``u``, (T, 3, 3).

    >>> np.round(rotation_about(np.array([0.0, 0, 1]), np.array([np.pi / 2]))[0] @ [1, 0, 0], 6).tolist()
    [0.0, 1.0, 0.0]
    """
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    uu = np.outer(u, u)
    return c * np.eye(3) + (1.0 - c) * uu + s * skew(u)


def project_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest ``M`` (Frobenius), by SVD; of each matrix of a stack (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(M)
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    return U @ Vt


def perp_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2): two orthonormal vectors perpendicular to ``u``."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], axis=1)


def rotvec(x: np.ndarray) -> np.ndarray:
    """The rotation by the rotation vector ``x`` (3,)."""
    angle = float(np.linalg.norm(x))
    return np.eye(3) if angle < 1e-15 else rotation_about(x / angle, np.array([angle]))[0]


def tilted(u: np.ndarray, U: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``u`` leaned by the small angles ``theta`` (2,) along the perpendicular basis ``U`` (3, 2)."""
    v = u + U @ theta
    return v / np.linalg.norm(v)
