"""Damage scenarios: change a running simulation's body or sensors and say, as a diff (docs/design.md,
'Diff JSON'), what changed.

Physical damage edits the MuJoCo spec and recompiles with the state kept, so the change shows up in
the physics (and in the ground truth read back from the compiled model):

* ``imu_moved``     the IMU's site moves onto another link's surface;
* ``imu_detached``  the IMU hangs loose on a short tether (a ball-jointed pendulum on its old link);
* ``joint_locked``  an equality constraint holds the joint where it is, while it is still commanded;
* ``link_lost``     the joint's link breaks off: a ball joint after the hinge lets the subtree dangle,
  while the motor and its encoder keep turning.

Sensor damage acts on the readings: ``imu_dead`` (``frozen`` or ``zero`` output) and
``encoder_fault`` (``stuck`` at its current value, a constant ``offset``, or a ``scale``: the encoder
reads ``value`` times the angle, a wrong gear ratio).

Geometry drift keeps the topology and shows only in the kinematics (:mod:`bodyschema.kinematic_drift`),
each with its magnitude (:data:`DRIFT_DAMAGES`):

* ``imu_rotated``   the IMU turns on its mount by ``angle_deg`` about a random axis of its frame (or
  ``about``, a 3-vector in it);
* ``imu_shifted``   the IMU slides on its link by ``meters``, perpendicular to its joint's axis (a slide
  along the axis moves nothing a recording can see);
* ``axis_changed``  the joint's axis bends by ``angle_deg`` towards a random perpendicular (a bent link,
  a loose bearing);
* ``backlash``      a dead band of ``deg`` between the motor, whose encoder is read, and the link the
  IMUs ride: the encoder leads the link by half of it in the direction of motion.

Every call returns a :class:`bodyschema.findings.Diff` with one finding; omitted arguments are picked
with the simulation's damage generator (seeded, reproducible).

The handlers act on a :class:`DamageTarget`, the part of a running simulation damage needs; this
module imports nothing of :mod:`simulators.simulation`, which imports it, so the two form no cycle.

Example
-------
>>> from simulators.simulation import Simulation
>>> sim = Simulation("paper-1", seed=0, imu_model="ideal")
>>> diff = apply_damage(sim, "imu_moved", imu="imu0", to="j5")
>>> diff.to_json()["findings"][0]["to"], sim.truth().imu_joint["imu0"]
('j5', 'j5')
"""

from __future__ import annotations

from typing import Any, Protocol

import mujoco
import numpy as np

from bodyschema.findings import KINEMATIC_KINDS, Diff, Finding
from simulators.builder import LOOSE_PREFIX, surface_frames
from simulators.imu_model import ImuStream
from simulators.robot import Robot

__all__ = ["DAMAGES", "DRIFT_DAMAGES", "DamageTarget", "apply_damage", "parse_damage"]

DAMAGES: tuple[str, ...] = (
    "imu_moved",
    "imu_detached",
    "imu_dead",
    "joint_locked",
    "encoder_fault",
    "link_lost",
)

#: Geometry drift: the topology stays, the kinematics change (see the module docstring); the kinds the
#: geometry's drift check reports.
DRIFT_DAMAGES: tuple[str, ...] = KINEMATIC_KINDS


class DamageTarget(Protocol):
    """What damage acts on: a running simulation (:class:`simulators.simulation.Simulation` is one)."""

    #: The simulated robot; physical damage edits its spec.
    robot: Robot
    #: The IMU readings' stream; ``imu_dead`` kills one of its sensors.
    stream: ImuStream
    #: Picks what the caller left open (seeded, reproducible).
    damage_rng: np.random.Generator
    #: The keywords of the damage being applied (set by :func:`apply_damage`).
    last_kwargs: dict[str, Any]
    #: Joints locked so far.
    locked: set[str]
    #: Joints whose link broke off so far.
    lost: set[str]
    #: Encoder faults so far: joint -> (``stuck``, ``offset``, ``scale`` or ``backlash``, value).
    encoder_faults: dict[str, tuple[str, float]]

    def sync(self) -> None:
        """Bring the physics back to the last returned sample."""

    def recompile(self) -> None:
        """Recompile the robot after a spec edit, keeping the state."""

    def record_damage(self, finding: Finding) -> None:
        """Keep ``finding`` as part of the ground truth."""


