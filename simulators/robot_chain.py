"""The product-of-exponentials model of a simulated robot (:class:`bodyschema.forward_kinematics.RobotChain`).

Read off the compiled MuJoCo model at its reference pose (``qpos0``): each robot joint's world axis
and anchor, each IMU site's world pose, and which robot joint moves each site's body. This is the
model a user of the simulator holds; the sensor discrepancy analysis for robots with encoders compares
what it predicts with what the IMUs read.

Example
-------
>>> from simulators.robot import Robot
>>> chain = robot_chain(Robot.from_catalog("ur5e"))
>>> len(chain.joint_names), len(chain.imu_names), chain.parent[:3]
(6, 12, (None, 0, 1))
"""

from __future__ import annotations

import mujoco
import numpy as np

from bodyschema.forward_kinematics import RobotChain
from simulators.robot import Robot, truth_from_model

__all__ = ["robot_chain"]


def robot_chain(robot: Robot) -> RobotChain:
    """The robot's joints and IMUs at its reference pose. Only fixed-base robots of hinge joints have
    one: a floating base moves with no encoder, a slide joint has no axis to turn about."""
    m = robot.model
    for name in robot.joint_names:
        if mujoco.mjtJoint(int(m.jnt_type[m.joint(name).id])) != mujoco.mjtJoint.mjJNT_HINGE:
            raise ValueError(
                f"{robot.name}: joint {name!r} is not a hinge; the encoder model needs revolute joints"
            )
    for j in range(m.njnt):
        if mujoco.mjtJoint(int(m.jnt_type[j])) == mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(f"{robot.name} has a floating base: its motion is not in the encoders")
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    mujoco.mj_kinematics(m, d)
    parents, imu_joint, _ = truth_from_model(m, robot.joint_names, robot.imu_names)
    index = {n: i for i, n in enumerate(robot.joint_names)}
    jid = [m.joint(n).id for n in robot.joint_names]
    sid = [m.site(n).id for n in robot.imu_names]
    axis = np.array([d.xaxis[j] / np.linalg.norm(d.xaxis[j]) for j in jid])
    return RobotChain(
        joint_names=tuple(robot.joint_names),
        parent=tuple(None if parents[n] is None else index[parents[n]] for n in robot.joint_names),
        axis=axis,
        point=np.array([d.xanchor[j] for j in jid]),
        imu_names=tuple(robot.imu_names),
        imu_joint=tuple(None if imu_joint.get(k) is None else index[imu_joint[k]] for k in robot.imu_names),
        imu_R=np.array([d.site_xmat[s].reshape(3, 3) for s in sid]),
        imu_p=np.array([d.site_xpos[s] for s in sid]),
        zero=np.array([m.qpos0[m.jnt_qposadr[j]] for j in jid]),
    )
