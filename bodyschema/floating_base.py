"""The rigid model of a floating-base robot: what its base IMU should read, from its encoders and contacts.

A walking robot's base moves with no encoder. What pins it is a foot on the ground: a stance foot does
not move in the world, so the base's motion is the leg's motion seen from the foot (leg odometry;
Bloesch et al., RSS 2012). Here every leg is a serial chain from the IMU's frame to a foot frame, and
each stance foot gives linear constraints on the IMU's twist (its angular velocity ``w`` and the
world velocity of its origin ``v``, both in the IMU frame):

* a **point foot** at ``p`` (IMU frame) moving relative to the IMU at ``dp`` fixes its position:
  ``v + w x p + dp = 0`` (3 equations);
* a **flat foot** also fixes its rotation: ``w + w_f = 0``, with ``w_f`` the foot's angular velocity
  relative to the IMU, in the IMU frame (3 more).

One flat foot fixes the whole twist; point feet fix it when three or more, not on one line, are down;
two leave the rotation about their line free, one leaves all rotation free. :func:`stance_twist`
solves the weighted least squares of every stance foot's constraints, fills what they leave free
from a given angular velocity (the measured gyro, when the caller allows it) and says per sample
which angular-velocity directions the kinematics predicted.

The specific force follows: ``f = dv/dt + w x v - R^T g``. Its gravity term needs the tilt: a flat
foot on level ground gives it directly (:func:`flat_foot_gravity`), point feet through the plane of
three or more stance feet (:func:`foot_plane_gravity`) between which :func:`tilt_filter` carries it
with the angular velocity. :func:`body_reference` packs the result as a
:class:`~bodyschema.rigid_motion.ReferenceMotion`, the form the IMU discrepancy analysis takes.

Example: a base that only translates at 0.5 m/s along x over a point foot 1 m below, fixed in the
world; the foot then moves backwards at 0.5 m/s in the IMU frame.

>>> import numpy as np
>>> p = np.tile([0.0, 0.0, -1.0], (4, 1)); dp = np.tile([-0.5, 0.0, 0.0], (4, 1))
>>> foot = FootMotion(R=np.tile(np.eye(3), (4, 1, 1)), p=p, w=np.zeros((4, 3)), v=dp, flat=True)
>>> w, v, seen = stance_twist([foot], np.ones((4, 1)))
>>> np.round(v[0], 6).tolist(), (np.round(w[0], 6) + 0.0).tolist(), bool(seen[0].all())
([0.5, 0.0, 0.0], [0.0, 0.0, 0.0], True)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from bodyschema.forward_kinematics import axis_rotations
from bodyschema.rigid_motion import ReferenceMotion, lowpass

__all__ = [
    "FootMotion",
    "SerialChain",
    "band_cutoff",
    "body_reference",
    "chain_frames",
    "chain_motion",
    "derivative",
    "flat_foot_gravity",
    "foot_plane_gravity",
    "minimal_rotations",
    "quantization_floor",
    "skew",
    "stance_twist",
    "tilt_filter",
]

#: Relative weight of the fill angular velocity in :func:`stance_twist`: small against the unit
#: weight of a stance foot's constraints, so it decides only the directions they leave free.
FILL_WEIGHT = 1e-6
#: An angular-velocity direction counts as predicted by the kinematics when the stance constraints'
#: information on it (Schur complement eigenvalue) exceeds this, per unit foot weight: a lever of
#: 3 cm between two point feet (0.03 m squared).
SEEN_EIGEN = 1e-3


@dataclass(frozen=True)
class SerialChain:
    """Revolute joints from a start frame (the IMU's) to a tip frame (a foot's).

    ``origins`` (J, 4, 4): each joint's frame in the previous joint's frame (the first in the start
    frame) at angle 0; ``axes`` (J, 3) unit axes in the joint frames; ``columns`` (J,): each joint's
    column of the recording's ``q``; ``tip`` (4, 4) the tip frame in the last joint's frame.
    """

    origins: np.ndarray
    axes: np.ndarray
    columns: tuple[int, ...]
    tip: np.ndarray

    def __post_init__(self) -> None:
        j = len(self.columns)
        if self.origins.shape != (j, 4, 4) or self.axes.shape != (j, 3) or self.tip.shape != (4, 4):
            raise ValueError(f"a chain of {j} joints needs origins (J, 4, 4), axes (J, 3), tip (4, 4)")


@dataclass(frozen=True)
class FootMotion:
    """A foot frame relative to the IMU frame: ``R`` (T, 3, 3) foot -> IMU, ``p`` (T, 3) its origin,
    ``w`` (T, 3) its angular velocity and ``v`` (T, 3) the rate of ``p``, in the IMU frame."""

    R: np.ndarray
    p: np.ndarray
    w: np.ndarray
    v: np.ndarray
    flat: bool


def skew(a: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    z = np.zeros(a.shape[:-1])
    x, y, w = a[..., 0], a[..., 1], a[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def chain_frames(chain: SerialChain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(R_tip (T, 3, 3), p_tip (T, 3), axes (T, J, 3), points (T, J, 3))``: the tip's pose and every
    joint's axis and a point on it, in the start frame, at joint angles ``q`` (T, N)."""
    T = q.shape[0]
    R, p = np.tile(np.eye(3), (T, 1, 1)), np.zeros((T, 3))
    axes, points = [], []
    for o, a, c in zip(chain.origins, chain.axes, chain.columns, strict=True):
        p = p + R @ o[:3, 3]
        R = R @ o[:3, :3]
        axes.append(R @ a)
        points.append(p.copy())
        R = R @ axis_rotations(a, q[:, c])
    p_tip = p + R @ chain.tip[:3, 3]
    empty = np.zeros((T, 0, 3))
    ax = np.stack(axes, axis=1) if axes else empty
    pt = np.stack(points, axis=1) if points else empty
    return R @ chain.tip[:3, :3], p_tip, ax, pt