def parse_damage(text: str) -> tuple[str, dict[str, Any]]:
    """``KIND[:key=value,...]`` (the CLI form) -> (kind, kwargs); numbers are parsed as floats.

    >>> parse_damage("encoder_fault:joint=j2,mode=offset,value=0.3")
    ('encoder_fault', {'joint': 'j2', 'mode': 'offset', 'value': 0.3})
    """
    kind, _, rest = text.partition(":")
    kind = kind.strip()
    if kind not in _HANDLERS:
        raise ValueError(f"unknown damage {kind!r}; expected one of {', '.join(_HANDLERS)}")
    kw: dict[str, Any] = {}
    for part in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = part.partition("=")
        if not eq:
            raise ValueError(f"damage argument {part!r} is not key=value")
        try:
            kw[key.strip()] = float(value)
        except ValueError:
            kw[key.strip()] = value.strip()
    return kind, kw


def _pick(rng: np.random.Generator, options: list[str], what: str) -> str:
    if not options:
        raise ValueError(f"no {what} to damage")
    return options[int(rng.integers(len(options)))]


def _check(name: str | None, known: tuple[str, ...], what: str) -> None:
    if name is not None and name not in known:
        raise ValueError(f"unknown {what} {name!r}")


def _the_imu(sim: DamageTarget, imu: str | None) -> str:
    """``imu`` checked, or an attached live IMU picked by the damage generator."""
    _check(imu, sim.robot.imu_names, "IMU")
    return imu or _pick(sim.damage_rng, _attached_imus(sim), "IMU")


def _the_joint(sim: DamageTarget, joint: str | None, options: list[str]) -> str:
    """``joint`` checked, or one of ``options`` picked by the damage generator."""
    _check(joint, sim.robot.joint_names, "joint")
    return joint or _pick(sim.damage_rng, options, "joint")


def _joint_body(sim: DamageTarget, joint: str | None) -> str:
    m = sim.robot.model
    if joint is None:
        return "base" if _has_body(m, "base") else m.body(1).name
    return m.body(int(m.jnt_bodyid[m.joint(joint).id])).name


def _has_body(m: mujoco.MjModel, name: str) -> bool:
    try:
        m.body(name)
    except KeyError:
        return False
    return True


def _imu_joint(sim: DamageTarget, imu: str) -> str | None:
    return sim.robot.truth().imu_joint.get(imu)


def _attached_imus(sim: DamageTarget) -> list[str]:
    _, _, detached = sim.robot.truth_arrays()
    dead = {sim.robot.imu_names[k] for k in sim.stream.dead}
    return [n for n, d in zip(sim.robot.imu_names, detached, strict=True) if not d and n not in dead]


def _move_site(sim: DamageTarget, imu: str, body: str, pos: np.ndarray, quat: np.ndarray) -> None:
    spec = sim.robot.spec
    old = spec.site(imu)
    size, rgba = list(old.size), list(old.rgba)
    spec.delete(old)
    spec.body(body).add_site(name=imu, pos=pos.tolist(), quat=quat.tolist(), size=size, rgba=rgba)


def _imu_moved(sim: DamageTarget, imu: str | None = None, to: str | None = None) -> Finding:
    r = sim.robot
    imu = _the_imu(sim, imu)
    src = _imu_joint(sim, imu)
    if "to" not in sim.last_kwargs:
        to = _pick(sim.damage_rng, [j for j in r.joint_names if j != src], "joint")
    elif to in ("", "base", "none"):
        to = None
    _check(to, r.joint_names, "joint")
    if to == src:
        raise ValueError(f"{imu} is already on the link of {to or 'the base'}")
    body = _joint_body(sim, to)
    bid = r.model.body(body).id
    pos, quat = surface_frames(r.model, bid, 8, sim.damage_rng)
    k = int(sim.damage_rng.integers(len(pos)))
    _move_site(sim, imu, body, pos[k], quat[k])
    sim.recompile()
    return Finding(kind="imu_moved", imu=imu, from_=src, to=to)


