"""The dispatcher and the dependency-matrix -> topology step."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from bodyschema.estimate import METHODS, estimate_topology, topology_from_dependency
from bodyschema.recording import Recording
from simulators.kinematic_tree import random_robot_recording


def test_unknown_method_and_missing_positions_are_refused(rng):
    rec = random_robot_recording(rng, n_joints=3, seconds=2.0)
    with pytest.raises(ValueError, match="unknown method"):
        estimate_topology(rec, method="magic")
    no_q = Recording(
        t=rec.t,
        joint_names=rec.joint_names,
        q=None,
        imu_names=rec.imu_names,
        acc=rec.acc,
        gyro=rec.gyro,
        ref_quat=np.tile([1.0, 0, 0, 0], (rec.n_samples, 1)),
    )
    with pytest.raises(ValueError, match="joint positions"):
        estimate_topology(no_q)
    assert METHODS == ("fast", "network", "network-paper", "mlp")


def test_truth_is_never_read(rng):
    rec = random_robot_recording(rng, n_joints=6, seconds=10.0)
    wrong = replace(rec, truth_joint_parent=("",) * rec.n_joints, truth_imu_joint=("",) * rec.n_imus)
    a, b = estimate_topology(rec, timer=time.process_time), estimate_topology(wrong)
    assert a.same_structure(b)
    assert a.method == "fast" and a.seconds > 0 and b.seconds == 0.0
    assert set(a.excitation) == set(rec.joint_names)
    np.testing.assert_allclose(
        [a.excitation[j] for j in rec.joint_names], np.sqrt(np.mean(rec.qd**2, axis=0))
    )


def test_dependency_rows_merge_and_complete():
    # imu a, a2 on j1's link, b on j2's link under j1, c on the base; j3 carries no IMU (all-0 column)
    D = np.array([[1, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0]], dtype=bool)
    topo = topology_from_dependency(D, ["a", "a2", "b", "c"], ["j1", "j2", "j3"], method="x")
    assert topo.imu_joint == {"a": "j1", "a2": "j1", "b": "j2", "c": None}
    assert topo.joint_parent["j2"] == "j1" and topo.joint_parent["j1"] is None
    assert not topo.unique
    # j3 can hang under the base, j1 or j2: three trees in all
    assert len(topo.candidates) == 2
    assert {c.joint_parent["j3"] for c in (topo, *topo.candidates)} == {None, "j1", "j2"}
    assert topo.confidence["joint:j3"] == pytest.approx(1 / 3)
    assert topo.confidence["joint:j1"] == pytest.approx(1.0)


def test_undetermined_joints_are_placeholders_on_the_base():
    D = np.array([[1, 0, 0], [1, 0, 1]], dtype=bool)
    topo = topology_from_dependency(D, ["a", "b"], ["j1", "j2", "j3"], undetermined=["j2"])
    assert topo.undetermined == ("j2",)
    assert topo.joint_parent == {"j1": None, "j2": None, "j3": "j1"}
    assert topo.confidence["joint:j2"] == 0.0
    assert topo.unique


def test_dependency_shape_is_checked():
    with pytest.raises(ValueError, match="shape"):
        topology_from_dependency(np.zeros((2, 2), dtype=bool), ["a"], ["j1", "j2"])


def test_a_noisy_matrix_is_corrected_to_the_nearest_tree():
    # chain j1 -> j2 -> j3 with one IMU per link; IMU c's row lost its j2 entry (a false 0)
    D = np.array([[1, 0, 0], [1, 1, 0], [1, 0, 1]], dtype=bool)
    topo = topology_from_dependency(
        D, ["a", "b", "c"], ["j1", "j2", "j3"], imu_confidence={"a": 1.0, "b": 1.0, "c": 1.0}
    )
    # one flip away: either j3 hangs on j2 (c's row was missing j2) or on j1 (a sibling of j2)
    assert topo.joint_parent["j1"] is None and topo.joint_parent["j2"] == "j1"
    assert topo.imu_joint == {"a": "j1", "b": "j2", "c": "j3"}


def test_a_stray_row_joins_the_row_that_overrules_the_least_evidence():
    # chain j0 -> j1 -> j2, three IMUs per link; IMU "a" of the first link shows a weak false j2
    # entry: its row is one flip from its own link's and one flip from the last link's
    D = np.array([[1, 0, 1], [1, 0, 0], [1, 0, 0]] + [[1, 1, 0]] * 3 + [[1, 1, 1]] * 3, dtype=bool)
    names = ["a", "a2", "a3", "b", "b2", "b3", "c", "c2", "c3"]
    joints = ["j0", "j1", "j2"]
    # counted alike, the tie goes to the bigger row (the last link): the weak entry wins
    plain = topology_from_dependency(D, names, joints)
    assert plain.imu_joint["a"] == "j2"
    evidence = np.full(D.shape, 2.0)
    evidence[0, 2] = 0.1  # the false j2 entry sat just above delta; a's j1 entry far below it
    topo = topology_from_dependency(D, names, joints, evidence=evidence)
    assert topo.joint_parent == {"j0": None, "j1": "j0", "j2": "j1"}
    assert topo.imu_joint == dict(zip(names, ["j0"] * 3 + ["j1"] * 3 + ["j2"] * 3, strict=True))
    with pytest.raises(ValueError, match="evidence"):
        topology_from_dependency(D, names, joints, evidence=-evidence)


def test_more_distinct_rows_than_joints_are_merged_then_corrected():
    # two links with two IMUs each, and one IMU whose row lost its j1 entry: 3 rows for 2 joints
    D = np.array([[1, 0], [1, 0], [1, 1], [1, 1], [0, 1]], dtype=bool)
    names = ["a", "a2", "b", "b2", "x"]
    topo = topology_from_dependency(D, names, ["j1", "j2"], imu_confidence=dict.fromkeys(names, 1.0))
    assert topo.joint_parent == {"j1": None, "j2": "j1"}
    assert topo.imu_joint == {"a": "j1", "a2": "j1", "b": "j2", "b2": "j2", "x": "j2"}
    assert topo.confidence["imu:x"] < 1.0
