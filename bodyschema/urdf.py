"""The learned body as a URDF: links, revolute joints with the learned axes, IMUs as fixed frames.

Frames (docs/kinematics.md): each joint's child link takes the orientation of its reference IMU
(:class:`bodyschema.kinematics.JointKinematics`) and its origin at the foot of that IMU's lever arm on
the joint axis, so the joint origin lies on the axis, the URDF ``axis`` is the learned one and the IMU
sits at ``xyz`` = its lever arm. A child joint's origin in its parent link is the axis foot seen from
the parent's reference IMU plus that IMU's own lever arm; its rotation is the learned rotation between
the two IMUs at ``q = 0``.

What the data cannot fix is set by convention and says so in an XML comment next to it: the base frame
(z up from gravity, yaw and the root joints' positions unobservable from a fixed base), positions
along each joint axis, turns a recording left undetermined (under a link that turned about one axis
only), and masses (the URDF needs them; the data say nothing about them). Joint limits
are the range of ``q`` the recording visited.

Example
-------
>>> import numpy as np
>>> from bodyschema.kinematics import ImuKinematics, JointKinematics, Kinematics
>>> from bodyschema.topology import Topology
>>> imu = ImuKinematics("imu1", "j1", axis=np.array([0.0, 0, 1]), lever_arm=np.array([0.1, 0, 0]),
...                     up_at_zero=np.array([0.0, 0, 9.81]), converged=True)
>>> kin = Kinematics({"imu1": imu}, {"j1": JointKinematics("j1", None, ("imu1",), "imu1")}, (), 10.0,
...                  0.0, 100, Topology({"j1": None}, {"imu1": "j1"}))
>>> xml = to_urdf(kin, "demo")
>>> xml.count("<joint "), 'type="revolute"' in xml
(2, True)
"""

from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from bodyschema.kinematics import ImuKinematics, Kinematics

__all__ = ["to_urdf"]

#: Placeholder inertia of every link: URDF consumers (MuJoCo) refuse massless moving bodies.
_MASS, _INERTIA = 0.1, 1e-4


def _f(x: float) -> str:
    return f"{float(x):.6g}"


def _xyz(v: np.ndarray) -> str:
    return " ".join(_f(x) for x in v)


def _rpy(R: np.ndarray) -> str:
    """URDF roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll), scipy's extrinsic "xyz"."""
    return _xyz(Rotation.from_matrix(R).as_euler("xyz"))


def _tilt(up: np.ndarray | None) -> np.ndarray:
    """The smallest rotation taking the measured 'up' (specific force at rest) to +z."""
    if up is None or not np.linalg.norm(up) > 0:
        return np.eye(3)
    a = up / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return Rotation.from_rotvec(v / np.linalg.norm(v) * math.atan2(np.linalg.norm(v), c)).as_matrix()


def _inertial() -> list[str]:
    return [
        "    <!-- placeholder inertia: masses are not observed -->",
        f'    <inertial><mass value="{_MASS}"/><inertia ixx="{_INERTIA}" iyy="{_INERTIA}" izz="{_INERTIA}"'
        ' ixy="0" ixz="0" iyz="0"/></inertial>',
    ]


def _link(name: str) -> list[str]:
    return [f"  <link name={quoteattr(name)}>", *_inertial(), "  </link>"]


def to_urdf(kin: Kinematics, name: str = "robot") -> str:
    """The URDF XML of ``kin`` (see the module docstring for frames and conventions)."""
    out = [
        '<?xml version="1.0"?>',
        "<!-- learned from IMU and encoder data by bodyhealth kinematics (docs/kinematics.md) -->",
        f"<robot name={quoteattr(name)}>",
        *_link("base"),
    ]
    link = {j: f"{j}_link" for j in kin.joints}
    for jn in kin.joints:
        out += _joint(kin, jn, link)
    for imu in kin.imus:
        out += _imu_mount(kin, imu, link)
    out.append("</robot>")
    return "\n".join(out) + "\n"


def _ref(kin: Kinematics, j: str | None) -> ImuKinematics | None:
    """The reference IMU of joint ``j``'s link, None when it has none."""
    if j is None or j not in kin.joints or kin.joints[j].ref_imu is None:
        return None
    return kin.imus[kin.joints[j].ref_imu]  # type: ignore[index]