def _imu_detached(sim: DamageTarget, imu: str | None = None, tether: float = 0.05) -> Finding:
    r = sim.robot
    imu = _the_imu(sim, imu)
    src = _imu_joint(sim, imu)
    m = r.model
    sid = m.site(imu).id
    parent = m.body(int(m.site_bodyid[sid])).name
    spec = r.spec
    site = spec.site(imu)
    pos, quat = np.array(site.pos), np.array(site.quat)
    loose = spec.body(parent).add_body(name=f"{LOOSE_PREFIX}{imu}", pos=pos.tolist(), quat=quat.tolist())
    loose.add_joint(name=f"{LOOSE_PREFIX}{imu}", type=mujoco.mjtJoint.mjJNT_BALL, damping=2e-4, armature=1e-5)
    loose.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.01, 0, 0],
        pos=[0, 0, tether],
        mass=0.02,
        contype=0,
        conaffinity=0,
    )
    _move_site(sim, imu, loose.name, np.array([0.0, 0.0, tether]), np.array([1.0, 0.0, 0.0, 0.0]))
    sim.recompile()
    return Finding(kind="imu_detached", imu=imu, from_=src, detail=f"hangs on a {tether:.3f} m tether")


def _imu_dead(sim: DamageTarget, imu: str | None = None, mode: str = "frozen") -> Finding:
    r = sim.robot
    imu = _the_imu(sim, imu)
    sim.stream.kill(r.imu_names.index(imu), mode)
    return Finding(kind="imu_dead", imu=imu, from_=_imu_joint(sim, imu), detail=mode)


def _movable_joints(sim: DamageTarget) -> list[str]:
    return [j for j in sim.robot.joint_names if j not in sim.locked and j not in sim.lost]


def _joint_locked(sim: DamageTarget, joint: str | None = None) -> Finding:
    r = sim.robot
    joint = _the_joint(sim, joint, _movable_joints(sim))
    q = float(r.q()[r.joint_names.index(joint)])
    data = [q] + [0.0] * 11
    r.spec.add_equality(
        name=f"lock:{joint}",
        type=mujoco.mjtEq.mjEQ_JOINT,
        objtype=mujoco.mjtObj.mjOBJ_JOINT,
        name1=joint,
        data=data,
        solref=[2 * r.model.opt.timestep, 1.0],
        solimp=[0.99, 0.9999, 0.001, 0.5, 2.0],
    )
    sim.locked.add(joint)
    sim.recompile()
    # a seizure stops the joint at once (the constraint alone would let it coast a few ms)
    r.data.qvel[r.dof_adr[r.joint_names.index(joint)]] = 0.0
    return Finding(kind="joint_locked", joint=joint, detail=f"seized at {q:.3f} rad")


def _encoder_fault(
    sim: DamageTarget, joint: str | None = None, mode: str = "stuck", value: float = 0.3
) -> Finding:
    r = sim.robot
    joint = _the_joint(sim, joint, [j for j in r.joint_names if j not in sim.encoder_faults])
    if mode == "stuck":
        value = float(r.q()[r.joint_names.index(joint)])
        detail = f"stuck at {value:.3f} rad"
    elif mode == "offset":
        detail = f"offset by {float(value):.3f} rad"
    elif mode == "scale":
        if not float(value) > 0.0:
            raise ValueError("encoder_fault scale must be positive")
        detail = f"reads {float(value):.4f} times the angle"
    else:
        raise ValueError("encoder_fault mode must be 'stuck', 'offset' or 'scale'")
    sim.encoder_faults[joint] = (mode, float(value))
    return Finding(kind="encoder_fault", joint=joint, detail=detail)


def _link_lost(sim: DamageTarget, joint: str | None = None) -> Finding:
    r = sim.robot
    joint = _the_joint(sim, joint, [j for j in r.joint_names if j not in sim.lost])
    body = _joint_body(sim, joint)
    r.spec.body(body).add_joint(
        name=f"{LOOSE_PREFIX}{joint}", type=mujoco.mjtJoint.mjJNT_BALL, damping=0.01, armature=1e-4
    )
    r.no_gravcomp.update(r.body_names(subtree_of=body))
    sim.lost.add(joint)
    sim.recompile()
    return Finding(kind="link_lost", joint=joint, detail=f"the subtree from {body!r} hangs loose")


