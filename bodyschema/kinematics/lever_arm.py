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

**The accelerometer's frame.** The gyro reads ``S ω`` with a sensitivity matrix ``S`` (gains within
3 %, cross-axis terms within 2 % on an MPU-6050), so the axis it reports, ``S u``, leans by up to about
two degrees, and the gyro alone cannot tell that from its mounting. The accelerometer can: gravity
turns with the link about the true axis, in the accelerometer's own frame, whose axes are square
(only its gains are off, and they are fitted). So the accelerometer model is refitted with the axis
free to lean (and, under a non-root joint, ``R0`` free to turn): nonlinear least squares over those
angles with the linear parameters projected out (:func:`_refine`), with its sandwich covariance. That
lean is fused with the gyro's reading, whose prior covariance follows from the datasheet bounds
(:func:`_gyro_lean_cov`), by inverse covariances (:func:`_fuse`): where the accelerometer sees the axis
well (gravity turns a lot about it) the answer is the accelerometer frame's, where it does not (an axis
near vertical) it stays near the gyro's with the gyro's uncertainty. The angular velocities rebuilt for
the joints below are then in the accelerometer's frame too. ``gyro_axis`` keeps the gyro's reading.

**The gyros' reading, for drift.** Each IMU's gyro is also regressed on its parent IMU's gyro as that
reads (:func:`_gyro_reading`), with the intercepts the parent gyro's bias needs through the joint and
one regressor for the encoder's steps at reversals (a dead band, :func:`_band_side`): ``gyro_axis``,
``gyro_axis_in_parent`` and ``backlash_deg`` then depend on two gyros' sensitivity matrices, which the
same IMUs repeat, and on noise, where the answers above carry every ancestor's, with errors that move
with the motion.

**Uncertainty.** The residuals of band-limited signals are autocorrelated, so the covariance of every
fit is the heteroscedasticity-and-autocorrelation-consistent (Newey-West) sandwich, with a Bartlett
window as long as the band's correlation time. ``axis_std_deg`` is the RMS angular error of ``u``: noise
and what remains of the gyro's lean after the fusion; ``gyro_axis_std_deg`` is the noise of the gyro's
reading alone (its lean is the same in every recording of one IMU, which is what drift compares).
``lever_arm_std_m`` is the RMS error of ``r``. What the sandwich cannot know, a model error of the
accelerometers' lean that does not shrink with more data, is added to their lean before the fusion
(``KinematicsOptions.acc_model_error_deg``, measured on simulated trees: :func:`_fuse`);
``bodyhealth bench kinematics`` reports the share of axes within two stds. An answer is ``converged``
when the joint moved enough, the axis gain is plausible and both stds (the gyro's noise and the lever
arm's) are within :class:`KinematicsOptions` bounds.

**What one recording leaves open.** Three answers, not two: a quantity the data do not fix is reported
with its std and named in ``undetermined``, with the motion that would fix it, not given as a number
that looks like the others. Where the parent link turned about one axis only (a root joint on the fixed
base), the child's ``R0`` turned about that axis's image fits exactly as well with ``d`` turned with
it: the parent's link accelerations ``K_p`` commute with turns about its own axis, so ``Rot R0`` and
``Rot d`` predict the same specific force. Only gravity across that axis tells the turn, ``g sin β``
for an axis ``β`` from vertical, and the accelerometers' biases trade with it (0.17 m/s² a degree
against their ±80 mg). The std of that turn comes from a fit over it alone, priors included
(:func:`_turn_std`); above ``max_axis_std_deg`` the turn, ``rotation_from_parent``,
``joint_origin_in_parent`` and the joint's ``axis_in_parent`` about that axis are undetermined. Such a
std is a curvature, not a bound: wells half a turn apart fit alike, and the rotations it flags can be
off by up to a half turn (``bodyhealth bench rotations`` compares the flagged and the passed ones with
the simulator on every catalog robot). Likewise two gyros on a link
that turned about one axis do not fix their rotation about it (:class:`SameLink`, ``rank``): the
joint's axis in the second one's frame is then left out.

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
>>> k = estimate_kinematics(rec, Topology({"j1": None}, {"imu1": "j1"})).imus["imu1"]
>>> np.round(k.axis, 3).tolist(), bool(k.gyro_axis_std_deg < 0.1)
([0.0, 0.6, 0.8], True)

An accelerometer that reads nothing cannot tell the gyro's lean: the axis keeps the gyro's datasheet
uncertainty (MPU-6050: about a degree).

>>> bool(0.5 < k.axis_std_deg < 1.5)
True
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.diff import undetermined_here
from bodyschema.recording import Recording
from bodyschema.timing import DLPF_GYRO, choose_band, edge_margin, lowpass, median_rate, timed_view
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
    "an accelerometer's cross-axis misalignment: axes are in the accelerometer's frame, taken as square",
    "where a parent link turned about one axis only (a root joint's link): the turn about that axis of a "
    "child's rotation_from_parent, joint_origin_in_parent and axis_in_parent, which only gravity across "
    "the axis fixes (the link's own accelerations turn with it); each answer's undetermined list names "
    "it where its std exceeds max_axis_std_deg. And the turn about it between two IMUs on that link "
    "(same_link, rank 1), which their gyros do not fix",
)


@dataclass(frozen=True)
class KinematicsOptions:
    """Settings of :func:`estimate_kinematics`.

    ``band_hz`` is the common band (None: :func:`bodyschema.timing.choose_band`, 10 Hz at most).
    ``min_qd_rms`` (rad/s, in band) is the joint motion below which nothing is claimed. An answer is
    converged when ``gyro_axis_std_deg`` ≤ ``max_axis_std_deg``, ``lever_arm_std_m`` ≤ ``max_lever_std_m`` and
    the gyro's gain along the axis lies within ``gain_range``. A rotation whose turn about a one-axis
    parent's axis has a std above ``max_axis_std_deg`` is reported undetermined (module docstring).

    ``accelerometer_frame`` gives axes in the accelerometer's frame, from gyro and accelerometers
    together (module docstring); False gives the axis the gyro reports. ``gyro_scale_error`` and
    ``gyro_cross_axis`` are the half-widths of the gyro's sensitivity errors (datasheet: MPU-6050 ±3 %
    and ±2 %), the prior on how far the gyro's reading of an axis can lean; ``acc_scale_error`` the
    half-width of the accelerometer's gain errors (±3 %), a prior on the gains those fits leave free;
    ``acc_bias`` the half-width of its zero-g offset (m/s²; ±80 mg on the worst axis), a prior on the
    biases of the child model (:func:`_child_prior_stds`). ``acc_model_error_deg`` is the RMS error of
    the accelerometers' lean beyond its noise, measured on simulated trees: the model error of
    :func:`_fuse`.
    """

    band_hz: float | None = None
    min_qd_rms: float = 0.05
    max_axis_std_deg: float = 1.0
    max_lever_std_m: float = 0.005
    gain_range: tuple[float, float] = (0.8, 1.25)
    imu_bandwidth_hz: float | None = DLPF_GYRO[3][0]
    accelerometer_frame: bool = True
    gyro_scale_error: float = 0.03
    gyro_cross_axis: float = 0.02
    acc_scale_error: float = 0.03
    acc_bias: float = 0.08 * 9.80665
    acc_model_error_deg: float = 0.15


