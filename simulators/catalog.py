"""The robots the CLI, the farm and the tests know by name.

``paper-1`` … ``paper-6``: six 5-joint topologies (serial and branching) with 12 IMUs per link, like
the paper's simulated experiment. ``ur5e``: Universal Robots' published DH parameters and link masses
with 2 IMUs per link. ``quadruped``: a torso and four 3-joint legs. ``humanoid``: 26 joints (legs,
waist, neck, arms). ``dual-arm``: two 6-joint arms on a rotating torso. All have a fixed base.

Example
-------
>>> sorted(CATALOG)[:3]
['dual-arm', 'humanoid', 'paper-1']
>>> describe("paper-3").n_joints, describe("paper-3").n_imus
(5, 60)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import mujoco
import numpy as np

from simulators.builder import build_spec
from simulators.description import LinkSpec, RobotDescription

__all__ = ["CATALOG", "PAPER_TOPOLOGIES", "build", "describe"]

#: Parent of each joint j1..j5 (0 = the base) of the six paper robots.
PAPER_TOPOLOGIES: dict[str, tuple[int, ...]] = {
    "paper-1": (0, 1, 2, 3, 4),  # serial chain
    "paper-2": (0, 1, 2, 1, 4),  # two branches of two
    "paper-3": (0, 1, 2, 2, 2),  # a hub carrying three
    "paper-4": (0, 1, 0, 3, 4),  # two chains on the base
    "paper-5": (0, 1, 2, 3, 1),  # a long chain and a short branch
    "paper-6": (0, 1, 1, 1, 4),  # three branches, one of them two long
}


def _rx(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0)


def _ry(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


def _rz(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))


def _qmul(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    return (float(out[0]), float(out[1]), float(out[2]), float(out[3]))


# --------------------------------------------------------------------------- paper robots
_AXES = ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
_LENGTHS = (0.25, 0.22, 0.2, 0.18, 0.16)
_MASSES = (1.0, 0.8, 0.6, 0.45, 0.35)


def _paper(name: str) -> RobotDescription:
    parents = PAPER_TOPOLOGIES[name]
    n = len(parents)
    depth = [0] * n
    for i, p in enumerate(parents):
        depth[i] = 0 if p == 0 else depth[p - 1] + 1
    children = {i: [c for c in range(n) if parents[c] == i + 1] for i in range(-1, n)}
    roots = [c for c in range(n) if parents[c] == 0]

    def make(i: int, pos: tuple[float, float, float], quat: tuple[float, ...]) -> LinkSpec:
        length = _LENGTHS[depth[i]]
        kids = children[i]
        specs = []
        for c_idx, c in enumerate(kids):
            spread = 0.0 if len(kids) == 1 else (-0.8 + 1.6 * c_idx / (len(kids) - 1))
            q = _qmul(_rz(math.pi / 2 * (1 + c_idx)), _rx(spread + 0.5))
            specs.append(make(c, (0.0, 0.0, length), q))
        return LinkSpec(
            name=f"link{i + 1}",
            joint=f"j{i + 1}",
            axis=_AXES[(i + depth[i]) % 3],
            pos=pos,
            quat=tuple(quat),  # type: ignore[arg-type]
            end=(0.0, 0.0, length),
            radius=0.03,
            mass=_MASSES[depth[i]],
            children=tuple(specs),
        )

    links = []
    for r_idx, r in enumerate(roots):
        x = 0.0 if len(roots) == 1 else -0.06 + 0.12 * r_idx / (len(roots) - 1)
        tilt = 0.0 if len(roots) == 1 else (-0.4 + 0.8 * r_idx / (len(roots) - 1))
        links.append(make(r, (x, 0.0, 0.0), _ry(tilt)))
    return RobotDescription(
        name=name,
        links=tuple(links),
        imus_per_link=12,
        seed=sum(map(ord, name)),
        summary=f"5 joints, parents {parents}, 12 IMUs per link",
    )


# --------------------------------------------------------------------------- UR5e from DH
UR5E_DH = {
    "d": (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    "a": (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    "alpha": (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0),
    "mass": (3.761, 8.058, 2.846, 1.37, 1.3, 0.365),
}
_UR_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
_UR_RADII = (0.06, 0.054, 0.04, 0.035, 0.035, 0.03)


def _ur_chain(prefix: str, pos: tuple[float, float, float], quat: tuple[float, ...], imus: int) -> LinkSpec:
    """Standard DH: joint i turns about its link's z; the next frame is Tz(d) Tx(a) Rx(alpha) away."""
    link: LinkSpec | None = None
    for i in reversed(range(6)):
        d, a, alpha = UR5E_DH["d"][i], UR5E_DH["a"][i], UR5E_DH["alpha"][i]
        kids = () if link is None else (replace(link, pos=(a, 0.0, d), quat=_rx(alpha)),)
        link = LinkSpec(
            name=f"{prefix}{_UR_JOINTS[i]}_link",
            joint=f"{prefix}{_UR_JOINTS[i]}",
            axis=(0.0, 0.0, 1.0),
            end=(a, 0.0, d),
            radius=_UR_RADII[i],
            mass=UR5E_DH["mass"][i],
            imus=imus,
            range=(-2 * math.pi, 2 * math.pi),
            children=kids,
        )
    assert link is not None
    return replace(link, pos=pos, quat=tuple(quat))


