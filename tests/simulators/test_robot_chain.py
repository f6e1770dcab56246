"""The product-of-exponentials model of the catalog robots against MuJoCo."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simulators.robot import Robot
from simulators.robot_chain import robot_chain


@pytest.mark.parametrize("name", ["ur5e", "paper-2", "paper-5", "dual-arm"])
def test_the_chain_predicts_what_mujoco_computes_at_any_state(name: str, rng: np.random.Generator) -> None:
    robot = Robot.from_catalog(name)
    chain = robot_chain(robot)
    m, d = robot.model, mujoco.MjData(robot.model)
    v = np.zeros(6)
    for _ in range(3):
        q, qd = rng.uniform(-1.5, 1.5, robot.n_joints), rng.normal(0.0, 1.0, robot.n_joints)
        d.qpos[:] = m.qpos0
        d.qpos[robot.qpos_adr] = q
        d.qvel[:] = 0.0
        d.qvel[robot.dof_adr] = qd
        mujoco.mj_forward(m, d)
        R, p, omega = chain.motion(q[None], qd[None])
        for k, s in enumerate(robot.site_ids):
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, int(s), v, 1)
            assert np.abs(p[0, k] - d.site_xpos[s]).max() < 1e-12
            assert np.abs(R[0, k] - d.site_xmat[s].reshape(3, 3)).max() < 1e-12
            assert np.abs(omega[0, k] - v[:3]).max() < 1e-12


_FLOATING = """<mujoco><worldbody><body name="base"><freejoint/><geom size="0.1"/>
<body name="leg" pos="0 0 -0.2"><joint name="hip" type="hinge" axis="0 1 0"/><geom size="0.05"/>
<site name="imu0"/></body></body></worldbody>
<sensor><accelerometer name="imu0:acc" site="imu0"/><gyro name="imu0:gyro" site="imu0"/></sensor></mujoco>"""


def test_a_floating_base_has_no_chain() -> None:
    robot = Robot(mujoco.MjSpec.from_string(_FLOATING), name="floating")
    with pytest.raises(ValueError, match="floating base"):
        robot_chain(robot)