def chain_motion(chain: SerialChain, q: np.ndarray, qd: np.ndarray, flat: bool) -> FootMotion:
    """The tip's pose and velocity in the start frame at joint angles ``q`` and rates ``qd`` (T, N)."""
    R_tip, p_tip, axes, points = chain_frames(chain, q)
    rates = qd[:, list(chain.columns), None]
    w = np.sum(axes * rates, axis=1)
    v = np.sum(np.cross(axes, p_tip[:, None, :] - points) * rates, axis=1)
    return FootMotion(R_tip, p_tip, w, v, flat)


def _foot_rows(foot: FootMotion) -> tuple[np.ndarray, np.ndarray]:
    """Constraint rows ``A x = b`` on ``x = (v, w)`` of one stance foot: (T, m, 6) and (T, m)."""
    T = foot.p.shape[0]
    eye = np.tile(np.eye(3), (T, 1, 1))
    A = np.concatenate([eye, -skew(foot.p)], axis=2)  # v + w x p = v - [p]x w
    b = -foot.v
    if foot.flat:
        A = np.concatenate([A, np.concatenate([np.zeros((T, 3, 3)), eye], axis=2)], axis=1)
        b = np.concatenate([b, -foot.w], axis=1)
    return A, b


def stance_twist(
    feet: Sequence[FootMotion], weights: np.ndarray, fill: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w, v, seen)``: the IMU's angular velocity and velocity (T, 3) that keep the stance feet
    still, and ``seen`` (T, 3), a basis mask: True where the kinematics fixed that axis of ``w``.

    ``weights`` (T, F) >= 0 is each foot's share of the stance (0: in the air). Directions the feet
    leave free take ``fill`` (T, 3) (None: zero) through a weak pull of :data:`FILL_WEIGHT`. ``seen``
    is tested on the IMU frame's axes: an axis is seen when less than 0.3 of it (a 17 deg lean) lies
    in the directions the feet leave free.
    """
    T = weights.shape[0]
    N = np.zeros((T, 6, 6))
    r = np.zeros((T, 6))
    for f, foot in enumerate(feet):
        A, b = _foot_rows(foot)
        wf = weights[:, f, None, None]
        N += wf * np.einsum("tmi,tmj->tij", A, A)
        r += weights[:, f, None] * np.einsum("tmi,tm->ti", A, b)
    # Information on w alone, v eliminated (Schur complement): what the feet say about the rotation.
    Nvv, Nvw, Nww = N[:, :3, :3], N[:, :3, 3:], N[:, 3:, 3:]
    S = Nww - np.swapaxes(Nvw, 1, 2) @ np.linalg.pinv(Nvv + 1e-12 * np.eye(3)) @ Nvw
    lam, U = np.linalg.eigh(S)
    total = np.maximum(weights.sum(axis=1), 1e-12)
    blind = lam < SEEN_EIGEN * total[:, None]  # (T, 3) eigen-directions the feet leave free
    seen = np.sqrt(np.einsum("tik,tk->ti", U**2, blind.astype(float))) < 0.3
    pull = np.zeros((T, 6, 6))
    pull[:, 3:, 3:] = FILL_WEIGHT * np.eye(3)
    pull[:, :3, :3] = FILL_WEIGHT * 1e-3 * np.eye(3)  # no foot down at all: v stays finite
    rhs = r.copy()
    if fill is not None:
        rhs[:, 3:] += FILL_WEIGHT * fill
    x = np.linalg.solve(N + pull, rhs[..., None])[..., 0]
    return x[:, 3:], x[:, :3], seen


def flat_foot_gravity(feet: Sequence[FootMotion], weights: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """(T, 3) world gravity in the IMU frame from the flat stance feet, each taken level (its frame
    a world frame turned about the vertical): ``R_if g``, averaged by weight. NaN where no flat foot
    is down."""
    acc = np.zeros((weights.shape[0], 3))
    tot = np.zeros(weights.shape[0])
    for f, foot in enumerate(feet):
        if foot.flat:
            acc += weights[:, f, None] * np.einsum("tij,j->ti", foot.R, gravity)
            tot += weights[:, f]
    out = np.full_like(acc, np.nan)
    ok = tot > 0
    g = acc[ok] / tot[ok, None]
    out[ok] = g / np.linalg.norm(g, axis=1, keepdims=True) * np.linalg.norm(gravity)
    return out


def foot_plane_gravity(points: np.ndarray, down: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """(T, 3) world gravity in the IMU frame from the plane through the stance feet (level ground),
    where ``down`` (T, F) marks three or more feet down, not on one line; NaN elsewhere.

    ``points`` (T, F, 3): the feet in the IMU frame. The normal is the plane's least-squares normal,
    turned so that the IMU lies above the feet.
    """
    T = points.shape[0]
    out = np.full((T, 3), np.nan)
    g = float(np.linalg.norm(gravity))
    for t in np.flatnonzero(down.sum(axis=1) >= 3):
        P = points[t, down[t]]
        c = P.mean(axis=0)
        _, s, vt = np.linalg.svd(P - c)
        if s[1] < 0.02:  # on one line (within 2 cm): no plane
            continue
        n = vt[2] if np.dot(vt[2], -c) > 0 else -vt[2]  # the normal pointing from the feet to the IMU
        out[t] = -g * n
    return out


def tilt_filter(t: np.ndarray, w: np.ndarray, g_meas: np.ndarray, tau: float) -> np.ndarray:
    """(T, 3) gravity in the IMU frame carried by the angular velocity ``w`` (``dg/dt = -w x g``) and
    pulled towards the measured ``g_meas`` (NaN: none) with time constant ``tau`` s. Starts from the
    mean of the first second of measurements (the first measurement when there are few)."""
    have = np.flatnonzero(np.all(np.isfinite(g_meas), axis=1))
    if have.size == 0:
        raise ValueError("no tilt measurement: the gravity direction cannot be carried")
    first = have[t[have] <= t[have[0]] + 1.0]
    g = g_meas[first].mean(axis=0)
    norm = float(np.linalg.norm(g_meas[have[0]]))
    out = np.empty_like(w)
    for k in range(len(t)):
        if k:
            dt = t[k] - t[k - 1]
            g = g - dt * np.cross(w[k], g)
            if np.isfinite(g_meas[k, 0]):
                g = g + min(dt / tau, 1.0) * (g_meas[k] - g)
            g = g / np.linalg.norm(g) * norm
        out[k] = g
    return out


def derivative(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Time derivative along axis 0 through a quintic interpolating spline (a central difference at
    100 Hz attenuates 3-5 Hz motion by 0.5-1.5 %, which would read as a scale error)."""
    return make_interp_spline(t, x, k=5, axis=0).derivative()(t)


