"""Instrumenting models people already have (MJCF, URDF) and simulating them."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simulators.builder import instrument, load_spec
from simulators.robot import Robot
from simulators.simulation import simulate

MJCF = """
<mujoco model="arm">
  <worldbody>
    <body name="upper" pos="0 0 0.1">
      <joint name="shoulder" type="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      <body name="fore" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="box" size="0.12 0.03 0.02" pos="0.12 0 0"/>
        <body name="hand" pos="0.26 0 0">
          <joint type="hinge" axis="1 0 0"/>
          <geom type="sphere" size="0.04"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

URDF = """<?xml version="1.0"?>
<robot name="twolink">
  <link name="base"><inertial><mass value="2"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><box size="0.2 0.2 0.05"/></geometry></collision></link>
  <link name="l1"><inertial><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/>
      <geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <link name="l2"><inertial><mass value="0.5"/>
    <inertia ixx="0.005" iyy="0.005" izz="0.005" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.1"/>
      <geometry><cylinder radius="0.025" length="0.2"/></geometry></collision></link>
  <joint name="a" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <joint name="b" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="5"/></joint>
</robot>
"""


def test_instrument_mjcf_all_bodies_on_their_surfaces(tmp_path) -> None:
    path = tmp_path / "arm.xml"
    path.write_text(MJCF)
    spec = load_spec(path)
    names = instrument(spec, per_link=4, seed=3)
    assert names == [f"imu{i}" for i in range(12)]
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    # the sphere's IMUs lie on the sphere, z pointing away from its centre
    hand = m.body("hand").id
    for s in range(m.nsite):
        if m.site_bodyid[s] == hand:
            rel = d.site_xpos[s] - d.xpos[hand]
            assert np.linalg.norm(rel) == pytest.approx(0.04, abs=1e-9)
            assert np.allclose(d.site_xmat[s].reshape(3, 3)[:, 2], rel / 0.04, atol=1e-9)
    # the box's IMUs lie on a face with z along its normal
    fore = m.body("fore").id
    g = next(i for i in range(m.ngeom) if m.geom_bodyid[i] == fore)
    for s in range(m.nsite):
        if m.site_bodyid[s] == fore:
            local = d.geom_xmat[g].reshape(3, 3).T @ (d.site_xpos[s] - d.geom_xpos[g])
            z = d.geom_xmat[g].reshape(3, 3).T @ d.site_xmat[s].reshape(3, 3)[:, 2]
            ax = int(np.argmax(np.abs(z)))
            assert abs(z[ax]) == pytest.approx(1.0)
            assert local[ax] * z[ax] == pytest.approx(m.geom_size[g][ax])
    assert m.nsensor == 24 and m.nu == 9  # 3 joints x (torque, pos, vel)


def test_instrument_chosen_bodies_only(tmp_path) -> None:
    path = tmp_path / "arm.xml"
    path.write_text(MJCF)
    spec = load_spec(path)
    instrument(spec, bodies=["fore"], per_link=3)
    robot = Robot(spec)
    assert set(robot.truth().imu_joint.values()) == {"elbow"}
    with pytest.raises(ValueError):
        instrument(load_spec(path), bodies=["nope"])


def test_simulate_a_urdf_file(tmp_path, seed: int) -> None:
    path = tmp_path / "twolink.urdf"
    path.write_text(URDF)
    rec = simulate(str(path), seconds=0.5, seed=seed, imu_model="ideal")
    assert rec.joint_names == ("a", "b")
    assert rec.truth_joint_parent == ("", "a")
    assert set(rec.truth_imu_joint) == {"a", "b"}
    assert rec.n_imus == 4  # 2 IMUs on each body with geometry
    assert np.abs(rec.gyro).max() > 0.01


def test_unreadable_model_is_a_clear_error(tmp_path) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><geom type='nope'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="cannot load"):
        load_spec(bad)
