"""Geometry drift (:mod:`bodyschema.kinematic_drift`): an IMU turned or slid on its link, a bent axis.

A random five-joint tree (j2 hangs under j1 and carries imu2 and imu3; imu1 rides j1) is recorded
twice on the realistic sensing preset with different motion, once healthy and once with one damage of
the simulators' drift catalog. First with ideal IMUs, then with MPU-6050 IMUs whose errors are drawn
once (``imu_seed``) and kept across the two runs, as a real IMU keeps its misalignment from run to
run: a turned IMU or a bent axis of 2° must be found, the same body with other motion must give
nothing.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bodyschema.findings import Finding
from bodyschema.kinematic_drift import kinematic_findings
from bodyschema.kinematics import Kinematics, estimate_kinematics
from simulators.random_robot import random_robot
from tests.bodyschema.test_kinematics import record, truth_topology


def learn(seed: int, damage: tuple[str, dict[str, Any]] | None = None) -> Kinematics:
    """The kinematics of 20 s of the tree, after ``damage`` (the simulators' drift catalog)."""
    robot = random_robot(np.random.default_rng(3), 5, rate=1000.0)
    case = record(robot, 20.0, seed=seed, imu_model="ideal", damage=damage)
    return estimate_kinematics(case.rec, truth_topology(case.rec))


TURN = ("imu_rotated", {"imu": "imu2", "angle_deg": 4.0, "about": [0.0, 0.6, 0.8]})
SLIDE = ("imu_shifted", {"imu": "imu2", "meters": 0.02})
BEND = ("axis_changed", {"joint": "j2", "angle_deg": 4.0})


@pytest.fixture(scope="module")
def baseline() -> Kinematics:
    return learn(seed=1)


def kinds(found: tuple[Finding, ...]) -> list[tuple[str, str | None]]:
    return sorted((f.kind, f.imu or f.joint) for f in found)


def test_same_body_other_motion_gives_nothing(baseline: Kinematics) -> None:
    assert kinematic_findings(baseline, learn(seed=5)) == ()


def test_turned_imu(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, damage=TURN))
    assert kinds(found) == [("imu_rotated", "imu2")]
    assert "turned 4." in found[0].detail or "turned 3." in found[0].detail


def test_slid_imu(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, damage=SLIDE))
    assert ("imu_shifted", "imu2") in kinds(found)
    assert all(f.kind == "imu_shifted" for f in found)


def test_bent_axis(baseline: Kinematics) -> None:
    found = kinematic_findings(baseline, learn(seed=5, damage=BEND))
    assert ("axis_changed", "j2") in kinds(found)
    assert not any(f.kind == "imu_rotated" for f in found)


def learn_mpu(seed: int, damage: tuple[str, dict[str, Any]] | None = None) -> Kinematics:
    """:func:`learn` with MPU-6050 IMUs, their errors drawn from one seed for every run."""
    robot = random_robot(np.random.default_rng(3), 5, rate=1000.0)
    case = record(robot, 20.0, seed=seed, damage=damage, imu_seed=11)
    return estimate_kinematics(case.rec, truth_topology(case.rec))


@pytest.fixture(scope="module")
def mpu_baseline() -> Kinematics:
    return learn_mpu(seed=1)


def test_mpu6050_same_body_other_motion_gives_nothing(mpu_baseline: Kinematics) -> None:
    assert kinematic_findings(mpu_baseline, learn_mpu(seed=5)) == ()


def test_mpu6050_imu_turned_two_degrees(mpu_baseline: Kinematics) -> None:
    from simulators.kinematics_truth import kinematics_truth

    u = kinematics_truth(random_robot(np.random.default_rng(3), 5, rate=1000.0))["imu2"].axis
    about = np.cross(u, [1.0, 0.0, 0.0])  # a turn that moves the axis seen from the IMU by all of it
    turn = ("imu_rotated", {"imu": "imu2", "angle_deg": 2.0, "about": about})
    found = kinematic_findings(mpu_baseline, learn_mpu(seed=5, damage=turn))
    assert kinds(found) == [("imu_rotated", "imu2")]
    assert "turned 2.0" in found[0].detail or "turned 1.9" in found[0].detail


def test_mpu6050_axis_bent_two_degrees(mpu_baseline: Kinematics) -> None:
    found = kinematic_findings(
        mpu_baseline, learn_mpu(seed=5, damage=("axis_changed", {"joint": "j2", "angle_deg": 2.0}))
    )
    assert ("axis_changed", "j2") in kinds(found)
    assert not any(f.kind == "imu_rotated" for f in found)