def _ur5e() -> RobotDescription:
    return RobotDescription(
        name="ur5e",
        links=(_ur_chain("", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 2),),
        imus_per_link=2,
        base_half_size=(0.075, 0.075, 0.02),
        base_mass=4.0,
        damping=0.5,
        armature=0.1,
        seed=5,
        summary="Universal Robots UR5e from published DH parameters and masses, 2 IMUs per link",
    )


# --------------------------------------------------------------------------- legged / humanoid
def _quadruped() -> RobotDescription:
    legs = []
    for tag, x, y in (("fl", 0.22, 0.1), ("fr", 0.22, -0.1), ("hl", -0.22, 0.1), ("hr", -0.22, -0.1)):
        knee = LinkSpec(
            f"{tag}_shank",
            f"{tag}_knee",
            axis=(0, 1, 0),
            pos=(0, 0, -0.22),
            end=(0, 0, -0.22),
            radius=0.02,
            mass=0.25,
            range=(-2.6, -0.2),
        )
        side = math.copysign(0.05, y)
        thigh = LinkSpec(
            f"{tag}_thigh",
            f"{tag}_hip_flex",
            axis=(0, 1, 0),
            pos=(0, side, 0),
            end=(0, 0, -0.22),
            radius=0.03,
            mass=1.0,
            range=(-1.5, 1.5),
            children=(knee,),
        )
        hip = LinkSpec(
            f"{tag}_hip",
            f"{tag}_hip_abd",
            axis=(1, 0, 0),
            pos=(x, y, 0),
            end=(0, math.copysign(0.05, y), 0),
            radius=0.04,
            mass=0.6,
            range=(-0.8, 0.8),
            children=(thigh,),
        )
        legs.append(hip)
    return RobotDescription(
        name="quadruped",
        links=tuple(legs),
        imus_per_link=2,
        base_imus=2,
        base_half_size=(0.3, 0.15, 0.06),
        base_mass=8.0,
        damping=0.2,
        armature=0.02,
        seed=7,
        summary="a torso and 4 legs x 3 joints, 2 IMUs per link and on the torso",
    )


def _chain(specs: list[dict[str, object]]) -> LinkSpec:
    """Links each mounted at the previous one's end (unless it gives ``pos``)."""
    link: LinkSpec | None = None
    for i in reversed(range(len(specs))):
        s = dict(specs[i])
        if link is not None:
            s["children"] = (*s.get("children", ()), link)  # type: ignore[misc]
        link = LinkSpec(**s)  # type: ignore[arg-type]
        if i > 0:
            prev_end = specs[i - 1].get("end", (0.0, 0.0, 0.2))
            if "pos" not in specs[i]:
                link = replace(link, pos=prev_end)
    assert link is not None
    return link


#: The humanoid's limbs, outward from the trunk, one link a row: (link, joint, axis, end, radius, mass,
#: range). Link and joint names take the side ("l_", "r_") in front; the first link's ``pos`` is the side's.
_HUMANOID_LEG: tuple[tuple, ...] = (
    ("hip_yaw_link", "hip_yaw", (0, 0, 1), (0, 0, -0.06), 0.04, 1.0, (-0.7, 0.7)),
    ("hip_roll_link", "hip_roll", (1, 0, 0), (0, 0, -0.06), 0.04, 1.0, (-0.5, 0.5)),
    ("thigh", "hip_pitch", (0, 1, 0), (0, 0, -0.4), 0.055, 4.0, (-1.6, 1.0)),
    ("shank", "knee", (0, 1, 0), (0, 0, -0.4), 0.045, 2.5, (0.0, 2.4)),
    ("ankle_link", "ankle_pitch", (0, 1, 0), (0, 0, -0.04), 0.035, 0.4, (-0.8, 0.8)),
    ("foot", "ankle_roll", (1, 0, 0), (0.15, 0, 0), 0.03, 0.6, (-0.4, 0.4)),
)
#: The arm; its first link's end points outward, to the side's y (given here for the left).
_HUMANOID_ARM: tuple[tuple, ...] = (
    ("shoulder_link", "shoulder_pitch", (0, 1, 0), (0, 0.06, 0), 0.04, 0.8, (-2.5, 2.5)),
    ("shoulder_roll_link", "shoulder_roll", (1, 0, 0), (0, 0, -0.05), 0.04, 0.6, (-1.5, 1.5)),
    ("upper_arm", "shoulder_yaw", (0, 0, 1), (0, 0, -0.28), 0.04, 1.5, (-1.5, 1.5)),
    ("forearm", "elbow", (0, 1, 0), (0, 0, -0.25), 0.035, 1.0, (-2.4, 0.0)),
    ("hand", "wrist_yaw", (0, 0, 1), (0, 0, -0.08), 0.03, 0.4, (-1.5, 1.5)),
)
#: Neck and head, then waist and chest (the chest carries the head and both arms).
_HUMANOID_HEAD: tuple[tuple, ...] = (
    ("neck", "neck_yaw", (0, 0, 1), (0, 0, 0.06), 0.03, 0.4, (-1.2, 1.2)),
    ("head", "neck_pitch", (0, 1, 0), (0, 0, 0.14), 0.08, 3.0, (-0.6, 0.6)),
)
_HUMANOID_TORSO: tuple[tuple, ...] = (
    ("waist", "waist_yaw", (0, 0, 1), (0, 0, 0.08), 0.08, 3.0, (-1.0, 1.0)),
    ("chest", "waist_pitch", (0, 1, 0), (0, 0, 0.32), 0.12, 10.0, (-0.5, 0.8)),
)


