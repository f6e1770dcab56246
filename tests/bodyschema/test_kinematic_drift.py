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
from tests.builders import record, truth_topology


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


def test_findings_survive_the_json_round_trip(mpu_baseline: Kinematics) -> None:
    """What the service keeps (the kinematics JSON) judges as the estimate itself did."""
    bent = learn_mpu(seed=5, damage=("axis_changed", {"joint": "j2", "angle_deg": 2.0}))
    topo = mpu_baseline.topology
    back = Kinematics.from_json(mpu_baseline.to_json(), topo)
    assert kinds(kinematic_findings(back, Kinematics.from_json(bent.to_json(), topo))) == kinds(
        kinematic_findings(mpu_baseline, bent)
    )
    assert kinematic_findings(back, mpu_baseline) == ()


def _two_on_a_link(turn_a: float, turn_b: float) -> tuple[Kinematics, Kinematics]:
    """j2 under j1, with imu1 on j1's link and imu2, imu3 on j2's; the axis seen from imu2 and imu3
    turned by ``turn_a`` and ``turn_b`` degrees (axis std 0.05°, limit 0.55°), nothing in the parent's
    frame to judge a bend by."""
    from bodyschema.kinematics import ImuKinematics, JointKinematics
    from bodyschema.topology import Topology

    topo = Topology({"j1": None, "j2": "j1"}, {"imu1": "j1", "imu2": "j2", "imu3": "j2"})

    def kin(a: float, b: float) -> Kinematics:
        def imu(name: str, joint: str, parent: str | None, deg: float) -> ImuKinematics:
            t = np.radians(deg)
            return ImuKinematics(
                name,
                joint,
                parent,
                axis=np.array([0.0, np.sin(t), np.cos(t)]),
                axis_std_deg=0.05,
                converged=True,
            )

        imus = {
            "imu1": imu("imu1", "j1", None, 0.0),
            "imu2": imu("imu2", "j2", "imu1", a),
            "imu3": imu("imu3", "j2", "imu1", b),
        }
        joints = {
            "j1": JointKinematics("j1", None, ("imu1",), "imu1"),
            "j2": JointKinematics("j2", "j1", ("imu2", "imu3"), "imu2"),
        }
        return Kinematics(imus, joints, (), 10.0, 0.0, 100, topo)

    return kin(0.0, 0.0), kin(turn_a, turn_b)


def test_every_imu_on_a_link_turned_is_a_bend_and_one_is_a_turned_mount() -> None:
    base, both = _two_on_a_link(2.0, 2.0)
    found = kinematic_findings(base, both)
    assert kinds(found) == [("axis_changed", "j2")]
    assert "all 2 IMUs" in found[0].detail and "2.00 to 2.00 deg" in found[0].detail
    assert kinds(kinematic_findings(*_two_on_a_link(2.0, 0.0))) == [("imu_rotated", "imu2")]
    assert kinematic_findings(*_two_on_a_link(0.5, 0.5)) == ()  # under 5 std + 0.2° floor (0.55°)


def test_mpu6050_backlash_one_degree(mpu_baseline: Kinematics) -> None:
    """A 1° dead band on j2 is read back within 15 % by both IMUs of its link, and is the one finding;
    the healthy body reads no band (within 5 std)."""
    found = kinematic_findings(
        mpu_baseline, (slack := learn_mpu(seed=5, damage=("backlash", {"joint": "j2", "deg": 1.0})))
    )
    assert kinds(found) == [("backlash", "j2")]
    assert "grew" in found[0].detail
    for name in ("imu2", "imu3"):
        k = slack.imus[name]
        assert abs(k.backlash_deg - 1.0) < 0.15, (name, k.backlash_deg)
        assert abs(mpu_baseline.imus[name].backlash_deg) < 5 * mpu_baseline.imus[name].backlash_std_deg + 0.01


def test_mpu6050_imu_turned_about_its_joints_axis(mpu_baseline: Kinematics) -> None:
    """A 2° turn of imu3 about j2's own axis leaves the axis both IMUs of j2's link see where it was;
    the rotation between the two gyros tells it (j2's link turns about two axes: j1's and its own)."""
    from simulators.kinematics_truth import kinematics_truth

    u = kinematics_truth(random_robot(np.random.default_rng(3), 5, rate=1000.0))["imu3"].axis
    turn = ("imu_rotated", {"imu": "imu3", "angle_deg": 2.0, "about": u})
    found = kinematic_findings(mpu_baseline, learn_mpu(seed=5, damage=turn))
    ((kind, part),) = kinds(found)
    assert kind == "imu_rotated" and part in ("imu2", "imu3")
    assert "rotation between imu2 and imu3 on one link turned" in found[0].detail
    seen = float(found[0].detail.split("turned ")[1].split(" deg")[0])
    assert 1.9 <= seen <= 2.1
    assert "about the joint's axis" in found[0].detail


def test_same_link_rotation_judged_only_where_the_link_turns_about_two_axes() -> None:
    """Under a root joint on a fixed base the link turns about one axis, and the gyros fix the
    rotation between its IMUs on that axis only (``SameLink.rank`` 1): a change there is not judged,
    even with a finite std (an estimate written before the rank was)."""
    from dataclasses import replace

    from bodyschema.kinematics import SameLink, rotation_about

    base, same = _two_on_a_link(0.0, 0.0)
    turned = rotation_about(np.array([0.0, 0.0, 1.0]), np.array([np.radians(2.0)]))[0]

    def with_pair(k: Kinematics, rot: np.ndarray, rank: int) -> Kinematics:
        return replace(k, same_link=(SameLink("imu2", "imu3", rot, 0.01, rank=rank),))

    found = kinematic_findings(with_pair(base, np.eye(3), 2), with_pair(same, turned, 2))
    assert kinds(found) == [("imu_rotated", "imu3")] and "turned 2.00 deg (limit 0.27)" in found[0].detail
    assert kinematic_findings(with_pair(base, np.eye(3), 2), with_pair(same, np.eye(3), 2)) == ()
    assert kinematic_findings(with_pair(base, np.eye(3), 1), with_pair(same, turned, 1)) == ()
    assert kinematic_findings(with_pair(base, np.eye(3), 2), with_pair(same, turned, 1)) == ()
