"""The fast estimator on short windows of slow random motion: undetermined, never a wrong unique tree.

Over the first seconds of the simulators' random excitation (sinusoids of 0.1-0.5 Hz, the robot
sensing preset) the joints' rates span a few smooth shapes, and a model through the wrong joint
leaves as little as the right one: the first 3 s of a UR5e used to give a unique and wrong tree.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.excitation import motion_plan
from bodyschema.diff import undetermined_reasons, unplaced_reasons
from bodyschema.estimate import estimate_topology
from bodyschema.fast_core import _rival_joints
from bodyschema.recording import Recording
from simulators.planned_motion import PlannedMotion
from simulators.robot import Robot
from simulators.sensing import apply_sensing, resolve_sensing
from simulators.simulation import Simulation


def _ur5e_random(seconds: float) -> Recording:
    """The excitation bench's UR5e with its default random motion (seed 0), the first ``seconds``."""
    robot = Robot.from_catalog("ur5e", rate=resolve_sensing("robot").inner_rate)
    plan, _ = motion_plan(robot, "random", 60.0, 0)
    sim = Simulation(robot, seed=0, excitation=PlannedMotion(plan), rate=robot.rate)
    rec = apply_sensing(sim.advance(seconds=seconds + 0.2), "robot", np.random.default_rng(0))
    return rec.window(0.0, seconds)


def _decided(topo) -> bool:
    return not undetermined_reasons(topo) and not unplaced_reasons(topo)


def test_three_seconds_of_random_motion_are_undetermined_and_name_the_joints():
    rec = _ur5e_random(3.0)
    topo = estimate_topology(rec)
    # the rival models through other joints fit as well as the chosen ones: every joint is named
    assert not _decided(topo)
    assert set(topo.undetermined) == set(rec.joint_names)
    assert "move each on its own" in unplaced_reasons(topo)[0]


def test_without_the_rival_test_the_same_window_was_confidently_wrong(monkeypatch):
    # what the window gave before the rivals were compared: a unique tree, and a wrong one
    monkeypatch.setattr("bodyschema.fast_core._rival_joints", lambda *a, **k: set())
    rec = _ur5e_random(3.0)
    topo = estimate_topology(rec)
    assert _decided(topo)
    assert topo.joint_parent != rec.truth_parent_map or topo.imu_joint != rec.truth_imu_map


@pytest.mark.slow
def test_eight_seconds_of_the_same_motion_give_the_right_tree():
    rec = _ur5e_random(8.0)
    topo = estimate_topology(rec)
    assert _decided(topo)
    assert topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map


def test_a_rival_only_counts_while_it_fits_about_as_well():
    class _Sig:
        n_eff, Tb = 0.8, 60

    # two groups and the world; group 1 hangs on group 0 through joint 1 (ratio 0.2)
    ratio = np.full((2, 3, 3), 1e3)
    ratio[1, 0, 1] = ratio[0, 1, 1] = 0.2
    ratio[0, 2, 0] = 0.3
    nbrs = {0: [(2, (0,), 0.3), (1, (1,), 0.2)], 1: [(0, (1,), 0.2)], 2: [(0, (0,), 0.3)]}
    parent_of = {0: (2, (0,), 0.3), 1: (0, (1,), 0.2)}
    assert _rival_joints(ratio, nbrs, parent_of, _Sig(), 25.0) == set()
    # the hinge between the groups fits through joint 2 as well as through joint 1: group 1 may hang
    # on group 0 through either, and group 0 on group 1 through joint 2 (a rival of its world edge)
    ratio[1, 0, 2] = ratio[0, 1, 2] = 0.25
    assert _rival_joints(ratio, nbrs, parent_of, _Sig(), 25.0) == {0, 1, 2}
    ratio[1, 0, 2] = ratio[0, 1, 2] = 5.0  # accepted, but 25 times worse on 140 degrees of freedom
    assert _rival_joints(ratio, nbrs, parent_of, _Sig(), 25.0) == set()
