"""``bench excitation``: the three motions share the limits, and one run gives a verdict."""

from __future__ import annotations

import numpy as np
import pytest

from bench.excitation import MOTIONS, _robot, motion_plan, prefixes, run_one
from bodyschema.excitation_plan import check_limits, finite_differences
from simulators.limits import robot_limits


def test_the_three_motions_use_the_same_limits() -> None:
    robot = _robot(("random", 7, 6))
    lim = robot_limits(robot)
    for motion in MOTIONS:
        plan, cpu = motion_plan(robot, motion, 20.0, seed=0)
        assert check_limits(plan, lim) == [], motion
        assert np.allclose(plan.q[0], robot.q()), motion  # from rest at the home pose
        v, a = finite_differences(plan.q, plan.rate)
        # equal limits, each used: the fastest joint reaches at least half its speed or acceleration
        # limit (whichever binds it), so no motion wins by moving harder than another may
        used = np.maximum(np.abs(v).max(axis=0) / lim.velocity, np.abs(a).max(axis=0) / lim.acceleration)
        assert used.max() > 0.5, motion
        assert cpu >= 0.0


def test_prefixes_are_fine_first_then_every_step() -> None:
    assert prefixes(30.0, 5.0) == [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0]
    assert prefixes(4.0, 5.0) == [2.0, 3.0, 4.0]


@pytest.mark.slow
def test_a_planned_run_reaches_the_right_tree_and_never_a_wrong_one() -> None:
    out = run_one(("random", 7, 6), "planned", 12.0, 5.0, 0, geometry_step=100.0)
    assert out["violations"] == 0 and out["wrong"] == 0
    assert out["topology_s"] is not None and out["topology_s"] <= 12.0
    assert out["method"] == "fourier" and out["joints"] == 6
