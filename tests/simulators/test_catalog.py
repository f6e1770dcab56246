"""Every catalog robot compiles, runs cleanly, and its ground truth is what the compiled model says."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simulators.catalog import CATALOG, PAPER_TOPOLOGIES, build, describe
from simulators.excitation import make_excitation
from simulators.robot import Robot

NAMES = list(CATALOG)


def _parent_joint_via_bodies(m: mujoco.MjModel) -> dict[str, str | None]:
    """Independent reading: every catalog body has at most one joint; walk body_parentid."""
    joint_of_body = {int(m.jnt_bodyid[j]): m.joint(j).name for j in range(m.njnt)}
    assert len(joint_of_body) == m.njnt, "catalog bodies carry one joint each"
    out: dict[str, str | None] = {}
    for j in range(m.njnt):
        b = int(m.body_parentid[m.jnt_bodyid[j]])
        while b != 0 and b not in joint_of_body:
            b = int(m.body_parentid[b])
        out[m.joint(j).name] = joint_of_body.get(b)
    return out


@pytest.mark.parametrize("excitation", ["random-torque", "sine", "observable", "poses"])
@pytest.mark.parametrize("name", NAMES)
def test_compiles_steps_two_seconds_without_warnings(
    name: str, excitation: str, rng: np.random.Generator
) -> None:
    robot = Robot.from_catalog(name)
    exc = make_excitation(excitation).bind(robot, rng)
    t = np.arange(200) / robot.rate
    s = robot.sample(exc.ctrl(robot, t))
    assert robot.warnings() == {}
    assert np.all(np.isfinite(s.acc)) and np.all(np.isfinite(s.gyro))
    assert robot.time == pytest.approx(2.0)
    # the robot moved
    assert np.abs(s.q[-1] - s.q[0]).max() > 0.05


@pytest.mark.parametrize("name", NAMES)
def test_truth_equals_body_parentid(name: str) -> None:
    robot = Robot.from_catalog(name)
    m = robot.model
    truth = robot.truth()
    assert truth.joint_parent == _parent_joint_via_bodies(m)
    joint_of_body = {int(m.jnt_bodyid[j]): m.joint(j).name for j in range(m.njnt)}
    for imu in robot.imu_names:
        b = int(m.site_bodyid[m.site(imu).id])
        assert truth.imu_joint[imu] == joint_of_body.get(b)
    # and the design intent agrees: the description's tree is what got built
    desc = describe(name)
    expect = {}
    for link in desc.iter_links():
        for child in link.children:
            expect[child.joint] = link.joint
    for link in desc.links:
        expect[link.joint] = None
    assert truth.joint_parent == expect
    assert len(robot.imu_names) == desc.n_imus
    assert robot.imu_names == tuple(f"imu{i}" for i in range(desc.n_imus))


def test_paper_robots_match_their_topologies_and_differ() -> None:
    seen = set()
    for name, parents in PAPER_TOPOLOGIES.items():
        truth = Robot.from_catalog(name).truth()
        expect = {f"j{i + 1}": (None if p == 0 else f"j{p}") for i, p in enumerate(parents)}
        assert truth.joint_parent == expect
        counts = {}
        for j in truth.imu_joint.values():
            counts[j] = counts.get(j, 0) + 1
        assert counts == {f"j{i}": 12 for i in range(1, 6)}
        seen.add(tuple(sorted(expect.items(), key=lambda kv: kv[0])))
    assert len(seen) == 6
    assert any(list(p).count(p[1]) > 1 for p in PAPER_TOPOLOGIES.values())  # some branch


def test_catalog_sizes() -> None:
    assert describe("ur5e").n_joints == 6 and describe("ur5e").n_imus == 12
    assert describe("quadruped").n_joints == 12
    assert describe("humanoid").n_joints >= 20
    assert describe("dual-arm").n_joints == 13
    truth = Robot.from_catalog("dual-arm").truth()
    assert truth.children("torso_yaw") == ["l_shoulder_pan", "r_shoulder_pan"]
    h = Robot.from_catalog("humanoid").truth()
    assert len(h.children(None)) == 3  # two legs and the waist on the pelvis
    assert len(h.children("waist_pitch")) == 3  # neck and two arms on the chest


def test_ur5e_follows_published_dh() -> None:
    """At q = 0 the tool flange sits where the DH parameters put it."""
    robot = Robot.from_catalog("ur5e")
    m, d = robot.model, mujoco.MjData(robot.model)
    mujoco.mj_forward(m, d)
    dh = {
        "d": [0.1625, 0, 0, 0.1333, 0.0997, 0.0996],
        "a": [0, -0.425, -0.3922, 0, 0, 0],
        "alpha": [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0],
    }
    T = np.eye(4)
    for d_, a_, al in zip(dh["d"], dh["a"], dh["alpha"], strict=True):
        ca, sa = np.cos(al), np.sin(al)
        T = T @ np.array([[1, 0, 0, a_], [0, ca, -sa, 0], [0, sa, ca, d_], [0, 0, 0, 1.0]])
    wrist3 = m.body("wrist_3_link").id
    # the flange is the end of the wrist_3 link segment
    end = d.xpos[wrist3] + d.xmat[wrist3].reshape(3, 3) @ np.array([0, 0, 0.0996])
    assert np.allclose(end, T[:3, 3], atol=1e-9)
    masses = [
        m.body_mass[m.body(f"{j}_link").id]
        for j in ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
    ]
    assert np.allclose(masses, [3.761, 8.058, 2.846, 1.37, 1.3, 0.365])


def test_imus_sit_on_the_surface_with_z_along_the_outward_normal() -> None:
    m = build("paper-5").compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for s in range(m.nsite):
        b = m.site_bodyid[s]
        g = next(i for i in range(m.ngeom) if m.geom_bodyid[i] == b)
        assert m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
        center, axis = d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3)[:, 2]
        rel = d.site_xpos[s] - center
        along = rel @ axis
        assert abs(along) <= m.geom_size[g][1] + 1e-9  # on the cylindrical part
        radial = rel - along * axis
        assert np.linalg.norm(radial) == pytest.approx(m.geom_size[g][0], abs=1e-9)
        z = d.site_xmat[s].reshape(3, 3)[:, 2]
        assert np.allclose(z, radial / np.linalg.norm(radial), atol=1e-9)


def test_builds_are_stable() -> None:
    a, b = build("paper-2").compile(), build("paper-2").compile()
    assert np.array_equal(a.site_pos, b.site_pos) and np.array_equal(a.site_quat, b.site_quat)


def test_unknown_robot_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="catalog"):
        describe("paper-7")
