"""What :func:`~bodyschema.kinematics.estimate_kinematics` reports, its settings, and their JSON."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.timing import DLPF_GYRO
from bodyschema.topology import Topology

__all__ = [
    "UNOBSERVABLE",
    "ImuKinematics",
    "JointKinematics",
    "Kinematics",
    "KinematicsOptions",
    "SameLink",
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
    :func:`fuse`.
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
    *gyro's* frame, through the rotation the two gyros alone fix (:func:`gyro_reading`); with
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
        out: dict[str, Any] = {
            "joint": self.joint,
            "parent_imu": self.parent_imu,
            "axis": _vec(self.axis),
            "lever_arm": _vec(self.lever_arm),
            "axis_std_deg": _finite(self.axis_std_deg),
            "lever_arm_std_m": _finite(self.lever_arm_std_m),
            "gain": _finite(self.gain),
            "converged": self.converged,
            "gyro_axis": _vec(self.gyro_axis),
            "gyro_axis_std_deg": _finite(self.gyro_axis_std_deg),
        }
        out |= self._gyro_json()
        out |= self._frame_json()
        return out

    def _gyro_json(self) -> dict[str, Any]:
        """The optional entries of the gyros' axis fit, in :meth:`to_json`'s order."""
        out: dict[str, Any] = {}
        if self.gyro_axis_in_parent is not None:
            out["gyro_axis_in_parent"] = _vec(self.gyro_axis_in_parent)
            out["gyro_axis_in_parent_std_deg"] = _finite(self.gyro_axis_in_parent_std_deg)
        if self.gyro_parent_axis is not None:
            out["gyro_parent_axis"] = _vec(self.gyro_parent_axis)
        if self.parent_rank:
            out["parent_rank"] = self.parent_rank
        if math.isfinite(self.turn_about_parent_std_deg):
            out["turn_about_parent_std_deg"] = _finite(self.turn_about_parent_std_deg)
        if self.undetermined:
            out["undetermined"] = list(self.undetermined)
        if self.axis_converged and not self.converged:
            out["axis_converged"] = True
        return out

    def _frame_json(self) -> dict[str, Any]:
        """The optional entries of backlash, the frame relative to the parent and the reason."""
        out: dict[str, Any] = {}
        if math.isfinite(self.backlash_deg):
            out["backlash_deg"] = _finite(self.backlash_deg)
            out["backlash_std_deg"] = _finite(self.backlash_std_deg)
        if self.rotation_from_parent is not None:
            out["rotation_from_parent"] = [_vec(row) for row in self.rotation_from_parent]
        if self.joint_origin_in_parent is not None:
            out["joint_origin_in_parent"] = _vec(self.joint_origin_in_parent)
        if self.up_at_zero is not None:
            out["up_at_zero"] = _vec(self.up_at_zero)
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


def _vec(x: np.ndarray | None, nd: int = 6) -> list[float] | None:
    return None if x is None else [round(float(v), nd) for v in np.ravel(x)]


def _finite(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None