def minimal_rotations(g_body: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """(T, 3, 3) body -> world rotations that carry the body-frame gravity ``g_body`` onto the world
    ``gravity``, each the smallest such rotation (the heading is not observed and stays 0)."""
    u = g_body / np.linalg.norm(g_body, axis=1, keepdims=True)
    v = np.asarray(gravity, dtype=float) / np.linalg.norm(gravity)
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=1)
    c = u @ v
    K = skew(axis / np.maximum(s, 1e-12)[:, None])
    ang = np.arctan2(s, c)[:, None, None]
    return np.eye(3) + np.sin(ang) * K + (1.0 - np.cos(ang)) * (K @ K)


def body_reference(
    t: np.ndarray, w: np.ndarray, v: np.ndarray, g_body: np.ndarray, gravity: np.ndarray, cutoff: float | None
) -> ReferenceMotion:
    """The IMU's reference motion from its twist (IMU frame) and the gravity it sees: low-passed at
    ``cutoff`` like the readings it is compared with; ``acc = dv/dt + w x v`` in the IMU frame.
    ``t`` must be uniform."""
    rate = float(1.0 / np.median(np.diff(t)))
    w_lp, v_lp = lowpass(w, rate, cutoff), lowpass(v, rate, cutoff)
    a_body = lowpass(derivative(t, v_lp) + np.cross(w_lp, v_lp), rate, cutoff)
    R = minimal_rotations(g_body, gravity)
    return ReferenceMotion(t, R, w_lp, np.einsum("tij,tj->ti", R, a_body), np.asarray(gravity, float))


