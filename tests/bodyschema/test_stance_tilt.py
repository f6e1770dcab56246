"""The flat stance foot's gravity against the base IMU's, on two synthetic legs whose truth is known."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.forward_kinematics import axis_rotations
from bodyschema.stance_tilt import TiltOptions, tilt_hypotheses, tilt_model, tilt_test

RATE = 100.0
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
G0 = np.array([0.0, 0.0, 9.81])
OPTS = TiltOptions()


def _walk(seconds: float, seed: int):
    """Base tilt (roll, pitch) carried by whichever leg stands; each leg's two joints (x then y) equal
    the tilt while its foot is down and swing away while it is up; white accelerometer noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE)) / RATE
    roll, pitch = 0.05 * np.sin(2 * np.pi * 0.3 * t), 0.08 * np.sin(2 * np.pi * 0.5 * t + 1)
    phase = np.sin(2 * np.pi * 0.8 * t)
    down = np.c_[phase > -0.3, phase < 0.3]
    q = np.c_[roll, pitch, roll, pitch]
    for leg in range(2):
        q[~down[:, leg], 2 * leg : 2 * leg + 2] += 0.3  # the swing leg's joints leave the tilt
    acc = (axis_rotations(AXES[0], roll) @ axis_rotations(AXES[1], pitch)) @ G0
    return q, acc + rng.normal(0, 0.3, acc.shape), down


@pytest.fixture(scope="module")
def model():
    q, acc, down = _walk(60.0, 0)
    chains = [((True, False), (0, 1), AXES), ((False, True), (2, 3), AXES)]
    m = tilt_model(q, acc, down, RATE, chains, OPTS)
    assert m is not None and [leg.foot for leg in m.legs] == [0, 1]
    np.testing.assert_allclose(m.legs[0].c, G0, atol=0.05)
    return m


def _best(model, q, acc, down):
    t2, crit, m, S, stance = tilt_test(model, q, acc, down, RATE, OPTS)
    return t2, crit, tilt_hypotheses(model, q, acc, stance, m, S, OPTS)[0]


def test_untouched_window_within_the_baseline_spread(model):
    q, acc, down = _walk(10.0, 1)
    t2, crit, _ = _best(model, q, acc, down)
    assert t2 < crit


def test_offset_on_one_leg_named_with_its_size(model):
    q, acc, down = _walk(10.0, 2)
    q[:, 1] += np.radians(2.0)
    t2, crit, (kind, _, part, deg, _) = _best(model, q, acc, down)
    assert t2 > crit
    assert (kind, part) == ("offset", 1)
    assert deg == pytest.approx(2.0, abs=0.2)


def test_turned_imu_moves_both_legs_alike(model):
    q, acc, down = _walk(10.0, 3)
    acc = acc @ axis_rotations(AXES[0], np.array([np.radians(2.0)]))[0].T
    t2, crit, (kind, _, part, deg, _) = _best(model, q, acc, down)
    assert t2 > crit
    assert (kind, part) == ("imu", -1)
    assert deg == pytest.approx(2.0, abs=0.2)
