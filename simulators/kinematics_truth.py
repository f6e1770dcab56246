"""The true joint axes and IMU lever arms of a simulated robot, in each IMU's own frame.

What :func:`bodyschema.kinematics.estimate_kinematics` estimates, read from the compiled MuJoCo model:
for an IMU site whose link is moved by joint ``j``, the joint's world axis ``xaxis`` and anchor
``xanchor`` and the site's pose give the axis in the site frame, ``u = Rᵀ xaxis``, and the
perpendicular lever arm ``r = (I - u uᵀ) Rᵀ (site_xpos - xanchor)``. Both are constant in the site
frame, so any pose of the robot gives them. MuJoCo's IMU sensors read in the site frame, which is
therefore the truth an estimate is compared with.

Example
-------
>>> from simulators.robot import Robot
>>> truth = kinematics_truth(Robot.from_catalog("paper-1"))
>>> sorted(truth)[:2], round(float(np.linalg.norm(truth["imu1"].axis)), 6)
(['imu0', 'imu1'], 1.0)
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from bodyschema.kinematics import ImuKinematics, SameLink, project_rotation, rotation_about
from simulators.robot import Robot, truth_from_model

__all__ = [
    "ImuTruth",
    "axis_error_deg",
    "kinematics_truth",
    "rotation_from_parent_error_deg",
    "same_link_error_deg",
]


@dataclass(frozen=True)
class ImuTruth:
    """One IMU's joint, that joint's unit axis and the IMU's lever arm (m), in the IMU frame."""

    joint: str | None
    axis: np.ndarray | None
    lever_arm: np.ndarray | None


def kinematics_truth(robot: Robot) -> dict[str, ImuTruth]:
    """Per IMU: the joint that moves its link, the axis and the perpendicular lever arm (site frame)."""
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.data.qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    _, imu_joint, _ = truth_from_model(m, robot.joint_names, robot.imu_names)
    out: dict[str, ImuTruth] = {}
    for imu in robot.imu_names:
        jn = imu_joint.get(imu)
        if jn is None:
            out[imu] = ImuTruth(joint=None, axis=None, lever_arm=None)
            continue
        s, j = m.site(imu).id, m.joint(jn).id
        R = d.site_xmat[s].reshape(3, 3)
        u = R.T @ d.xaxis[j]
        u /= np.linalg.norm(u)
        rel = R.T @ (d.site_xpos[s] - d.xanchor[j])
        out[imu] = ImuTruth(joint=jn, axis=u, lever_arm=rel - u * float(u @ rel))
    return out


def axis_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit axes, degrees (signs count: a flipped axis is 180° off)."""
    c = float(np.clip(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))
    return float(np.degrees(np.arccos(c)))


def _site_frames(robot: Robot) -> tuple[mujoco.MjData, dict[str, np.ndarray]]:
    """The model at the robot's current pose and every IMU site's frame (3×3, site to world)."""
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.data.qpos
    mujoco.mj_kinematics(m, d)
    return d, {n: d.site_xmat[m.site(n).id].reshape(3, 3).copy() for n in robot.imu_names}


def rotation_from_parent_error_deg(robot: Robot, k: ImuKinematics) -> float:
    """How far ``k.rotation_from_parent`` (with ``k.axis`` and the joint's angle) is from the simulator's
    relative site pose at the robot's current pose: the rotation angle of the difference, degrees."""
    d, frames = _site_frames(robot)
    q = float(d.qpos[robot.model.jnt_qposadr[robot.model.joint(k.joint).id]])
    predicted = rotation_about(k.axis, np.array([-q]))[0] @ k.rotation_from_parent  # type: ignore[arg-type]
    return _angle_deg(predicted @ (frames[k.imu].T @ frames[k.parent_imu]).T)  # type: ignore[index]


def same_link_error_deg(robot: Robot, s: SameLink) -> float:
    """How far a same-link rotation (``b``'s frame into ``a``'s) is from the simulator's, degrees."""
    _, frames = _site_frames(robot)
    return _angle_deg(s.rotation @ (frames[s.a].T @ frames[s.b]).T)


def _angle_deg(R: np.ndarray) -> float:
    """The rotation angle of a near-rotation ``R`` (projected onto the rotations first), degrees."""
    c = (float(np.trace(project_rotation(R))) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
