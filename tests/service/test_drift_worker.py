"""Geometry drift through the worker's real cycle: a turned IMU, a bent axis and a dead band raise
their alerts.

A UR5e runs in the simulated farm on the ``robot`` sensing preset with MPU-6050 IMUs (their errors
drawn once and kept, as a real IMU keeps its misalignment), its frames go into a real store, and a
worker with the production settings learns the topology baseline, then the geometry on it (joint
axes and lever arms, every ``kinematics_interval_cycles`` = 6 cycles of 5 s: each estimate on a 30 s
window of its own). Then one drift damage is injected (the simulators' catalog: a 2° turn, a 2° bend,
a 1° dead band) and cycles run until the first alert. Asserted: the nominal run raises no alert and
no finding at all, ever; each damage's first alert is of its kind, on its part.

A turned IMU is seen through the axis it reports, so the turn is about a direction perpendicular to
the joint's axis in the IMU's frame (a turn about the axis itself leaves the axis where it was and
moves only the lever arm's direction, by 3.5 mm at 10 cm for 2°: below what a lever arm repeats to).

Time to the alert: the window must first pass the change (6 cycles), then M = 2 geometry estimates in
a row must show it (6 cycles apart), and the estimates are staggered per robot (up to 5 more):
``POST_CYCLES`` = 24.
"""

from __future__ import annotations

import numpy as np
import pytest

from simulators.kinematics_truth import kinematics_truth
from simulators.robot import Robot
from tests.service.test_damage_worker import RobotRuns, run_robot

pytestmark = pytest.mark.slow

POST_CYCLES = 24
#: Healthy cycles on the topology baseline before the damage: one geometry estimate (kept as the
#: geometry baseline) and one compared with it, whatever the stagger.
HEALTHY_CYCLES = 13


def _turn_about(axis: np.ndarray) -> list[float]:
    """A unit direction perpendicular to ``axis``."""
    e = np.eye(3)[int(np.argmin(np.abs(axis)))]
    v = np.cross(axis, e)
    return (v / np.linalg.norm(v)).tolist()


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> RobotRuns:
    u = kinematics_truth(Robot.from_catalog("ur5e"))["imu7"].axis
    assert u is not None
    kwargs = {
        "imu_rotated": {"imu": "imu7", "angle_deg": 2.0, "about": _turn_about(u)},
        "axis_changed": {"joint": "wrist_1", "angle_deg": 2.0},
        "backlash": {"joint": "wrist_1", "deg": 1.0},
    }
    return run_robot(
        "ur5e",
        7,
        tmp_path_factory.mktemp("drift"),
        kinds=tuple(kwargs),
        damage_kwargs=kwargs,
        post_cycles=POST_CYCLES,
        nominal_cycles=POST_CYCLES,
        healthy_cycles=HEALTHY_CYCLES,
    )


def test_nominal_run_raises_nothing(runs: RobotRuns) -> None:
    assert runs.nominal_alerts == []
    assert all(f == [] for f in runs.nominal_findings[runs.baseline_cycle :]), runs.nominal_findings


@pytest.mark.parametrize(
    ("kind", "part"),
    [("imu_rotated", "imu:imu7"), ("axis_changed", "joint:wrist_1"), ("backlash", "joint:wrist_1")],
)
def test_drift_alerts_first_with_its_kind(runs: RobotRuns, kind: str, part: str) -> None:
    run = runs.damages[kind]
    print(kind, run.first, run.first_finding, run.findings)
    assert run.first is not None, run.findings
    assert run.first[:2] == (kind, part), run.findings
    assert run.first[2] <= POST_CYCLES
    assert run.first_finding is not None and "limit" in run.first_finding["detail"]
