"""The shared IMU effect forward models against closed-form expectations."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema import imu_effects as fx


def test_doctests() -> None:
    result = doctest.testmod(fx)
    assert result.attempted >= 10 and result.failed == 0  # the module's examples ran, and held


def test_time_shift_recovers_delayed_sine(rng: np.random.Generator) -> None:
    t = np.arange(2000) / 1000.0
    delay = rng.uniform(0.001, 0.01)
    x = np.stack([np.sin(2 * np.pi * 3 * t)] * 3, axis=1)
    y = fx.time_shift(t, x, delay)
    inner = t > 0.02
    expect = np.sin(2 * np.pi * 3 * (t - delay))
    assert np.max(np.abs(y[inner, 0] - expect[inner])) < 2e-4


def test_time_shift_multi_imu_shape_and_edge_hold() -> None:
    t = np.arange(10) * 0.1
    x = np.arange(10 * 2 * 3, dtype=float).reshape(10, 2, 3)
    y = fx.time_shift(t, x, 0.25)
    assert y.shape == x.shape
    assert np.allclose(y[0], x[0]) and np.allclose(y[1], x[0])
    assert np.allclose(y[5], 0.5 * (x[2] + x[3]))


def test_affine_per_imu_matrix_and_bias(rng: np.random.Generator) -> None:
    x = rng.normal(size=(7, 4, 3))
    m = rng.normal(size=(4, 3, 3))
    b = rng.normal(size=(4, 3))
    y = fx.affine(x, m, b)
    for k in range(4):
        assert np.allclose(y[:, k], x[:, k] @ m[k].T + b[k])
    d = rng.normal(size=(4, 3))
    assert np.allclose(fx.affine(x, d), x * d)


def test_rotate_is_transpose_of_mounting(rng: np.random.Generator) -> None:
    rv = rng.normal(size=3)
    R = Rotation.from_rotvec(rv).as_matrix()
    v = rng.normal(size=(5, 3))
    assert np.allclose(fx.rotate(v, rv), (R.T @ v.T).T)
    rvk = rng.normal(size=(2, 3))
    vk = rng.normal(size=(5, 2, 3))
    y = fx.rotate(vk, rvk)
    for k in range(2):
        assert np.allclose(y[:, k], vk[:, k] @ Rotation.from_rotvec(rvk[k]).as_matrix())


def test_lever_arm_matches_rigid_body_point(rng: np.random.Generator) -> None:
    # A body spinning at a constant rate about z: a point at radius r feels -w^2 r (centripetal).
    w = rng.uniform(0.5, 3.0)
    r = np.array([rng.uniform(0.1, 1.0), 0.0, 0.0])
    out = fx.lever_arm(np.zeros((1, 3)), np.array([[0, 0, w]]), np.zeros((1, 3)), r)
    assert np.allclose(out, [[-(w**2) * r[0], 0, 0]])
    # tangential term: wdot x r
    out = fx.lever_arm(np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0, 0, 2.0]]), r)
    assert np.allclose(out, [[0, 2.0 * r[0], 0]])


def test_specific_force_at_rest_reads_up_in_sensor_frame(rng: np.random.Generator) -> None:
    R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    g = np.array([0, 0, -9.81])
    f = fx.specific_force(R[None], np.zeros((1, 3)), g)
    assert np.allclose(R @ f[0], [0, 0, 9.81])


def test_angular_acceleration_of_ramp() -> None:
    t = np.arange(50) * 0.01
    g = np.stack([t * 3.0, -t, np.zeros_like(t)], axis=1)
    assert np.allclose(fx.angular_acceleration(t, g), [3.0, -1.0, 0.0])


def test_white_noise_std(rng: np.random.Generator) -> None:
    n = fx.white_noise((200_000, 3), [0.01, 0.02, 0.03], 100.0, rng)
    assert np.allclose(n.std(axis=0), np.array([0.1, 0.2, 0.3]), rtol=0.02)


def test_quantize_and_resample() -> None:
    assert np.allclose(fx.quantize(np.array([[0.12, 0.37, -0.6]]), 0.25), [[0.0, 0.25, -0.5]])
    t = np.sort(np.r_[0.0, np.random.default_rng(1).uniform(0, 1, 50), 1.0])
    x = np.stack([2 * t + 1] * 3, axis=1)
    tn, xn = fx.resample(t, x, 10.0)
    assert np.allclose(tn, np.arange(11) / 10)
    assert np.allclose(xn[:, 0], 2 * tn + 1)


@pytest.mark.parametrize("bad", [np.zeros((5, 2)), np.zeros(5)])
def test_bad_shapes_raise(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        fx.affine(bad, np.eye(3))
