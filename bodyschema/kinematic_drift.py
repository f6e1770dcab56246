"""Geometry drift between two kinematics estimates of one robot: IMUs turned or shifted, axes changed.

The topology diff (:mod:`bodyschema.diff`) sees an IMU that moved to another link; an IMU that turned
or slid on its own link, or a joint whose axis bent, keeps the topology and shows only in the geometry
(:mod:`bodyschema.kinematics`). The axes compared are the ones the gyros report (``gyro_axis``,
``gyro_axis_in_parent``, with their noise-only standard deviations): a gyro's misalignment leans them,
but it belongs to the sensor, not to the run, so it cancels between two estimates from the same
sensors, where the accelerometer-frame axis moves with how much each recording's motion let the
accelerometers decide. (Each reading comes from the IMU's gyro regressed on its parent's gyro as that
reads: regressed on the parent's motion rebuilt down the tree, the axis in the parent's frame moved by
up to 14° between two 30 s windows of a healthy UR5e.) A change is reported when it exceeds ``sigmas``
combined standard deviations plus a small floor:

* ``axis_changed`` — a joint's axis seen from its parent IMU turned (``θ > sigmas √(σ₁² + σ₂²) +
  floor``, with the stds of the axis in the parent's frame, which carry the error of the gyro-fixed
  rotation as well as the axis's), and that parent IMU was not itself found turned. Where the parent
  link turns about one axis only, the gyros fix the joint's axis against that axis but not its turn
  about it (the accelerometers' part, which moves with the motion by more than its noise): then ``θ``
  is the change of the angle between the two axes (its limit with twice the variance: both IMUs' axis
  errors enter), and a bend about the parent's axis reads as ``imu_rotated``, which says so. Also
  when every IMU on the joint's link (two or more) sees the axis turn: several mounts knocked alike
  at once are far less likely than a bent link. The IMUs' own turns are then the bend's;
* ``imu_rotated`` — otherwise, the axis seen from the IMU turned: the IMU turned on its link (a turned
  child IMU leaves the axis in the *parent's* frame as it was). Under a root joint with one IMU on its
  link nothing tells the two apart, and the finding says so;
* ``imu_rotated`` also where the rotation between two IMUs on one link changed (both gyros read it;
  where the link turned about two axes or more): a mount turned about its joint's axis, which no axis
  comparison sees. Which of the two turned the gyros cannot tell; the finding names both;
* ``imu_shifted`` — the lever arm changed by more than its combined std plus a floor (for an IMU that
  also turned, only its length is compared: a turn alone rotates the vector, not its length). The
  stated std is one window's noise: on some links the window's motion moves lever arms by several
  times it, so the service judges slides against many estimates' scatter instead
  (:mod:`bodyschema.lever_pool`, ``DriftOptions.lever_arms``);
* ``backlash`` — the dead band between a joint's encoder and its link changed: the encoder steps by
  the band at each reversal and the gyros do not (``ImuKinematics.backlash_deg``, read by the joint's
  IMU whose two estimates are surest; limit ``sigmas`` combined stds plus ``floor_backlash_deg``).

Only IMUs whose axis converged in both estimates on the same joint are compared, and their lever
arms only where those converged too; the axis in the parent's frame only where the parent link turned
about as many axes in both (one, two or three); an IMU on another joint is the topology diff's ``imu_moved``.

Example
-------
>>> import numpy as np
>>> from bodyschema.kinematics import ImuKinematics, JointKinematics, Kinematics
>>> from bodyschema.topology import Topology
>>> def kin(axis):
...     imu = ImuKinematics("imu1", "j1", axis=np.array(axis), lever_arm=np.array([0.1, 0, 0]),
...                         axis_std_deg=0.05, lever_arm_std_m=0.001, converged=True)
...     return Kinematics({"imu1": imu}, {"j1": JointKinematics("j1", None, ("imu1",), "imu1")}, (),
...                       10.0, 0.0, 100, Topology({"j1": None}, {"imu1": "j1"}))
>>> [f.kind for f in kinematic_findings(kin([0, 0, 1.0]), kin([0, np.sin(0.1), np.cos(0.1)]))]
['imu_rotated']
>>> kinematic_findings(kin([0, 0, 1.0]), kin([0, 0, 1.0]))
()
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bodyschema.findings import Finding
from bodyschema.kinematics import ImuKinematics, Kinematics, SameLink

__all__ = ["DriftOptions", "kinematic_findings"]


@dataclass(frozen=True)
class DriftOptions:
    """How far beyond the estimates' own uncertainty a change must be: ``sigmas`` combined stds plus
    ``floor_deg`` (angles) or ``floor_m`` (lever arms). ``lever_arms=False`` leaves slides out: their
    stated std holds one window's noise, not how the window's motion moves the fit, and on some links
    lever arms move between healthy windows by several times it (module docstring); a caller with
    many estimates judges them against their scatter instead (:mod:`bodyschema.lever_pool`)."""

    sigmas: float = 5.0
    floor_deg: float = 0.2
    floor_m: float = 0.002
    floor_backlash_deg: float = 0.1
    lever_arms: bool = True

    def limit(self, std_a: float, std_b: float, floor: float) -> float:
        """The change two estimates of stds ``std_a`` and ``std_b`` must exceed: ``sigmas`` combined
        stds plus ``floor``."""
        return self.sigmas * math.hypot(std_a, std_b) + floor


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))
    return math.degrees(math.acos(c))


def _both(a: ImuKinematics | None, b: ImuKinematics | None) -> bool:
    """Both estimates found the IMU's axis (its lever arm may still be loose) on the same joint."""
    return (
        a is not None
        and b is not None
        and (a.converged or a.axis_converged)
        and (b.converged or b.axis_converged)
        and a.joint == b.joint
        and a.axis is not None
        and b.axis is not None
    )


