"""Geometry drift (:mod:`bodyschema.kinematic_drift`): an IMU turned or slid on its link, a bent axis.

A random five-joint tree (j2 hangs under j1 and carries imu2 and imu3; imu1 rides j1) is recorded
twice on the realistic sensing preset with different motion, once healthy and once with one edit to
its model. Ideal IMUs: a real IMU keeps its own misalignment from run to run, which the simulator
would otherwise redraw.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
import pytest

from bodyschema.findings import Finding
from bodyschema.kinematic_drift import kinematic_findings
from bodyschema.kinematics import Kinematics, estimate_kinematics
from simulators.random_robot import random_robot
from simulators.robot import Robot
from tests.bodyschema.test_kinematics import record, truth_topology


def learn(seed: int, edit: Callable[[Robot], None] | None = None) -> Kinematics:
    robot = random_robot(np.random.default_rng(3), 5, rate=1000.0)
    if edit is not None:
        edit(robot)
        robot.recompile()
    case = record(robot, 20.0, seed=seed, imu_model="ideal")
    return estimate_kinematics(case.rec, truth_topology(case.rec))


def turn_site(robot: Robot) -> None:
    site = robot.spec.site("imu2")
    q = np.empty(4)
    mujoco.mju_axisAngle2Quat(q, np.array([0.0, 0.6, 0.8]), np.radians(4.0))
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(site.quat, dtype=float), q)
    site.quat = out


def slide_site(robot: Robot) -> None:
    site = robot.spec.site("imu2")
    site.pos = np.asarray(site.pos, dtype=float) + np.array([0.0, 0.0, 0.02])


def bend_axis(robot: Robot) -> None:
    joint = robot.spec.joint("j2")
    a = np.asarray(joint.axis, dtype=float)
    b = np.cross(a, [1.0, 0.0, 0.0])
    b /= np.linalg.norm(b)
    joint.axis = np.cos(np.radians(4.0)) * a + np.sin(np.radians(4.0)) * b


@pytest.fixture(scope="module")
def baseline() -> Kinematics:
    return learn(seed=1)


def kinds(found: tuple[Finding, ...]) -> list[tuple[str, str | None]]:
    return sorted((f.kind, f.imu or f.joint) for f in found)


def test_same_body_other_motion_gives_nothing(baseline: Kinematics) -> None:
    assert kinematic_findings(baseline, learn(seed=5)) == ()


def test_turned_imu(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, edit=turn_site))
    assert kinds(found) == [("imu_rotated", "imu2")]
    assert "turned 4." in found[0].detail or "turned 3." in found[0].detail


def test_slid_imu(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, edit=slide_site))
    assert ("imu_shifted", "imu2") in kinds(found)
    assert all(f.kind == "imu_shifted" for f in found)


def test_bent_axis(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, edit=bend_axis))
    assert ("axis_changed", "j2") in kinds(found)
    assert not any(f.kind == "imu_rotated" for f in found)
