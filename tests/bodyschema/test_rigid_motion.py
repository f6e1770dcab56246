"""Ideal IMU readings from a reference rigid-body motion (bodyschema.rigid_motion)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.rigid_motion import (
    angular_velocity,
    continuous_quat,
    ideal_imu,
    integrate_angular_velocity,
    linear_acceleration,
    lowpass,
    quat_to_matrix,
    reference_motion,
    smooth_random_motion,
)


def test_constant_rate_is_recovered_exactly_in_the_body_frame() -> None:
    t = np.arange(300) * 0.01
    w = np.tile([0.3, -0.5, 1.2], (300, 1))
    q = integrate_angular_velocity(t, w, Rotation.from_rotvec([0.4, 0.1, -0.2]).as_quat(scalar_first=True))
    est = angular_velocity(t, q)
    assert np.allclose(est[2:-2], [0.3, -0.5, 1.2], atol=1e-9)


def test_smooth_motion_readings_match_the_analytic_ones(rng: np.random.Generator) -> None:
    m = smooth_random_motion(10.0, 200.0, rng, max_rate=4.0, max_accel=3.0)
    gyro, acc = ideal_imu(m["t"], m["quat"], m["pos"], m["gravity"])
    inner = slice(10, -10)
    # spline derivatives: errors far below any sensor's resolution
    assert np.max(np.abs(gyro - m["gyro"])[inner]) < 2e-3
    assert np.max(np.abs(acc - m["acc"])[inner]) < 2e-3
    assert np.max(np.abs(m["gyro"])) == pytest.approx(4.0, rel=0.05)


def test_specific_force_at_rest_reads_plus_g_along_world_up_in_the_sensor_frame() -> None:
    t = np.arange(50) * 0.01
    # body x axis points up: rotate -90 deg about y (body x -> world z)
    q = np.tile(Rotation.from_rotvec([0.0, -np.pi / 2, 0.0]).as_quat(scalar_first=True), (50, 1))
    gyro, acc = ideal_imu(t, q, np.zeros((50, 3)))
    assert np.allclose(gyro, 0.0, atol=1e-12)
    assert np.allclose(acc, [9.81, 0.0, 0.0], atol=1e-9)


def test_linear_acceleration_of_a_parabola() -> None:
    t = np.linspace(0.0, 2.0, 101)
    pos = np.stack([0.5 * 3.0 * t**2, -t, np.ones_like(t)], axis=1)
    assert np.allclose(linear_acceleration(t, pos), [3.0, 0.0, 0.0], atol=1e-8)


def test_continuous_quat_removes_sign_flips_without_changing_rotations(rng: np.random.Generator) -> None:
    q = Rotation.from_rotvec(np.outer(np.linspace(0, 1, 20), [0.0, 0.0, 1.0])).as_quat(scalar_first=True)
    flips = rng.choice([-1.0, 1.0], size=20)
    c = continuous_quat(q * flips[:, None])
    assert np.all(np.einsum("ij,ij->i", c[1:], c[:-1]) > 0)
    assert np.allclose(quat_to_matrix(c), quat_to_matrix(q))


def test_lowpass_keeps_slow_and_removes_fast_without_delay() -> None:
    t = np.arange(2000) / 200.0
    slow = np.sin(2 * np.pi * 0.5 * t)
    x = np.stack([slow + 0.5 * np.sin(2 * np.pi * 40 * t)] * 3, axis=1)
    y = lowpass(x, 200.0, 5.0)
    assert np.max(np.abs(y[100:-100, 0] - slow[100:-100])) < 0.01


@pytest.mark.parametrize("cutoff", [0.0, 150.0])
def test_lowpass_rejects_cutoffs_outside_the_band(cutoff: float) -> None:
    with pytest.raises(ValueError, match="cutoff"):
        lowpass(np.zeros((100, 3)), 200.0, cutoff)


def test_bad_reference_input_is_refused_with_a_reason() -> None:
    t = np.arange(10) * 0.01
    q = np.tile([1.0, 0.0, 0.0, 0.0], (10, 1))
    q[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        angular_velocity(t, q)
    with pytest.raises(ValueError, match="increasing"):
        angular_velocity(t[::-1], np.tile([1.0, 0.0, 0.0, 0.0], (10, 1)))
    with pytest.raises(ValueError, match="shape"):
        reference_motion(t, np.ones((10, 3)), np.zeros((10, 3)))