def _perpendicular(rng: np.random.Generator, axis: np.ndarray | None) -> np.ndarray:
    """A random unit vector, perpendicular to ``axis`` when one is given."""
    v = rng.normal(size=3)
    if axis is not None:
        a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
        v -= a * float(a @ v)
    return v / np.linalg.norm(v)


def _imu_rotated(
    sim: DamageTarget, imu: str | None = None, angle_deg: float = 2.0, about: Any = None
) -> Finding:
    r = sim.robot
    imu = _the_imu(sim, imu)
    site = r.spec.site(imu)
    turn, quat = np.empty(4), np.empty(4)
    axis = _perpendicular(sim.damage_rng, None) if about is None else np.asarray(about, dtype=float)
    mujoco.mju_axisAngle2Quat(turn, axis / np.linalg.norm(axis), np.radians(float(angle_deg)))
    mujoco.mju_mulQuat(quat, np.asarray(site.quat, dtype=float), turn)
    site.quat = quat
    sim.recompile()
    joint = _imu_joint(sim, imu)
    return Finding(kind="imu_rotated", imu=imu, joint=joint, detail=f"turned {angle_deg:g} deg")


def _imu_shifted(sim: DamageTarget, imu: str | None = None, meters: float = 0.005) -> Finding:
    r = sim.robot
    imu = _the_imu(sim, imu)
    joint = _imu_joint(sim, imu)
    m = r.model
    axis = None
    if joint is not None and int(m.site_bodyid[m.site(imu).id]) == int(m.jnt_bodyid[m.joint(joint).id]):
        axis = np.asarray(r.spec.joint(joint).axis, dtype=float)  # in the body frame, as the site's pos
    site = r.spec.site(imu)
    site.pos = np.asarray(site.pos, dtype=float) + float(meters) * _perpendicular(sim.damage_rng, axis)
    sim.recompile()
    return Finding(kind="imu_shifted", imu=imu, joint=joint, detail=f"slid {1e3 * float(meters):g} mm")


def _axis_changed(sim: DamageTarget, joint: str | None = None, angle_deg: float = 2.0) -> Finding:
    r = sim.robot
    joint = _the_joint(sim, joint, _movable_joints(sim))
    spec_joint = r.spec.joint(joint)
    a = np.asarray(spec_joint.axis, dtype=float)
    a /= np.linalg.norm(a)
    b = _perpendicular(sim.damage_rng, a)
    angle = np.radians(float(angle_deg))
    spec_joint.axis = np.cos(angle) * a + np.sin(angle) * b
    sim.recompile()
    return Finding(kind="axis_changed", joint=joint, detail=f"bent {angle_deg:g} deg")


def _backlash(sim: DamageTarget, joint: str | None = None, deg: float = 1.0) -> Finding:
    r = sim.robot
    joint = _the_joint(sim, joint, [j for j in r.joint_names if j not in sim.encoder_faults])
    if not float(deg) > 0.0:
        raise ValueError("backlash deg must be positive")
    sim.encoder_faults[joint] = ("backlash", float(np.radians(float(deg))))
    return Finding(kind="backlash", joint=joint, detail=f"dead band {float(deg):g} deg")


_HANDLERS = {
    "imu_moved": _imu_moved,
    "imu_detached": _imu_detached,
    "imu_dead": _imu_dead,
    "joint_locked": _joint_locked,
    "encoder_fault": _encoder_fault,
    "link_lost": _link_lost,
    "imu_rotated": _imu_rotated,
    "imu_shifted": _imu_shifted,
    "axis_changed": _axis_changed,
    "backlash": _backlash,
}


def apply_damage(sim: DamageTarget, kind: str, **kwargs: Any) -> Diff:
    """Apply damage ``kind`` to ``sim`` now; return its ground-truth diff (also kept by ``sim``)."""
    if kind not in _HANDLERS:
        raise ValueError(f"unknown damage {kind!r}; expected one of {', '.join(_HANDLERS)}")
    sim.sync()  # act at the last returned sample, not at the end of any read-ahead
    sim.last_kwargs = dict(kwargs)
    try:
        finding = _HANDLERS[kind](sim, **kwargs)
    except TypeError as err:
        raise ValueError(f"bad arguments for {kind}: {err}") from err
    sim.record_damage(finding)
    return Diff(findings=(finding,))