def _limb(
    rows: tuple[tuple, ...], pos: tuple[float, float, float], prefix: str = ""
) -> list[dict[str, object]]:
    """The :func:`_chain` specs of a table of links, the first at ``pos``, names after ``prefix``."""
    specs: list[dict[str, object]] = [
        dict(
            name=f"{prefix}{link}", joint=f"{prefix}{joint}", axis=axis, end=end, radius=r, mass=m, range=rng
        )
        for link, joint, axis, end, r, m, rng in rows
    ]
    specs[0]["pos"] = pos
    return specs


def _humanoid() -> RobotDescription:
    def leg(side: str, y: float) -> LinkSpec:
        return _chain(_limb(_HUMANOID_LEG, (0, y, -0.06), f"{side}_"))

    def arm(side: str, y: float) -> LinkSpec:
        sgn = 1.0 if y > 0 else -1.0
        specs = _limb(_HUMANOID_ARM, (0, y, 0.26), f"{side}_")
        specs[0]["end"] = (0, sgn * 0.06, 0)
        return _chain(specs)

    head = _chain(_limb(_HUMANOID_HEAD, (0, 0, 0.32)))
    torso_specs = _limb(_HUMANOID_TORSO, (0, 0, 0.02))
    torso_specs[1]["children"] = (head, arm("l", 0.2), arm("r", -0.2))
    torso = _chain(torso_specs)
    return RobotDescription(
        name="humanoid",
        links=(leg("l", 0.1), leg("r", -0.1), torso),
        imus_per_link=2,
        base_imus=2,
        base_half_size=(0.1, 0.15, 0.06),
        base_mass=8.0,
        damping=0.3,
        armature=0.02,
        seed=11,
        summary="26 joints: legs (6 each), waist (2), neck (2), arms (5 each); fixed pelvis",
    )


def _dual_arm() -> RobotDescription:
    left = _ur_chain("l_", (0.0, 0.2, 0.45), _rx(-math.pi / 2), 2)
    right = _ur_chain("r_", (0.0, -0.2, 0.45), _rx(math.pi / 2), 2)
    torso = LinkSpec(
        "torso",
        "torso_yaw",
        axis=(0, 0, 1),
        end=(0, 0, 0.45),
        radius=0.1,
        mass=15.0,
        range=(-3.0, 3.0),
        children=(left, right),
    )
    return RobotDescription(
        name="dual-arm",
        links=(torso,),
        imus_per_link=2,
        base_imus=0,
        base_half_size=(0.2, 0.2, 0.05),
        base_mass=30.0,
        damping=0.5,
        armature=0.1,
        seed=13,
        summary="two 6-joint UR5e-like arms on a rotating torso, 2 IMUs per link",
    )


CATALOG: dict[str, Callable[[], RobotDescription]] = {
    **{name: (lambda n=name: _paper(n)) for name in PAPER_TOPOLOGIES},
    "ur5e": _ur5e,
    "quadruped": _quadruped,
    "humanoid": _humanoid,
    "dual-arm": _dual_arm,
}


def describe(name: str) -> RobotDescription:
    """The description of catalog robot ``name``; ``ValueError`` listing the names when unknown."""
    try:
        return CATALOG[name]()
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; catalog: {', '.join(CATALOG)}") from None


def build(name: str) -> mujoco.MjSpec:
    """The (uncompiled) MuJoCo spec of catalog robot ``name``."""
    return build_spec(describe(name))