def _reading(k: ImuKinematics) -> tuple[np.ndarray, float, np.ndarray | None, float]:
    """The axis, its std, the axis in the parent's frame and that one's std as the gyro reports them
    (module docstring); an estimate without them (built by hand) stands for itself, with twice the
    axis's variance for the axis in the parent's frame (both IMUs' errors enter it)."""
    if k.gyro_axis is None:
        return k.axis, k.axis_std_deg, k.axis_in_parent, math.sqrt(2.0) * k.axis_std_deg  # type: ignore[return-value]
    return k.gyro_axis, k.gyro_axis_std_deg, k.gyro_axis_in_parent, k.gyro_axis_in_parent_std_deg


def _between(axis: np.ndarray, parent_axis: np.ndarray) -> float:
    """The angle between a joint's axis and its parent link's single axis, 0..90° (that one's sign is
    arbitrary)."""
    c = abs(float(axis @ parent_axis)) / (np.linalg.norm(axis) * np.linalg.norm(parent_axis))
    return math.degrees(math.acos(min(c, 1.0)))


def _confidence(change: float, limit: float) -> float:
    """How far past its limit a change is, as a score in (0.5, 1)."""
    return round(1.0 - 0.5 * limit / max(change, limit), 4)


@dataclass(frozen=True)
class _Seen:
    """One IMU's two readings of its joint: the turn of the axis seen from it and of the axis in its
    parent's frame (None: not judged there), each with its limit."""

    old: ImuKinematics
    new: ImuKinematics
    turn: float
    limit: float
    turn_p: float | None
    limit_p: float
    one_axis: bool


def _seen(old: ImuKinematics, new: ImuKinematics, rotated: set[str], o: DriftOptions) -> _Seen:
    (old_axis, old_std, old_in_p, old_p_std), (new_axis, new_std, new_in_p, new_p_std) = (
        _reading(old),
        _reading(new),
    )
    p = old.parent_imu
    # the same parent, not itself turned, and turning about as many axes: a gyro's sensitivity matrix
    # is no rotation, so the rotation fixed on a plane of the parent's motion differs from the one fixed
    # on all three directions (by 0.2 to 0.6° four joints deep in paper-4)
    judged = p is not None and p == new.parent_imu and p not in rotated and old.parent_rank == new.parent_rank
    one_axis = old.gyro_parent_axis is not None and new.gyro_parent_axis is not None
    turn_p: float | None = None
    limit_p = math.inf
    if judged and one_axis:  # the parent turns about one axis: only the angle to it is the gyro's
        turn_p = abs(
            _between(old_axis, old.gyro_parent_axis)  # type: ignore[arg-type]
            - _between(new_axis, new.gyro_parent_axis)  # type: ignore[arg-type]
        )
        # both IMUs' axis errors enter the angle: twice the variance
        limit_p = o.limit(math.sqrt(2) * old_std, math.sqrt(2) * new_std, o.floor_deg)
    elif judged and old_in_p is not None and new_in_p is not None:
        turn_p = _angle(old_in_p, new_in_p)
        limit_p = o.limit(old_p_std, new_p_std, o.floor_deg)
    return _Seen(
        old=old,
        new=new,
        turn=_angle(old_axis, new_axis),
        limit=o.limit(old_std, new_std, o.floor_deg),
        turn_p=turn_p,
        limit_p=limit_p,
        one_axis=one_axis,
    )