@dataclass(frozen=True)
class ImuKinematics:
    """One IMU's joint, that joint's axis and the IMU's lever arm, in the IMU's own frame.

    ``axis`` is the unit axis (sign: positive ``q``), ``lever_arm`` the perpendicular vector from the axis
    to the IMU origin (m). ``rotation_from_parent`` (3×3) maps vectors of ``parent_imu``'s frame into
    this IMU's frame at ``q = 0``; ``joint_origin_in_parent`` is the foot of the lever arm on the axis
    in ``parent_imu``'s frame (m); ``up_at_zero`` (root joints) the specific force at ``q = 0``, which
    gives the link's tilt. ``reason`` says why an answer is not converged; ``axis_converged`` holds
    when the axis is (its std and the gyro's gain within bounds) whatever the lever arm's std.

    ``gyro_axis`` is the axis as the gyro reports it against the parent's gyro as that reads (its
    sensitivity matrix leans it by up to about 2°) and ``gyro_axis_in_parent`` that axis in the parent
    *gyro's* frame, through the rotation the two gyros alone fix (:func:`_gyro_reading`); with
    ``gyro_axis_std_deg`` and ``gyro_axis_in_parent_std_deg`` (noise only) they are what
    :mod:`bodyschema.kinematic_drift` compares: the lean is the same in every recording of the same
    IMUs, so a change beyond the noise is the body's. Where the parent link turns about one axis only,
    the gyro fixes ``R0`` on that axis only: ``gyro_axis_in_parent`` is then None, ``gyro_parent_axis``
    the parent's axis as this IMU's gyro sees it (sign arbitrary), and only the angle between it and
    ``gyro_axis`` is the gyro's.

    ``turn_about_parent_std_deg`` is, under such a parent, the std of ``rotation_from_parent``'s turn
    about that axis (NaN otherwise: the gyros fix it), and ``undetermined`` names what the recording
    leaves open, with the motion that would fix it (module docstring).
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
    gyro_axis: np.ndarray | None = None
    gyro_axis_std_deg: float = math.inf
    gyro_axis_in_parent: np.ndarray | None = None
    gyro_parent_axis: np.ndarray | None = None
    gyro_axis_in_parent_std_deg: float = math.inf
    axis_converged: bool = False
    backlash_deg: float = math.nan
    backlash_std_deg: float = math.nan
    parent_rank: int = 0
    turn_about_parent_std_deg: float = math.nan
    undetermined: tuple[str, ...] = ()

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
            "gyro_axis": vec(self.gyro_axis),
            "gyro_axis_std_deg": _finite(self.gyro_axis_std_deg),
        }
        if self.gyro_axis_in_parent is not None:
            out["gyro_axis_in_parent"] = vec(self.gyro_axis_in_parent)
            out["gyro_axis_in_parent_std_deg"] = _finite(self.gyro_axis_in_parent_std_deg)
        if self.gyro_parent_axis is not None:
            out["gyro_parent_axis"] = vec(self.gyro_parent_axis)
        if self.parent_rank:
            out["parent_rank"] = self.parent_rank
        if math.isfinite(self.turn_about_parent_std_deg):
            out["turn_about_parent_std_deg"] = _finite(self.turn_about_parent_std_deg)
        if self.undetermined:
            out["undetermined"] = list(self.undetermined)
        if self.axis_converged and not self.converged:
            out["axis_converged"] = True
        if math.isfinite(self.backlash_deg):
            out["backlash_deg"] = _finite(self.backlash_deg)
            out["backlash_std_deg"] = _finite(self.backlash_std_deg)
        if self.rotation_from_parent is not None:
            out["rotation_from_parent"] = [vec(row) for row in self.rotation_from_parent]
        if self.joint_origin_in_parent is not None:
            out["joint_origin_in_parent"] = vec(self.joint_origin_in_parent)
        if self.up_at_zero is not None:
            out["up_at_zero"] = vec(self.up_at_zero)
        if self.reason:
            out["reason"] = self.reason
        return out

    @classmethod
    def from_json(cls, imu: str, d: dict[str, Any]) -> ImuKinematics:
        """Read back :meth:`to_json` (rounded to its digits; ``axis_in_parent``, the URDF's axis in
        the parent IMU's frame, is not in it: the joint's entry holds it)."""

        def arr(key: str) -> np.ndarray | None:
            return None if d.get(key) is None else np.asarray(d[key], dtype=float)

        def num(key: str, missing: float = math.inf) -> float:
            return missing if d.get(key) is None else float(d[key])

        converged = bool(d.get("converged", False))
        return cls(
            imu=imu,
            joint=d.get("joint"),
            parent_imu=d.get("parent_imu"),
            axis=arr("axis"),
            lever_arm=arr("lever_arm"),
            axis_std_deg=num("axis_std_deg"),
            lever_arm_std_m=num("lever_arm_std_m"),
            gain=num("gain", math.nan),
            rotation_from_parent=arr("rotation_from_parent"),
            joint_origin_in_parent=arr("joint_origin_in_parent"),
            up_at_zero=arr("up_at_zero"),
            converged=converged,
            axis_converged=converged or bool(d.get("axis_converged", False)),
            reason=d.get("reason", ""),
            gyro_axis=arr("gyro_axis"),
            gyro_axis_std_deg=num("gyro_axis_std_deg"),
            gyro_axis_in_parent=arr("gyro_axis_in_parent"),
            gyro_axis_in_parent_std_deg=num("gyro_axis_in_parent_std_deg"),
            gyro_parent_axis=arr("gyro_parent_axis"),
            parent_rank=int(d.get("parent_rank", 0)),
            backlash_deg=num("backlash_deg", math.nan),
            backlash_std_deg=num("backlash_std_deg", math.nan),
            turn_about_parent_std_deg=num("turn_about_parent_std_deg", math.nan),
            undetermined=tuple(d.get("undetermined", ())),
        )


@dataclass(frozen=True)
class JointKinematics:
    """A joint's IMUs, its axis in the frame of each IMU on its parent link (``{imu: unit axis}``; none
    under a root joint, whose base IMU cannot see it turn) and the range of ``q`` the data visited.

    ``ref_imu`` is the IMU whose frame stands for the link's: the parent IMU of the joints below and
    the one the other IMUs on the link are related to (:class:`SameLink`). ``undetermined`` names what
    of ``axis_in_parent`` the recording leaves open (the module docstring's three answers).
    """

    joint: str
    parent: str | None
    imus: tuple[str, ...]
    ref_imu: str | None = None
    axis_in_parent: dict[str, np.ndarray] = field(default_factory=dict)
    q_range: tuple[float, float] = (0.0, 0.0)
    converged: bool = False
    undetermined: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        out = {
            "parent": self.parent,
            "imus": list(self.imus),
            "reference_imu": self.ref_imu,
            "q_range": [round(x, 6) for x in self.q_range],
            "axis_in_parent": {k: [round(float(x), 6) for x in v] for k, v in self.axis_in_parent.items()},
            "converged": self.converged,
        }
        if self.undetermined:
            out["undetermined"] = list(self.undetermined)
        return out

    @classmethod
    def from_json(cls, joint: str, d: dict[str, Any]) -> JointKinematics:
        """Read back :meth:`to_json`."""
        lo, hi = d.get("q_range", (0.0, 0.0))
        return cls(
            joint=joint,
            parent=d.get("parent"),
            imus=tuple(d.get("imus", ())),
            ref_imu=d.get("reference_imu"),
            axis_in_parent={k: np.asarray(v, dtype=float) for k, v in d.get("axis_in_parent", {}).items()},
            q_range=(float(lo), float(hi)),
            converged=bool(d.get("converged", False)),
            undetermined=tuple(d.get("undetermined", ())),
        )


@dataclass(frozen=True)
class SameLink:
    """Two IMUs on one link: ``rotation`` maps vectors of ``b``'s frame into ``a``'s frame.

    ``std_deg`` is its RMS angular error: the fit's noise and the two gyros' cross-axis errors, which
    turn each gyro's frame by the antisymmetric part of its sensitivity matrix (uniform within
    ``gyro_cross_axis``: about ``gyro_cross_axis`` radians RMS for the two, 1.1° on an MPU-6050).
    ``noise_std_deg`` is the noise alone, what drift compares: the same gyros repeat their errors
    (NaN: ``std_deg`` stands for it). ``rank`` is how many independent axes the link turned about. The
    gyros fix the rotation on those directions only: at rank 1 its turn about the link's one axis is
    anyone's, so both stds are infinite (None in JSON) and ``undetermined`` says what would fix it.
    """

    a: str
    b: str
    rotation: np.ndarray
    std_deg: float
    rank: int = 3
    undetermined: tuple[str, ...] = ()
    noise_std_deg: float = math.nan

    def to_json(self) -> dict[str, Any]:
        out = {
            "imus": [self.a, self.b],
            "rotation": [[round(float(x), 6) for x in row] for row in self.rotation],
            "std_deg": _finite(self.std_deg),
            "noise_std_deg": _finite(self.noise_std_deg),
            "rank": self.rank,
        }
        if self.undetermined:
            out["undetermined"] = list(self.undetermined)
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SameLink:
        """Read back :meth:`to_json`. An estimate written before ``rank`` and ``noise_std_deg`` counts
        as rank 3, and its ``std_deg``, which was the noise alone, as both stds."""
        a, b = d["imus"]
        std = math.inf if d.get("std_deg") is None else float(d["std_deg"])
        noise = d.get("noise_std_deg", d.get("std_deg"))
        return cls(
            a,
            b,
            np.asarray(d["rotation"], dtype=float),
            std,
            rank=int(d.get("rank", 3)),
            undetermined=tuple(d.get("undetermined", ())),
            noise_std_deg=math.inf if noise is None else float(noise),
        )


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

    @classmethod
    def from_json(cls, d: dict[str, Any], topology: Topology) -> Kinematics:
        """Read back :meth:`to_json` (kept by the service as a robot's geometry baseline) for the tree
        ``topology`` it was estimated on.

        >>> from bodyschema.topology import Topology
        >>> topo = Topology({"j1": None}, {"imu1": "j1"})
        >>> imu = ImuKinematics("imu1", "j1", axis=np.array([0, 0, 1.0]), axis_std_deg=0.1, converged=True)
        >>> k = Kinematics({"imu1": imu}, {}, (), 10.0, 0.0, 100, topo)
        >>> back = Kinematics.from_json(k.to_json(), topo)
        >>> back.imus["imu1"].axis.tolist(), back.imus["imu1"].converged, back.to_json() == k.to_json()
        ([0.0, 0.0, 1.0], True, True)
        """
        return cls(
            imus={k: ImuKinematics.from_json(k, v) for k, v in d.get("imus", {}).items()},
            joints={k: JointKinematics.from_json(k, v) for k, v in d.get("joints", {}).items()},
            same_link=tuple(SameLink.from_json(x) for x in d.get("same_link", ())),
            band_hz=float(d.get("band_hz", math.nan)),
            lag_ms=float(d.get("lag_ms", 0.0)),
            samples=int(d.get("samples", 0)),
            topology=topology,
        )


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
    """The rotation nearest ``M`` (Frobenius), by SVD; of each matrix of a stack (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(M)
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    return U @ Vt


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


def _ls(X: np.ndarray, Y: np.ndarray, lags: int, ridge: np.ndarray | None = None) -> _Fit:
    """Stacked least squares ``Y[t] ≈ X[t] @ β`` with X (T, m, p), Y (T, m) and its Newey-West covariance.

    Columns are scaled for conditioning; a rank-deficient design (a nuisance block that the data do
    not excite) gets the minimum-norm solution, which leaves the identifiable parameters unchanged.
    ``ridge`` (p,) adds ``Σ ridge_k β_k²`` to the squared residuals: zero-mean priors (:func:`_prior`).
    """
    T, m, p = X.shape
    Xs, scale, Gi, beta, e = _solve(X, Y, ridge)
    g = np.einsum("tmi,tm->ti", Xs, e)
    dof = max(T * m - p, 1)
    cov = Gi @ _newey_west(g, lags) @ Gi * (T * m / dof)
    return _Fit(coef=beta / scale, cov=cov / np.outer(scale, scale), resid=e)


def _solve(
    X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The least squares of :func:`_ls` without its covariance: scaled design, column scales, inverse
    normal matrix, scaled coefficients and residuals (T, m). Flat matrix products keep it on BLAS."""
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


def _resid(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None = None) -> np.ndarray:
    """The residuals (T, m) of :func:`_ls`'s fit, all that a variable projection needs."""
    return _solve(X, Y, ridge)[4]


def _newey_west(g: np.ndarray, lags: int) -> np.ndarray:
    """The long-run covariance of the scores ``g`` (T, p): Bartlett-weighted autocovariances to ``lags``."""
    S = g.T @ g
    for k in range(1, lags + 1):
        w = 1.0 - k / (lags + 1)
        Gk = g[k:].T @ g[:-k]
        S += w * (Gk + Gk.T)
    return S


def _prior(e: np.ndarray, lags: int, stds: np.ndarray) -> np.ndarray:
    """The ridge of :func:`_ls` for zero-mean priors of std ``stds`` (p,) on the coefficients (``inf``:
    none).

    Weighed against the data, whose residuals ``e`` (T, m) have the variance ``σe²`` and are
    correlated over about ``κ`` samples (Newey-West long-run variance over the plain one): the data
    count as ``Σ e² / (κ σe²)``, a prior as ``β² / std²``, so its ridge is ``κ σe² / std²``.
    """
    var = float(np.mean(e * e))
    long_run = float(np.mean([_newey_west(e[:, i : i + 1], lags)[0, 0] for i in range(e.shape[1])]))
    kappa = long_run / max(var * e.shape[0], 1e-300)
    return kappa * var / np.asarray(stds, dtype=float) ** 2


def _penalized(X: np.ndarray, Y: np.ndarray, ridge: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The residuals (T, m) of :func:`_ls`'s fit and its priors' ``sqrt(ridge_k) β_k`` (k,) for the
    coefficients that have one: together, all that a variable projection (:func:`_refine`) needs."""
    _, scale, _, beta, e = _solve(X, Y, ridge)
    return e, _prior_resid(ridge, beta / scale)


def _prior_resid(ridge: np.ndarray | None, coef: np.ndarray) -> np.ndarray:
    """``sqrt(ridge_k) β_k`` for the coefficients ``coef`` with a prior: the priors as residuals."""
    if ridge is None:
        return np.zeros(0)
    has = ridge > 0
    return np.sqrt(ridge[has]) * coef[has]


def _refine(
    residual: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], n: int, n_linear: int, lags: int
) -> _Fit:
    """Nonlinear least squares over ``n`` small parameters (radians), from zero, and their covariance.

    ``residual(x)`` returns the (T, m) residuals left once the model's ``n_linear`` linear parameters
    are fitted for ``x`` (variable projection), and the residuals of those parameters' priors
    (:func:`_prior_resid`). The objective is the sum of both's squares: the priors' residuals belong
    in it, as the linear fit itself weighs them. Without them a search could trade the data's
    residual for a coefficient the prior rules out (under a vertical root axis the parent's bias took
    9.5 m/s², its whole gravity, to turn the child's frame 70°). The covariance is the Newey-West
    sandwich of the Jacobian at the solution, as in :func:`_ls`, with the priors in its bread and only
    the data in its meat. ``coef`` is the solution, ``resid`` its residuals.
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
    return _Fit(coef=sol.x, cov=Hi @ _newey_west(g, lags) @ Hi * (T * m / dof), resid=e)


def _per_axis(X: np.ndarray, Y: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Y (T, 3) ≈ X (T, p) @ coef (p, 3), one fit per column; returns coef and each column's
    covariance (3, p, p)."""
    coef = np.empty((X.shape[1], Y.shape[1]))
    cov = np.empty((Y.shape[1], X.shape[1], X.shape[1]))
    for i in range(Y.shape[1]):
        f = _ls(X[:, None, :], Y[:, i : i + 1], lags)
        coef[:, i] = f.coef
        cov[i] = f.cov
    return coef, cov


def _variances(cov: np.ndarray) -> np.ndarray:
    """The (p, 3) coefficient variances of :func:`_per_axis`'s covariances."""
    return np.diagonal(cov, axis1=1, axis2=2).T


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
    coef: np.ndarray  # the per-output-axis fit (p, 3) and its covariances (3, p, p)
    cov: np.ndarray
    backlash_deg: float = math.nan  # the dead band the encoder's steps at reversals tell (drift reading)
    backlash_std_deg: float = math.nan


def _span_axes(span: np.ndarray) -> tuple[int, np.ndarray]:
    """How many directions a :func:`_span` projector holds, and its strongest direction."""
    return round(float(np.trace(span))), np.linalg.eigh(span)[1][:, -1]


def _span(x: np.ndarray, rel: float = 1e-3) -> np.ndarray:
    """Projector onto the directions a (T, 3) signal excites (second-moment eigenvalues above ``rel``)."""
    lam, V = np.linalg.eigh(x.T @ x)
    V = V[:, lam > rel * max(float(lam[-1]), 1e-300)]
    return V @ V.T


def _axis_fit(sig: _Signals, j: int, c: int, omega_p: np.ndarray | None, measured: bool = False) -> _AxisFit:
    """Fit the exact gyro model of the module docstring for child IMU ``c`` of joint ``j``.

    ``omega_p`` is the parent link's angular velocity rebuilt from the encoders (no gyro bias or gain
    in it); None under a root joint on the fixed base. ``measured`` is the drift reading
    (:func:`_gyro_reading`): ``omega_p`` is the parent gyro's reading instead, whose bias, seen through
    the turning joint, needs the intercepts ``cos q`` and ``sin q`` too, and whose noise floor a
    direction of the parent's motion must clear (1 % of the strongest's power) to count as excited; and
    the encoder's steps at reversals, a dead band's, get a regressor of their own (:func:`_band_side`).
    """
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    qd = r.qd[:, j]  # type: ignore[index]
    if omega_p is None:
        X = np.c_[qd, np.ones_like(qd)]
    else:
        X = np.c_[omega_p, omega_p * np.cos(q)[:, None], omega_p * np.sin(q)[:, None], qd, np.ones_like(qd)]
        if measured:
            X = np.c_[X, np.cos(q), np.sin(q)]
    Yb = sig.band_limit(r.gyro[:, c])
    Xb = sig.band_limit(X)
    if measured:
        rate = _link_rate(sig, X, Xb, r.gyro[:, c], Yb, 0 if omega_p is None else 9)
        side = sig.band_limit(sig.derivative(_band_side(sig, rate))[:, None])
        Xb = np.c_[Xb, side]
    coef, cov = _per_axis(Xb, Yb, sig.lags)
    var = _variances(cov)
    ia = 0 if omega_p is None else 9
    a = coef[ia]
    gain = float(np.linalg.norm(a))
    u = a / gain if gain > 0 else np.array([0.0, 0.0, 1.0])
    P = np.eye(3) - np.outer(u, u)
    var_perp = float(np.sum(np.diag(P) * var[ia])) / max(gain, 1e-12) ** 2
    H = span = None
    if omega_p is not None:
        # a gyro's bias is a constant the intercepts take: only the motion about it spans directions
        span = _span(Xb[:, :3] - Xb[:, :3].mean(axis=0), 1e-2) if measured else _span(Xb[:, :3])
        H = (coef[0:3] + coef[3:6]).T @ span
    backlash = backlash_std = math.nan
    if measured:  # ω = u (q̇_enc - (b/2) ṡ): the side's coefficient is -(b/2) a
        backlash = -2.0 * float(coef[-1] @ u) / max(gain, 1e-12)
        backlash_std = 2.0 * math.sqrt(float(np.sum(u * u * var[-1]))) / max(gain, 1e-12)
    return _AxisFit(
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
    sig: _Signals, X: np.ndarray, Xb: np.ndarray, gyro: np.ndarray, Yb: np.ndarray, ia: int
) -> np.ndarray:
    """The joint's rate as the gyros see the link turn, in the common band: the gyro model fitted
    (on the band-limited ``Xb``, ``Yb``) without the encoder's dead-band steps, everything but its ``q̇``
    column taken out of the child's ``gyro`` and the rest read along the axis. Unlike the encoder's
    velocity it turns where the link turns."""
    coef, _ = _per_axis(Xb, Yb, sig.lags)
    a = coef[ia]
    gain = max(float(np.linalg.norm(a)), 1e-12)
    others = [k for k in range(X.shape[1]) if k != ia]
    rest = gyro - X[:, others] @ coef[others]
    return lowpass(rest @ (a / gain**2), sig.rate, sig.band)


def _band_side(sig: _Signals, rate: np.ndarray) -> np.ndarray:
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


# ------------------------------------------------------------------------------------- lever arm
@dataclass(frozen=True)
class _LeverFit:
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


# ------------------------------------------------------------------- the axis in the accelerometer frame
def _rotvec(x: np.ndarray) -> np.ndarray:
    """The rotation by the rotation vector ``x`` (3,)."""
    angle = float(np.linalg.norm(x))
    return np.eye(3) if angle < 1e-15 else rotation_about(x / angle, np.array([angle]))[0]


def _tilted(u: np.ndarray, U: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``u`` leaned by the small angles ``theta`` (2,) along the perpendicular basis ``U`` (3, 2)."""
    v = u + U @ theta
    return v / np.linalg.norm(v)


def _gyro_lean_cov(u: np.ndarray, U: np.ndarray, opts: KinematicsOptions) -> np.ndarray:
    """Prior covariance (2, 2, rad²) of the lean of the axis a gyro reports, in the basis ``U``.

    The gyro reads ``S ω`` with ``S = I + diag(s) + C`` (scale errors ``s_i`` and cross-axis terms
    ``C_ij``, uniform within the datasheet's half-widths), so the axis it reports is ``S u``. Along a
    unit ``e ⊥ u`` that leans by ``Σ_i e_i s_i u_i + Σ_{i≠j} e_i C_ij u_j``, whose covariance between two
    directions ``e``, ``f`` is ``σs² Σ_i e_i f_i u_i² + σc² Σ_i e_i f_i (1 - u_i²)``.
    """
    vs, vc = opts.gyro_scale_error**2 / 3.0, opts.gyro_cross_axis**2 / 3.0
    return U.T @ np.diag(vs * u**2 + vc * (1.0 - u**2)) @ U


def _fuse(
    u: np.ndarray, noise_var: float, acc: _Fit, at: slice, opts: KinematicsOptions
) -> tuple[np.ndarray, float]:
    """The axis from the gyro's reading ``u`` and the accelerometers' lean of it, and its RMS error (°).

    Two estimates of the lean ``θ`` (basis :func:`_perp_basis`): the gyro's, zero with its noise
    (``noise_var`` per direction) plus the prior of :func:`_gyro_lean_cov`, and the accelerometers'
    (``acc.coef[at]``, sandwich covariance plus the model error), combined by their inverse
    covariances. Where the accelerometers see the axis well the answer is theirs, in their frame; where
    they do not, it stays near the gyro's with the prior's uncertainty.

    The model error (``acc_model_error_deg`` RMS, split over the two directions) is what the
    sandwich covariance cannot know. It was measured on simulated trees (``bodyhealth bench kinematics
    --seed 0``, 5 to 15 joints, MPU-6050 errors, ``robot`` sensing) as the RMS error of the
    accelerometers' own lean (before this fusion) over the axes it decides (its variance below the
    gyro's), beyond its reported variance, ``sqrt(mean(err² - var))``: 0.13, 0.19 and 0.14° from 15, 30
    and 60 s of data (0.14, 0.05 and about 0 on seed 1; 0.12, 0.13 and 0.10 on seed 3). An error that
    does not shrink with the recording's length is the model's, not the noise's. With it, 95 to 100 %
    of the axes of seeds 0 to 3 are within two stds from every length. (It was 0.2° while the child
    model's gain columns read the parent's noisy accelerometer, :func:`_lever_child`, whose
    errors-in-variables bias made 0.33, 0.28 and 0.22° on seed 0.)
    """
    U = _perp_basis(u)
    Cg = _gyro_lean_cov(u, U, opts) + noise_var * np.eye(2)
    # the model error along the directions the accelerometers see; a direction they do not see (a zero
    # of the sandwich covariance: the fit never depended on it) stays without information
    w, V = np.linalg.eigh(acc.cov[at, at])
    seen = w > max(1e-12 * float(w.max()), 0.0)
    model = math.radians(opts.acc_model_error_deg) ** 2 / 2.0
    Pa = (V[:, seen] / (w[seen] + model)) @ V[:, seen].T
    C = np.linalg.inv(np.linalg.inv(Cg) + Pa)
    theta = C @ Pa @ acc.coef[at]
    return _tilted(u, U, theta), math.degrees(math.sqrt(max(float(np.trace(C)), 0.0)))


def _root_axis_acc(
    sig: _Signals, j: int, c: int, u: np.ndarray, turning: np.ndarray, gain_std: float
) -> _Fit:
    """The lean of a root joint's axis the accelerometer implies (:func:`_refine` over two angles).

    Gravity seen from the link turns about the true axis: ``f_c = D Rot(u, -q) g0 + b + [α]× r_t +
    [ω]×[ω]× r`` with the accelerometer's gains ``D = I + diag(δ)`` taken to first order about
    ``turning``, the part of gravity at ``q = 0`` that turns with ``q`` (the part along the axis stays,
    as does the bias: both are in ``b``). Given ``u`` it is linear in (δ, g0, b, r_t, r). The gains are
    free, yet the lean is not: ``D⁻¹`` must make the two gravity components that turn with ``q``
    perpendicular and equally long, two conditions on two gain ratios. That leaves nothing over, so
    the gains also get the datasheet's prior (``gain_std``, :func:`_prior`). A vertical axis (gravity never
    turns) leaves the lean to the gyro through a large covariance.
    """
    q = sig.rec.q[:, j]  # type: ignore[index]
    qd = sig.rec.qd[:, j]  # type: ignore[index]
    # ω = v q̇ under a root joint: [α]× = q̈ [v]×, [ω]×[ω]× = q̇² [v]×², so the band limit of every
    # regressor is that of a scalar signal times a constant matrix, for any leaned axis v
    rows = sig.band_limit(np.c_[np.ones_like(q), np.cos(q), np.sin(q), sig.derivative(qd), qd * qd])
    o, cq, sq, qdd, qd2 = (rows[:, k][:, None, None] for k in range(5))
    U = _perp_basis(u)
    Y = sig.band_limit(sig.rec.acc[:, c])
    eye = np.eye(3)
    ridge: np.ndarray | None = None

    def resid(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = _tilted(u, U, theta)
        vx = skew(v)
        Uv = _perp_basis(v)
        Rq = cq * eye + (o - cq) * np.outer(v, v) - sq * vx  # band-limited Rot(v, -q)
        X = np.zeros((Y.shape[0], 3, 13))
        X[:, :, 0:3] = (Rq @ turning)[:, :, None] * eye
        X[:, :, 3:6] = Rq
        X[:, :, 6:9] = o * eye
        X[:, :, 9:11] = qdd * (vx @ Uv)
        X[:, :, 11:13] = qd2 * (vx @ vx @ Uv)
        return _penalized(X, Y, ridge)

    stds = np.full(13, np.inf)
    stds[0:3] = gain_std
    ridge = _prior(resid(np.zeros(2))[0], sig.lags, stds)
    return _refine(resid, 2, 13, sig.lags)


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
    Xa = _stack(np.c_[np.ones_like(q), np.cos(q), np.sin(q)], [Ka @ U, Kw @ U])
    return _LeverFit(
        r=U @ f.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        up=G[:, 0] + G[:, 1],
        turning=G[:, 1],
        r_tangential=U @ f.coef[-4:-2],
        force=np.einsum("tmp,p->tm", Xa, f.coef),
    )


#: The child model's linear parameters (:func:`_lever_child`): δ_c 0:3, b_c 3:6, b_p 6:9, δ_p 9:12,
#: d_t 12:15, d 15:18, r_t 18:20, r 20:22; the gains are δ_c and δ_p.
_CHILD_COLS = 22
_CHILD_GAINS = [0, 1, 2, 9, 10, 11]
_CHILD_BIASES = [3, 4, 5, 6, 7, 8]


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
    opts: KinematicsOptions,
    noise_var: float,
    fp_model: np.ndarray | None = None,
) -> _LeverFit:
    """Child of a link with an IMU: the accelerometer model with ``R(q) = Rot(u, -q) R0`` a rotation.

    ``f_c = s_c + δ_c ⊙ s_c + b_c`` with ``s_c = R(q) (f_p + δ_p ⊙ f_p + b_p + K_p d) + K_c r``, the
    specific force the child feels: the two accelerometers' gains to first order (``δ``, a few %) and
    their biases, the parent's seen through the turning joint. Given ``R0`` it is linear in (δ_c, b_c,
    b_p, δ_p, d, r) but for the product of ``δ_c`` with the rest (below). (Free intercepts
    ``b1 cos q + b2 sin q`` in place of ``R(q) b_p`` would also absorb most of the gravity the child sees
    turn, which is what tells the axis apart from its accelerometer's gains.) The gyro fixes
    ``R0`` on the directions the parent link turned about; when that is one axis (a root parent),
    the remaining turn about its image is the one that minimises the accelerometer residual (variable
    projection over one angle: a coarse grid, then a bounded search), which gravity decides unless
    the parent's axis is vertical. A general matrix in place of ``R(q)`` would keep the model linear
    but can absorb the ``K_p d`` term through the parent's own dynamics in ``f_p``.

    With ``opts.accelerometer_frame``, the accelerometers then decide the child's frame: ``R0`` turned
    by a rotation vector and ``u`` leaned by two angles (:func:`_refine` over five), the lean fused
    with the gyro's reading (:func:`_fuse`), and ``R0`` refitted for the fused axis. A rotation of the
    child's frame moves ``u`` and ``R0`` together, and the child's accelerometer, whose gains are free
    but whose axes are square, sees it in the gravity it reads.

    The gain columns (``δ_c ⊙ R(q) f_p`` and ``R(q) (δ_p ⊙ f_p)``) are built from ``fp_model``, the
    parent's specific force as its own model predicts it (``_LeverFit.force``), not from its noisy
    reading: free coefficients on a regressor whose noise is also in the residual (``-R(q) n_p``) are an
    errors-in-variables fit that shrinks the noise. Under a root parent, whose specific force along its
    axis is a constant the intercepts take, that shrink is almost free for the signal and a turn of
    ``R0`` about the parent's axis, with the lean, makes up the rest: on ``bench kinematics --seed 2``
    an axis leaned 1.7° (6 std) from the parent's accelerometer noise alone, the same in every noise
    draw, and 0.03° with a noise-free parent. The prediction's own noise is the grandparent's,
    independent of this residual's. ``R(q) f_p`` itself keeps the reading: its coefficient is fixed.

    The child's accelerometer scales the specific force it feels, ``s_c``, not the parent's reading
    turned into its frame, ``R(q) f_p``: that reading holds the parent's bias, which the parent's frame
    carries round with ``q`` (``δ_c ⊙ R(q) b_p``, 3 % of up to 0.8 m/s², turning with ``q`` as the
    gravity the child sees does), and neither holds the accelerations of the joint origin and of the
    child's lever arm. What the gains cannot take of that goes into the lean and into ``R0``: on ``bench
    kinematics --seed 2`` (10 joints, robot 2) an axis under a root parent leaned 1.7° (4 std) that way,
    1.4° with every noise and the gyro's sensitivity errors off, 0.05° with the accelerometers' gains
    off instead. The product is bilinear in the gains and in (δ_p, b_p, d, r), so the gain columns stay
    ``δ_c ⊙ R(q) f_p`` and the rest, ``δ_c ⊙ (s_c - R(q) f_p)`` (:func:`_felt_beyond`), comes from a fit
    without it at the same ``R0`` and axis: one step of alternating least squares in every evaluation
    of the residual, so that the lean and ``R0`` the accelerometers choose are judged with it, and off
    by the gains' product with what that fit got wrong, second order in the gains. That axis is then
    0.48° off (std 0.43°), 0.07° without the noise and the gyro's errors. Taken once, at the gyro's
    ``R0`` and axis, the rest carried the gyro's lean (up to 2°) in the gains and ``b_p`` fitted there,
    and moved another axis (``--seed 1``) from 0.2° to 0.6°. With all of ``s_c`` in the columns, a gain
    common to both accelerometers, which the data do not tell, would trade against the scale of
    ``b_p``, ``d`` and ``r`` instead of between the two gains alone, and the fit, nearly singular along
    it, put a lever arm 0.4 m off there. The gains in the product are fitted with their datasheet
    prior too, even in the final fit: that common gain, and under a vertical root axis the parent's
    gains against its bias (its force hardly changes), are left to it; without it two lever arms of a
    UR5e came out 0.06 and 0.12 m off.
    """
    r = sig.rec
    q = r.q[:, j]  # type: ignore[index]
    mods = (np.ones_like(q), np.cos(q), np.sin(q))
    U = _perp_basis(u)
    kc = _kmats(sig, omega_c)
    KcU = _lever_basis(sig, kc, U)
    fp = r.acc[:, p]
    Kp = np.concatenate(_kmats(sig, omega_p), axis=2)  # (T, 3, 6): d_t then d
    # the regressors at the aligned rate (the model's prediction below) and through the common band
    raw = (
        [m[:, None] * fp for m in mods],
        [m[:, None] * (fp if fp_model is None else fp_model) for m in mods],
        [m[:, None, None] * Kp for m in mods],
    )
    Fm, Gm, Km = ([sig.band_limit(x) for x in xs] for xs in raw)
    ones = [sig.band_limit(m) for m in mods]
    Y = sig.band_limit(r.acc[:, c])

    def build(
        R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, arrays: tuple[list[np.ndarray], ...]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Design (T, 3, 22) and the known part ``R(q) f_p`` (T, 3) from the modulated regressors."""
        F_, G_, K_, o_ = arrays
        uu, ux = np.outer(axis, axis), skew(axis)
        P = (uu @ R, (np.eye(3) - uu) @ R, -ux @ R)
        RF = sum(F @ Pm.T for Pm, F in zip(P, F_, strict=True))
        RG = sum(F @ Pm.T for Pm, F in zip(P, G_, strict=True))
        X = np.zeros((RF.shape[0], 3, _CHILD_COLS))
        X[:, :, 0:3] = RG[:, :, None] * np.eye(3)
        X[:, :, 3:6] = o_[0][:, None, None] * np.eye(3)
        X[:, :, 6:9] = sum(Pm[None, :, :] * o[:, None, None] for Pm, o in zip(P, o_, strict=True))
        X[:, :, 9:12] = sum(Pm[None, :, :] * F[:, None, :] for Pm, F in zip(P, G_, strict=True))
        X[:, :, 12:18] = sum(np.matmul(Pm, K) for Pm, K in zip(P, K_, strict=True))
        X[:, :, 18:22] = kcu
        return X, RF

    def design(R: np.ndarray, axis: np.ndarray, kcu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The design and what it leaves to fit, less the gains' product with the rest of the specific
        force the child feels, as a fit without it and with the gains' prior tells them
        (:func:`_felt_beyond`)."""
        X, RF = build(R, axis, kcu, (Fm, Gm, Km, ones))
        _, scale, _, beta, _ = _solve(X, Y - RF, ridge)
        return X, Y - RF - _felt_beyond(X, beta / scale)

    def resid(
        R: np.ndarray, axis: np.ndarray, kcu: np.ndarray, ridge: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The residuals of :func:`design` with the priors ``ridge`` in both fits, which share one
        factorization: the second moves the first's residuals ``e`` by the product ``p`` less its
        projection onto the design, and its coefficients by ``p``'s fit; and the priors' residuals
        (:func:`_prior_resid`) of the second's coefficients."""
        X, RF = build(R, axis, kcu, (Fm, Gm, Km, ones))
        Xs, scale, Gi, beta, e = _solve(X, Y - RF, ridge)
        flat = Xs.reshape(-1, _CHILD_COLS)
        p = _felt_beyond(X, beta / scale).reshape(-1)
        moved = Gi @ (flat.T @ p)
        e2 = e - (p - flat @ moved).reshape(e.shape)
        return e2, _prior_resid(ridge, (beta - moved) / scale)

    stds = _child_prior_stds(opts)

    def gains_prior(R: np.ndarray) -> np.ndarray:
        """The gains' datasheet prior (:func:`_prior`) against the residuals of the fit without it at
        ``R``: the product needs plausible gains, where the data leave some freedom (a gain common to
        both accelerometers; the parent's gains against its bias when its force along its axis hardly
        changes)."""
        X, RF = build(R, u, KcU, (Fm, Gm, Km, ones))
        return _prior(_resid(X, Y - RF), sig.lags, stds)

    def fit(R: np.ndarray, ridge: np.ndarray | None = None) -> float:
        """The linear fit's objective without the product (the turn's search only has to find the well
        that the accelerometers' frame then refines): the residual sum of squares, plus the priors'
        ``Σ ridge β²`` when the priors ``ridge`` are given (:func:`_penalized`)."""
        X, RF = build(R, u, KcU, (Fm, Gm, Km, ones))
        e, pen = _penalized(X, Y - RF, ridge)
        return float(np.sum(e * e) + np.sum(pen * pen))

    def judged(R: np.ndarray) -> float:
        return fit(R, gains_prior(R))

    R = R0 if span_rank != 1 else _turn_about_parent(fit, judged, R0, R0 @ parent_axis)
    R_gyro, axis, axis_std = R, u, math.nan
    ridge = gains_prior(R)
    if opts.accelerometer_frame:
        # the gyro's prior on R0, weighed against the data as the gains' prior is
        held = _gyro_frame_prior(
            None if span_rank != 1 else R @ parent_axis,
            ridge[_CHILD_GAINS[0]] * stds[_CHILD_GAINS[0]] ** 2,
            noise_var,
            opts,
        )
        axis, axis_std, R, U, KcU = _child_frame(resid, R_gyro, u, kc, sig, noise_var, ridge, held, opts)
    turn_std = (
        math.nan if span_rank != 1 else _turn_std(resid, R, axis, KcU, ridge, R @ parent_axis, sig.lags)
    )
    X, Yr = design(R, axis, KcU)
    f = _ls(X, Yr, sig.lags)
    cov_r = U @ f.cov[-2:, -2:] @ U.T
    kca = np.concatenate([kc[0] @ U, kc[1] @ U], axis=2)
    Xa, RFa = build(R, axis, kca, (*raw, list(mods)))
    return _LeverFit(
        r=U @ f.coef[-2:],
        std_m=math.sqrt(max(float(np.trace(cov_r)), 0.0)),
        d=f.coef[15:18],
        M0=R,
        r_tangential=U @ f.coef[-4:-2],
        axis=axis,
        axis_std_deg=axis_std,
        force=RFa + _felt_beyond(Xa, f.coef) + Xa @ f.coef,
        turn_std_deg=turn_std,
    )


def _child_prior_stds(opts: KinematicsOptions) -> np.ndarray:
    """The child model's priors (:func:`_prior`): the datasheet's gains and biases of both accelerometers
    (uniform within their half-widths), none on the rest.

    The biases' prior matters where the data leave a bias free to take more than a bias: under a
    vertical root axis the parent's specific force is a constant gravity in its own frame, and
    ``R(q) b_p`` can trade it for any other constant, which frees ``R0`` to turn the image of the
    parent's axis, which the gyro had fixed. The MPU-6050's zero-g offset is at most 80 mg; turning
    gravity by θ takes ``2 g sin(θ/2)``, 0.17 m/s² a degree."""
    stds = np.full(_CHILD_COLS, np.inf)
    stds[_CHILD_GAINS] = opts.acc_scale_error / math.sqrt(3.0)
    stds[_CHILD_BIASES] = opts.acc_bias / math.sqrt(3.0)
    return stds


def _felt_beyond(X: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """``δ_c ⊙ (s_c - R(q) f_p)`` (T, 3) of the child model (:func:`_lever_child`) with design ``X`` and
    coefficients ``coef`` (:data:`_CHILD_COLS`): the child's gains times the rest of the specific force
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
    with that prior. On a quadruped's hips (30 s windows) the flipped well's costs 15 to 140 against
    2 to 6 for the other, whose residual alone was up to 3.5 times the flipped well's. Judged by the
    largest gain of the fit without the prior, a gain the data do not tell decided (1 to 120, in
    either well): the parent's along its own axis, which its bias takes as well where its force along
    that axis hardly changes. The flipped well was then kept in 29 of 48 windows of the hips' IMUs,
    harmless to the linear fit, whose gains absorb the flip, but for ``rotation_from_parent`` (162°
    off) and for the gains' product with the rest of the force the child feels
    (:func:`_felt_beyond`), a first-order term: at gains of about -0.8 it put a lever arm 80 mm
    (17 std) off and raised a false ``imu_shifted``."""
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

    return math.degrees(math.sqrt(max(float(_refine(about, 1, _CHILD_COLS, lags).cov[0, 0]), 0.0)))


def _lever_basis(sig: _Signals, kc: tuple[np.ndarray, np.ndarray], U: np.ndarray) -> np.ndarray:
    """The band-limited tangential and centripetal regressors (T, 3, 4) of a lever arm in the plane ``U``."""
    return np.concatenate([sig.band_limit(kc[0] @ U), sig.band_limit(kc[1] @ U)], axis=2)


def _gyro_frame_prior(
    w: np.ndarray | None, data_var: float, noise_var: float, opts: KinematicsOptions
) -> np.ndarray:
    """The gyro's prior on a turn ``x`` (rotation vector, child frame) of the ``R0`` it read, as the rows
    (k, 3) whose product with ``x`` are its residuals, weighed against the data as :func:`_prior` weighs
    (``data_var``: the data's ``κ σe²``).

    The gyro fixes ``R0`` on the directions the parent link turned about: all of it where that is two
    axes or more (``w`` None), the image ``w`` of its one axis otherwise, which leaves the turn about
    ``w`` free. Each gyro's sensitivity errors turn what it reads by at most the larger of its gain and
    cross-axis variances per direction (:func:`_gyro_lean_cov`), and ``R0`` is read by two gyros, so
    each fixed direction gets ``2 max(σs², σc²)`` plus the fit's noise. The accelerometers' search needs
    it: under a vertical root axis the parent's specific force along that axis is gravity, a constant
    its bias can trade, and the turn of ``w`` is then the biases' prior's alone (0.17 m/s² a degree)."""
    var = 2.0 * max(opts.gyro_scale_error, opts.gyro_cross_axis) ** 2 / 3.0 + noise_var
    rows = np.eye(3) if w is None else _perp_basis(w / np.linalg.norm(w)).T
    return math.sqrt(data_var / var) * rows


def _child_frame(
    resid: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]],
    R: np.ndarray,
    u: np.ndarray,
    kc: tuple[np.ndarray, np.ndarray],
    sig: _Signals,
    noise_var: float,
    ridge: np.ndarray,
    held: np.ndarray,
    opts: KinematicsOptions,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """A child link's accelerometer frame (:func:`_lever_child`): the axis, its std, ``R0``, the lever-arm
    plane and its regressors. ``resid(R0, axis, lever regressors, ridge)`` are the child model's
    residuals and its priors', ``ridge`` the priors (:func:`_prior`), ``held @ x`` the residuals of the
    gyro's prior on the turn ``x`` of ``R0`` (:func:`_gyro_frame_prior`)."""
    U = _perp_basis(u)
    KcU = _lever_basis(sig, kc, U)

    def lean(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, pen = resid(_rotvec(x[:3]) @ R, _tilted(u, U, x[3:]), KcU, ridge)
        return e, np.concatenate([pen, held @ x[:3]])

    axis, std = _fuse(u, noise_var, _refine(lean, 5, _CHILD_COLS, sig.lags), slice(3, 5), opts)
    U = _perp_basis(axis)
    KcU = _lever_basis(sig, kc, U)

    def turned(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, pen = resid(_rotvec(x) @ R, axis, KcU, ridge)
        return e, np.concatenate([pen, held @ x])

    return axis, std, _rotvec(_refine(turned, 3, _CHILD_COLS, 0).coef) @ R, U, KcU


# ------------------------------------------------------------------------------------ same link
def _same_link(
    sig: _Signals, a: int, b: int, names: tuple[str, ...], omega: np.ndarray, opts: KinematicsOptions
) -> SameLink | None:
    """``gyro_a = M gyro_b + bias``; the rotation is ``M`` projected, its noise std from M's
    off-diagonals, its std with the gyros' cross-axis errors too (:class:`SameLink`). Measured on the
    catalog robots (``bench rotations``), the rotations at rank 2 or more are off by about that.

    The rank is that of the link's angular velocity ``omega`` as the encoders rebuild it (``a``'s frame;
    no gyro noise in it, so a root joint's link has rank 1 however little it moved), directions below
    1 % of the strongest's power left out, as :func:`_axis_fit` leaves out a measured parent's."""
    gb = sig.band_limit(sig.rec.gyro[:, b])
    ga = sig.band_limit(sig.rec.gyro[:, a])
    moving = gb - gb.mean(axis=0)
    if float(np.sqrt(np.mean(moving**2))) < 1e-3:
        return None
    X = np.c_[gb, np.ones(gb.shape[0])]
    coef, cov = _per_axis(X, ga, sig.lags)
    M = coef[:3].T
    v = _variances(cov)[:3].T
    off = float(np.sum(v) - np.sum(np.diag(v)))
    link = sig.band_limit(omega)
    rank, axis = _span_axes(_span(link - link.mean(axis=0), 1e-2))
    noise = math.degrees(math.sqrt(off / 4.0))
    open_: tuple[str, ...] = ()
    std = math.hypot(noise, math.degrees(opts.gyro_cross_axis))
    if rank < 2:
        std = noise = math.inf
        open_ = (
            f"the turn about the link's one axis ({_vec_text(axis)} in {names[a]}'s frame): the link "
            "turned about it only; a recording in which it turns about a second axis too (a joint above "
            "it, or the base, moving) fixes it",
        )
    return SameLink(
        a=names[a],
        b=names[b],
        rotation=project_rotation(M),
        std_deg=std,
        rank=rank,
        undetermined=open_,
        noise_std_deg=noise,
    )


def _vec_text(v: np.ndarray) -> str:
    """A unit vector for a sentence: ``[0.00, 0.71, 0.71]``."""
    return "[" + ", ".join(f"{x:.2f}" for x in v) + "]"


# ------------------------------------------------------------------------------------------- main
def _order(topo: Topology) -> list[str]:
    """Joints parents first."""
    out: list[str] = []
    seen: set[str | None] = {None}
    todo = list(topo.joint_parent)
    while todo:
        ready = [j for j in todo if topo.joint_parent[j] in seen]
        if not ready:
            out.extend(todo)
            break
        out.extend(ready)
        seen.update(ready)
        todo = [j for j in todo if j not in seen]
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
    force: dict[str, np.ndarray] = field(default_factory=dict)  # each fitted IMU's modelled specific force
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
        why_open = undetermined_here(w.topo, [f"imu:{imu}", f"joint:{jn}"])
        if why_open:
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=why_open)
        elif w.qd_rms[j] < w.opts.min_qd_rms:
            why = f"joint {jn} hardly moved ({w.qd_rms[j]:.3g} rad/s RMS)"
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=why)
        elif pj is not None and parent is None:
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=f"no fitted IMU on the link of {pj}")
        else:
            w.imus[imu], w.omega[imu], w.force[imu] = _one_imu(
                w.sig, w.opts, j, jn, kidx[imu], imu, parent, kidx, w.omega, w.force
            )
    fitted = [k for k in kids if w.imus[k].axis is not None]
    if not fitted:
        return
    # the first whose axis converged: the same IMU from one recording to the next (a lever arm's
    # convergence varies with the motion more), so the joints below are read in the same frame
    w.ref[jn] = next((k for k in fitted if w.imus[k].axis_converged), fitted[0])
    for b in kids:
        if b != w.ref[jn]:
            sl = _same_link(w.sig, kidx[w.ref[jn]], kidx[b], w.sig.rec.imu_names, w.omega[w.ref[jn]], w.opts)
            if sl is not None:
                w.same[b] = sl


def _joint_entry(w: _Walk, jn: str, j: int) -> JointKinematics:
    """Joint ``jn``'s axis in every IMU frame of its parent link (through the same-link rotations)."""
    pj = w.topo.joint_parent.get(jn)
    parent = None if pj is None else w.ref.get(pj)
    in_parent: dict[str, np.ndarray] = {}
    open_: list[str] = []
    axis_p = w.imus[w.ref[jn]].axis_in_parent if jn in w.ref else None
    if parent is not None and axis_p is not None:
        in_parent[parent] = axis_p
        ref = w.imus[w.ref[jn]]
        if ref.undetermined:
            open_.append(
                f"the axis in {parent}'s frame, turned about {parent}'s link axis: std "
                f"{ref.turn_about_parent_std_deg:.2f} deg, from {ref.imu}'s rotation_from_parent "
                "(see its own)"
            )
        left_out = []
        for b in w.on_joint.get(pj, []):
            if b in w.same and w.same[b].a == parent:
                if w.same[b].rank >= 2:
                    in_parent[b] = w.same[b].rotation.T @ axis_p
                else:
                    left_out.append(b)
        if left_out:
            open_.append(
                f"the axis in the frames of {', '.join(left_out)}: left out, their rotations from {parent} "
                "are open about the one axis their link turned about (see same_link)"
            )
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
        undetermined=tuple(open_),
    )


def estimate_kinematics(
    rec: Recording, topology: Topology | None = None, options: KinematicsOptions | None = None
) -> Kinematics:
    """Joint axes, IMU lever arms and same-link rotations of ``rec`` (model in the module docstring).

    ``topology`` is the learned or given tree; without one the fast estimator learns it. A multi-rate
    recording, or a single-clock one without measured velocities (read as ``t_q = t``,
    :func:`bodyschema.timing.timed_view`), is aligned with the lag in ``topology.timing`` (the fast
    estimator's; a topology without timing gets it from a fast fit of ``rec``). An IMU the tree that
    fits does not place (:func:`bodyschema.diff.open_parts`) is not fitted: its reason says so.
    """
    opts = options or KinematicsOptions()
    rec = timed_view(rec)  # positions only, on one clock: the timed path, as the fast estimator reads it
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
        why = undetermined_here(topo, [f"imu:{imu}"]) or "on the base: no joint moves it"
        w.imus[imu] = ImuKinematics(imu=imu, joint=None, reason=why)
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
    force: dict[str, np.ndarray],
) -> tuple[ImuKinematics, np.ndarray, np.ndarray]:
    """Axis, lever arm, the rebuilt angular velocity of one IMU's link and its modelled specific force,
    and the joint as the gyros alone read it (:func:`_gyro_reading`); ``parent``: the reference IMU of
    the parent link (None: a root joint on the fixed base); ``force``: the modelled specific forces of
    the IMUs fitted so far (:func:`_lever_child` reads its parent's)."""
    al = sig.rec
    q, qd = al.q[:, j], al.qd[:, j]  # type: ignore[index]
    R0 = d = None
    best_p = parent
    if parent is None:
        fit = _axis_fit(sig, j, c, None)
        axis, axis_std = fit.axis, fit.std_deg
        om = fit.axis * qd[:, None]
        gyro = _gyro_reading(sig, j, c, None)
        lever = _lever_root(sig, j, c, fit.axis, om)
        if opts.accelerometer_frame:
            noise_var = math.radians(fit.std_deg) ** 2 / 2.0
            gain_std = opts.acc_scale_error / math.sqrt(3.0)
            acc = _root_axis_acc(sig, j, c, fit.axis, lever.turning, gain_std)  # type: ignore[arg-type]
            axis, axis_std = _fuse(fit.axis, noise_var, acc, slice(0, 2), opts)
            om = axis * qd[:, None]
            lever = _lever_root(sig, j, c, axis, om)
    else:
        fit = _axis_fit(sig, j, c, omega[parent])
        u = fit.axis
        # R0 on the span of the parent's motion (all that ω_c needs), from the gyro
        Rg = project_rotation(fit.H)  # type: ignore[arg-type]
        om = np.einsum("ij,tj->ti", Rg, omega[best_p])
        om = np.einsum("tij,tj->ti", rotation_about(u, -q), om) + u * qd[:, None]
        rank, p_axis = _span_axes(fit.span)  # type: ignore[arg-type]
        noise_var = math.radians(fit.std_deg) ** 2 / 2.0
        lever = _lever_child(
            sig, j, c, kidx[best_p], u, om, omega[best_p], Rg, rank, p_axis, opts, noise_var, force[best_p]
        )
        R0, d = lever.M0, lever.d
        gyro = _gyro_reading(sig, j, c, kidx[best_p])
        axis, axis_std = u, fit.std_deg
        if opts.accelerometer_frame:
            # the child's frame is now its accelerometer's: rebuild ω_c in it for the joints below
            axis, axis_std = lever.axis, lever.axis_std_deg  # type: ignore[assignment]
            om = np.einsum("ij,tj->ti", R0, omega[best_p])  # type: ignore[arg-type]
            om = np.einsum("tij,tj->ti", rotation_about(axis, -q), om) + axis * qd[:, None]
    open_: tuple[str, ...] = ()
    if lever.turn_std_deg > opts.max_axis_std_deg:  # a child of a one-axis parent (NaN otherwise)
        up = al.acc[:, kidx[best_p]].mean(axis=0)  # type: ignore[index]
        open_ = (_open_turn(up, p_axis, best_p, lever.turn_std_deg, opts),)  # type: ignore[arg-type]
    lo, hi = opts.gain_range
    why = []
    if fit.std_deg > opts.max_axis_std_deg:
        why.append(f"gyro axis std {fit.std_deg:.2f} deg > {opts.max_axis_std_deg:g}")
    if not lo <= fit.gain <= hi:
        why.append(f"gyro gain {fit.gain:.2f} outside {lo:g}..{hi:g}")
    axis_converged = not why
    if lever.std_m > opts.max_lever_std_m:
        why.append(f"lever-arm std {lever.std_m * 1e3:.1f} mm > {opts.max_lever_std_m * 1e3:g}")
    return (
        ImuKinematics(
            imu=imu,
            joint=jn,
            parent_imu=best_p,
            axis=axis,
            lever_arm=lever.r,
            axis_std_deg=axis_std,
            lever_arm_std_m=lever.std_m,
            gain=fit.gain,
            rotation_from_parent=R0,
            axis_in_parent=None if R0 is None else R0.T @ axis,
            joint_origin_in_parent=d,
            up_at_zero=lever.up,
            converged=not why,
            axis_converged=axis_converged,
            reason="; ".join(why),
            gyro_axis=gyro.fit.axis,
            gyro_axis_std_deg=gyro.fit.std_deg,
            gyro_axis_in_parent=gyro.in_parent,
            gyro_parent_axis=gyro.parent_axis,
            gyro_axis_in_parent_std_deg=gyro.in_parent_std_deg,
            parent_rank=gyro.parent_rank,
            backlash_deg=gyro.fit.backlash_deg,
            backlash_std_deg=gyro.fit.backlash_std_deg,
            turn_about_parent_std_deg=lever.turn_std_deg,
            undetermined=open_,
        ),
        om,
        lever.force,  # type: ignore[return-value]
    )


def _open_turn(up: np.ndarray, axis: np.ndarray, parent: str, std: float, opts: KinematicsOptions) -> str:
    """What a child's turn about its one-axis parent's axis leaves open (module docstring), and the
    motion that fixes it; ``up`` is the parent's mean specific force and ``axis`` its axis, both in
    the parent's frame."""
    tilt = math.degrees(math.acos(min(abs(float(up @ axis)) / max(float(np.linalg.norm(up)), 1e-12), 1.0)))
    return (
        f"the turn about {parent}'s link axis ({_vec_text(axis)} in {parent}'s frame, {tilt:.0f} deg from "
        f"vertical) of rotation_from_parent and joint_origin_in_parent: std {std:.2f} deg > "
        f"{opts.max_axis_std_deg:g}; the joint's position about that axis trades with it and only gravity "
        "across the axis tells it; a recording with that axis further from vertical fixes it, or the joint's "
        "position from a drawing"
    )


@dataclass(frozen=True)
class _GyroReading:
    """A child IMU's joint as its gyro alone reports it (:func:`_gyro_reading`)."""

    fit: _AxisFit
    #: the axis in the parent gyro's frame, and its std (a parent that turned about two axes or more)
    in_parent: np.ndarray | None = None
    in_parent_std_deg: float = math.inf
    parent_axis: np.ndarray | None = None  # the parent's one axis as this gyro sees it (sign arbitrary)
    parent_rank: int = 0  # how many independent axes the parent link turned about (0: a root joint)


def _gyro_reading(sig: _Signals, j: int, c: int, p: int | None) -> _GyroReading:
    """The joint axis and the rotation from the parent as the two gyros alone fix them.

    The child's gyro is regressed on the parent's gyro ``p`` as it reads (None: a root joint), not on
    the parent's motion rebuilt from the encoders down the tree: that keeps every quantity of the
    reading a function of these two gyros' sensitivity matrices, which a recording of the same IMUs
    repeats, and of noise. Through a rebuilt chain every ancestor's answer enters, and its errors
    depend on the motion: the axes of the IMUs four joints deep in the paper-1 tree moved by up to 0.7°
    (7 std) between 30 s windows of a healthy robot that way, and by up to 14° through the
    accelerometer-frame chain.
    """
    if p is None:
        return _GyroReading(_axis_fit(sig, j, c, None, measured=True))
    fit = _axis_fit(sig, j, c, sig.rec.gyro[:, p], measured=True)
    rank, p_axis = _span_axes(fit.span)  # type: ignore[arg-type]
    if rank >= 2:
        in_parent = project_rotation(fit.H).T @ fit.axis
        std = _in_parent_std(fit.coef, fit.cov, fit.span, in_parent)  # type: ignore[arg-type]
        return _GyroReading(fit, in_parent=in_parent, in_parent_std_deg=std, parent_rank=rank)
    seen = fit.H @ p_axis  # type: ignore[operator]
    return _GyroReading(fit, parent_axis=seen / max(float(np.linalg.norm(seen)), 1e-12), parent_rank=rank)