def quantization_floor(
    quantum: float, rate: float, cutoff: float, lever_m: float, joints: int, order: int = 4
) -> dict[str, float]:
    """The gyro (rad/s) and accelerometer (m/s²) noise that encoder quantization alone puts on the
    prediction: white angle noise ``quantum/sqrt(12)`` per joint at ``rate``, through the zero-phase
    Butterworth low-pass of :func:`~bodyschema.rigid_motion.lowpass` (power response
    ``1/(1+(f/fc)^(2 order))^2``), differentiated once (twice); ``joints`` in the chain add in power,
    the acceleration through a lever of ``lever_m``."""
    from scipy.integrate import quad

    s = quantum / np.sqrt(12.0)
    nyq = rate / 2.0

    def band(power: int) -> float:
        x_max = nyq / cutoff
        return quad(lambda x: x**power / (1.0 + x ** (2 * order)) ** 2, 0.0, x_max, limit=200)[0]

    d1 = s * np.sqrt((2 * np.pi) ** 2 * cutoff**3 * band(2) / nyq)
    d2 = s * np.sqrt((2 * np.pi) ** 4 * cutoff**5 * band(4) / nyq)
    return {"gyro_std": float(d1 * np.sqrt(joints)), "acc_std": float(d2 * lever_m * np.sqrt(joints))}


def band_cutoff(
    quantum: float, rate: float, lever_m: float, joints: int, tol: float = 0.1, cap: float = 10.0
) -> float:
    """The common low-pass (Hz, at most ``cap``) at which encoder quantization alone puts ``tol``
    m/s² on the predicted specific force (:func:`quantization_floor`; the floor grows with the
    cutoff to the power 2.5)."""
    acc = quantization_floor(quantum, rate, cap, lever_m, joints)["acc_std"]
    return float(cap if acc <= tol else cap * (tol / acc) ** 0.4)