def _joint(kin: Kinematics, jn: str, link: dict[str, str]) -> list[str]:
    """Joint ``jn``'s child link and its revolute joint, with notes on what is placeholder."""
    jk = kin.joints[jn]
    me = _ref(kin, jn)
    notes: list[str] = []
    if me is None or me.axis is None:
        axis = np.array([0.0, 0.0, 1.0])
        notes.append("axis not observed (no fitted IMU on this link): placeholder z")
    else:
        axis = me.axis
    xyz, R = _joint_origin(kin, jn, me, notes)
    lo, hi = jk.q_range
    if not hi - lo > 1e-6:  # a joint that never moved: a valid (non-empty) range around where it stood
        lo, hi = lo - 1e-3, hi + 1e-3
    return [
        *_link(link[jn]),
        *(f"  <!-- {n} -->" for n in notes),
        f'  <joint name={quoteattr(jn)} type="revolute">',
        f"    <parent link={quoteattr(link.get(jk.parent, 'base') if jk.parent else 'base')}/>",
        f"    <child link={quoteattr(link[jn])}/>",
        f'    <origin xyz="{_xyz(xyz)}" rpy="{_rpy(R)}"/>',
        f'    <axis xyz="{_xyz(axis)}"/>',
        "    <!-- limits: the range the recording visited, not the mechanism's -->",
        f'    <limit lower="{_f(lo)}" upper="{_f(hi)}" effort="0" velocity="0"/>',
        "  </joint>",
    ]


def _joint_origin(
    kin: Kinematics, jn: str, me: ImuKinematics | None, notes: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """Joint ``jn``'s origin in its parent link (position, rotation); adds how it was found to ``notes``."""
    jk = kin.joints[jn]
    parent = _ref(kin, jk.parent)
    if jk.parent is None:
        notes.append(
            "origin by convention: a fixed base does not show where the joint is or its yaw; "
            "tilt from gravity at q = 0 (accelerometer bias included)"
        )
        return np.zeros(3), _tilt(None if me is None else me.up_at_zero)
    if parent is None or me is None or me.joint_origin_in_parent is None:
        notes.append("origin not observed: identity placeholder")
        return np.zeros(3), np.eye(3)
    lever_p = parent.lever_arm if parent.lever_arm is not None else np.zeros(3)
    xyz = me.joint_origin_in_parent + lever_p
    R = me.rotation_from_parent.T if me.rotation_from_parent is not None else np.eye(3)
    notes.append("origin along the parent's axis by convention (at the foot of its IMU's lever arm)")
    if me.undetermined:
        notes.append(
            f"origin turned about the parent link's one axis by an undetermined angle (std "
            f"{me.turn_about_parent_std_deg:.1f} deg): any turn fits the data alike"
        )
    return xyz, R


def _imu_mount(kin: Kinematics, imu: str, link: dict[str, str]) -> list[str]:
    """IMU ``imu``'s link and the fixed joint that mounts it on its joint's link."""
    ik = kin.imus[imu]
    j = kin.topology.imu_joint.get(imu)
    parent_link = link.get(j, "base") if j is not None else "base"
    jr = _ref(kin, j)
    same = {s.b: s for s in kin.same_link}
    if j is None:
        xyz, R = np.zeros(3), np.eye(3)
        note = "on the base: pose not observable from a fixed base"
    elif jr is not None and jr.imu == imu:
        xyz, R = (ik.lever_arm if ik.lever_arm is not None else np.zeros(3)), np.eye(3)
        note = "the link's reference IMU: its frame is the link's, at its lever arm from the axis"
    elif imu in same:
        R = same[imu].rotation
        xyz = R @ ik.lever_arm if ik.lever_arm is not None else np.zeros(3)
        note = "rotation from the gyros; position along the axis unobservable: the axis foot's"
        if same[imu].rank < 2:
            note += "; the turn about the link's one axis undetermined (the link turned about it only)"
    else:
        xyz, R = np.zeros(3), np.eye(3)
        note = "pose not observed: identity placeholder"
    return [
        *_link(imu),
        f"  <!-- {note} -->",
        f'  <joint name={quoteattr(imu + "_mount")} type="fixed">',
        f"    <parent link={quoteattr(parent_link)}/>",
        f"    <child link={quoteattr(imu)}/>",
        f'    <origin xyz="{_xyz(xyz)}" rpy="{_rpy(R)}"/>',
        "  </joint>",
    ]