def kinematic_findings(
    baseline: Kinematics, current: Kinematics, options: DriftOptions | None = None
) -> tuple[Finding, ...]:
    """``imu_rotated``, ``imu_shifted``, ``axis_changed`` and ``backlash`` findings from ``baseline`` to
    ``current``.

    Per joint: its axis bent when the axis in the parent's frame turned as one of its IMUs sees it, or
    when every IMU on its link (two or more) sees the axis turn (a knock that turns several mounts
    the same way at once is far less likely than a bent link); the IMUs' own turns are then the bend's
    and are not reported again. Otherwise each IMU whose axis turned is ``imu_rotated``. Joints are
    visited parents first, so a parent IMU found turned is known before its children's axes are judged
    in its frame.
    """
    o = options or DriftOptions()
    out: list[Finding] = []
    rotated: set[str] = set()
    for jn, joint in baseline.joints.items():
        seen = [
            _seen(old, new, rotated, o)
            for name in joint.imus
            if _both(old := baseline.imus.get(name), new := current.imus.get(name))
        ]
        bend = [x for x in seen if x.turn_p is not None and x.turn_p > x.limit_p]
        every = len(seen) >= 2 and all(x.turn > x.limit for x in seen)
        if bend or every:
            out.append(_bent(jn, bend, seen))
        for x in seen:
            turned = x.turn > x.limit
            if turned and not (bend or every):
                rotated.add(x.old.imu)
                out.append(_rotated(jn, x))
            shifted = _shifted(x.old, x.new, turned, o) if o.lever_arms else None
            if shifted is not None:
                out.append(shifted)
        slack = _backlash(jn, seen, o)
        if slack is not None:
            out.append(slack)
    bent = {f.joint for f in out if f.kind == "axis_changed"}
    out += _same_link_turns(baseline, current, rotated, bent, o)
    return tuple(out)


def _same_link_turns(
    baseline: Kinematics, current: Kinematics, rotated: set[str], bent: set[str | None], o: DriftOptions
) -> list[Finding]:
    """``imu_rotated`` where the rotation between two IMUs on one link changed: a mount turned about
    its joint's axis, which leaves the axis each IMU sees where it was.

    The rotation is read from the two gyros (:class:`~bodyschema.kinematics.SameLink`) and judged on
    its noise std (the sensors' sensitivity matrices are the same in both estimates). It is fixed only
    where the link turned about two axes or more (``SameLink.rank``): under a root joint on a fixed
    base it turns about one, and the rotation about that axis is anyone's. Pairs with an IMU already
    found turned, or on a bent joint, are left to those findings. Which of the two turned the gyros
    cannot tell: the finding is raised on the second IMU (the first is the link's reference IMU) and
    names both."""
    then = {(s.a, s.b): s for s in baseline.same_link}
    out = []
    for s in current.same_link:
        old = then.get((s.a, s.b))
        a0, a1, b0 = baseline.imus.get(s.a), current.imus.get(s.a), baseline.imus.get(s.b)
        if old is None or a0 is None or a1 is None or b0 is None or {s.a, s.b} & rotated:
            continue
        if a0.joint in bent or a0.joint != b0.joint or min(old.rank, s.rank) < 2:
            continue
        c = (np.trace(old.rotation.T @ s.rotation) - 1.0) / 2.0
        turn = math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))
        limit = o.limit(_noise(old), _noise(s), o.floor_deg)
        if turn > limit:
            out.append(
                Finding(
                    kind="imu_rotated",
                    imu=s.b,
                    joint=a0.joint,
                    confidence=_confidence(turn, limit),
                    detail=(
                        f"rotation between {s.a} and {s.b} on one link turned {turn:.2f} deg (limit "
                        f"{limit:.2f}), the axis each sees unchanged: one of them turned about the "
                        "joint's axis"
                    ),
                )
            )
    return out


def _noise(s: SameLink) -> float:
    """A same-link rotation's noise std, what two estimates from the same gyros differ by (their
    cross-axis errors repeat); ``std_deg`` where it has none (built by hand)."""
    return s.noise_std_deg if not math.isnan(s.noise_std_deg) else s.std_deg


def _backlash(jn: str, seen: list[_Seen], o: DriftOptions) -> Finding | None:
    """``backlash`` of joint ``jn`` when the dead band its encoder's steps tell changed beyond its
    uncertainty, read by the joint's IMU whose two estimates are surest."""
    pairs = [
        (x.old, x.new)
        for x in seen
        if math.isfinite(
            x.old.backlash_deg + x.new.backlash_deg + x.old.backlash_std_deg + x.new.backlash_std_deg
        )
    ]
    if not pairs:
        return None
    old, new = min(pairs, key=lambda p: math.hypot(p[0].backlash_std_deg, p[1].backlash_std_deg))
    change = new.backlash_deg - old.backlash_deg
    limit = o.limit(old.backlash_std_deg, new.backlash_std_deg, o.floor_backlash_deg)
    if abs(change) <= limit:
        return None
    return Finding(
        kind="backlash",
        joint=jn,
        confidence=_confidence(abs(change), limit),
        detail=(
            f"dead band {'grew' if change > 0 else 'shrank'} from {old.backlash_deg:.2f} to "
            f"{new.backlash_deg:.2f} deg (change limit {limit:.2f}; read by {old.imu})"
        ),
    )


def _bent(jn: str, bend: list[_Seen], seen: list[_Seen]) -> Finding:
    """``axis_changed`` of joint ``jn``: from the parent's frame (``bend``), else from all its IMUs."""
    if bend:
        x = max(bend, key=lambda b: b.turn_p / b.limit_p)  # type: ignore[operator]
        assert x.turn_p is not None
        p = x.old.parent_imu
        what = (
            f"axis's angle to the axis {p}'s link turns about changed"
            if x.one_axis
            else f"axis in {p}'s frame turned"
        )
        return Finding(
            kind="axis_changed",
            joint=jn,
            confidence=_confidence(x.turn_p, x.limit_p),
            detail=f"{what} {x.turn_p:.2f} deg (limit {x.limit_p:.2f})",
        )
    lo, hi = min(x.turn for x in seen), max(x.turn for x in seen)
    return Finding(
        kind="axis_changed",
        joint=jn,
        confidence=min(_confidence(x.turn, x.limit) for x in seen),
        detail=(
            f"axis seen from all {len(seen)} IMUs on its link turned {lo:.2f} to {hi:.2f} deg "
            f"(limits {max(x.limit for x in seen):.2f} at most): a bend, or every mount turned alike"
        ),
    )


def _rotated(jn: str, x: _Seen) -> Finding:
    """``imu_rotated`` of the IMU of ``x``."""
    p = x.old.parent_imu
    where = (
        " (a root joint: its axis bending would read the same)"
        if p is None
        else " (its parent link turns about one axis: the joint's axis bending about that axis "
        "would read the same)"
        if x.one_axis
        else ""
    )
    return Finding(
        kind="imu_rotated",
        imu=x.old.imu,
        joint=jn,
        confidence=_confidence(x.turn, x.limit),
        detail=f"axis seen from {x.old.imu} turned {x.turn:.2f} deg (limit {x.limit:.2f}){where}",
    )


def _shifted(old: ImuKinematics, new: ImuKinematics, turned: bool, o: DriftOptions) -> Finding | None:
    """``imu_shifted`` when the lever arm changed beyond its uncertainty (its length only, if turned)."""
    if old.lever_arm is None or new.lever_arm is None or not (old.converged and new.converged):
        return None
    if turned:
        shift = abs(float(np.linalg.norm(new.lever_arm) - np.linalg.norm(old.lever_arm)))
    else:
        shift = float(np.linalg.norm(new.lever_arm - old.lever_arm))
    limit = o.limit(old.lever_arm_std_m, new.lever_arm_std_m, o.floor_m)
    if shift <= limit:
        return None
    return Finding(
        kind="imu_shifted",
        imu=old.imu,
        joint=old.joint,
        confidence=_confidence(shift, limit),
        detail=f"lever arm changed {shift * 1e3:.1f} mm (limit {limit * 1e3:.1f})",
    )
