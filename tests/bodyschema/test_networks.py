"""Sensor networks: derivatives by hand equal autodiff; a short training recovers a small robot."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.func import jvp

from bodyschema.dependency import dependency_from_jacobian, invariant_jacobian, network_jacobian
from bodyschema.networks import (
    SensorNetworks,
    robot_scale,
    rpy_to_matrix,
    train_sensor_networks,
)
from bodyschema.threads import set_torch_threads
from simulators.kinematic_tree import random_robot_recording


def _net(seed: int) -> SensorNetworks:
    net = SensorNetworks(3, 4, hidden=(8, 8, 8), seed=seed).double()
    net.set_input_scaling(torch.zeros(4), torch.full((4,), 0.7))
    net.in_mean, net.in_std = net.in_mean.double(), net.in_std.double()
    return net


def test_rpy_matrix_is_a_rotation(rng):
    R = rpy_to_matrix(torch.as_tensor(rng.uniform(-3, 3, size=(50, 3))))
    eye = torch.eye(3, dtype=R.dtype).expand_as(R)
    assert torch.allclose(R @ R.transpose(-1, -2), eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(50, dtype=R.dtype))


def test_hand_rolled_time_derivatives_equal_nested_autodiff(seed):
    net = _net(seed)
    g = torch.Generator().manual_seed(seed)
    th, thd, thdd = (torch.randn(6, 4, generator=g, dtype=torch.float64) for _ in range(3))

    def along(s):
        return net.raw(th + s * thd + 0.5 * s * s * thdd)

    def first(s):
        return jvp(along, (s,), (torch.ones_like(s),))

    z = torch.zeros((), dtype=torch.float64)
    (o, o1), (_, o2) = jvp(first, (z,), (torch.ones_like(z),))
    m0, m1, m2 = net._along(th, thd, thdd)
    for a, b in ((o, m0), (o1, m1), (o2, m2)):
        assert torch.allclose(a, b, atol=1e-12)
    # the closed-form Euler body rates equal vee(Rᵀ Ṙ)
    w, _ = net.predict(th, thd, thdd, None)
    R = rpy_to_matrix(o[..., 3:])
    Rd = jvp(rpy_to_matrix, (o[..., 3:],), (o1[..., 3:],))[1]
    W = R.transpose(-1, -2) @ Rd
    omega = torch.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], -1)
    assert torch.allclose(omega + net.gyro_bias, w, atol=1e-12)


def test_threads_default_to_one(monkeypatch):
    monkeypatch.delenv("BODYHEALTH_TORCH_THREADS", raising=False)
    before = torch.get_num_threads()
    try:
        assert set_torch_threads() == 1
        assert torch.get_num_threads() == 1
    finally:
        set_torch_threads(before)


def test_training_lowers_the_loss(rng):
    rec = random_robot_recording(rng, n_joints=2, seconds=5.0).derived()
    _, hist = train_sensor_networks(
        rec.q,
        rec.qd,
        rec.qdd,
        rec.gyro,
        rec.acc,
        rec.gravity,
        hidden=(16, 16, 16),
        epochs=20,
        seed=1,
    )
    # the first epoch already starts from the IMUs' mean poses (gravity), so the drop is measured
    # over 20 epochs: 0.012-0.027 of the first epoch's loss on four drawn robots
    assert hist[-1] < 0.1 * hist[0]


@pytest.mark.slow
def test_networks_recover_a_small_robot_exactly():
    """A 3-joint branching robot, 2 IMUs per link, 20 s: the second-moment matrix is exact.

    The robot is a fixed draw: over random draws of this small kind (2 IMUs per link, 20 s) the
    40-epoch networks give the exact matrix on 29 of 32 measured (a true dependency as weak as the
    noise floor, or features of two links too close to split), so a random draw would make this test
    fail by chance rather than by regression. The catalog robots (12 IMUs per link, 60 s) are
    measured by ``bodyhealth bench topology``."""
    rec = random_robot_recording(
        np.random.default_rng(1),
        n_joints=3,
        seconds=20.0,
        imus_per_link=(2, 2),
        base_imus=0,
        parent=[-1, 0, 0],
    )
    jbar = network_jacobian(rec, kind="network", epochs=40, seed=0).jbar
    res = dependency_from_jacobian(jbar, "moment", rng=np.random.default_rng(0))
    np.testing.assert_array_equal(res.dependency, rec.truth_dependency)


def test_invariant_jacobian_equals_central_differences(seed, rng):
    """Eq. 14 on an untrained network: column norms of ∂R/∂θ_j and the norm of ∂b/∂θ_j, per sample."""
    net = _net(seed)  # 3 IMUs, 4 joints, float64
    theta = torch.as_tensor(rng.normal(size=(7, 4)))
    jb = invariant_jacobian(net, theta)
    assert tuple(jb.shape) == (3, 7, 4, 4)
    h = 1e-6
    for j in range(4):
        e = torch.zeros_like(theta)
        e[:, j] = h
        (R1, b1), (R0, b0) = net.pose(theta + e), net.pose(theta - e)
        dR, db = (R1 - R0) / (2 * h), (b1 - b0) / (2 * h)
        fd = torch.cat(
            [torch.linalg.vector_norm(dR, dim=-2), torch.linalg.vector_norm(db, dim=-1)[..., None]], -1
        )
        assert torch.allclose(jb[..., j], fd, rtol=1e-5, atol=1e-9), j
    assert float(jb.min()) > 1e-5  # an untrained network depends on every input, a little


def test_fused_jacobian_norms_equal_one_jvp_per_joint(seed, rng):
    """The sensor networks' one-pass Jacobian norms equal the generic loop (one ``jvp`` of the pose per
    joint) that any pose model gets, with input scaling on, to float32 rounding."""

    class PoseOnly:  # hides the fused method: invariant_jacobian takes its generic path
        def __init__(self, net: SensorNetworks) -> None:
            self.pose = net.pose

    net = SensorNetworks(n_imus=5, n_joints=6, hidden=(16, 16, 16), seed=seed)
    net.set_input_scaling(torch.zeros(6), torch.as_tensor(rng.uniform(0.2, 2.0, size=6)))
    theta = torch.as_tensor(rng.normal(scale=2.0, size=(50, 6)), dtype=torch.float32)
    fused, generic = invariant_jacobian(net, theta), invariant_jacobian(PoseOnly(net), theta)
    assert tuple(fused.shape) == tuple(generic.shape) == (5, 50, 4, 6)
    assert torch.allclose(fused, generic, rtol=1e-4, atol=1e-6 * float(generic.abs().max()))


def test_loss_scale_is_one_per_sensor_type_not_per_imu(rng):
    # five IMUs; the first barely moves (a first link turning about the vertical near its axis)
    spreads = np.array([0.005, 1.0, 1.5, 2.0, 3.0])
    meas = torch.as_tensor(rng.normal(size=(5, 5000, 3)) * spreads[:, None, None], dtype=torch.float32)
    scale = float(robot_scale(meas, 1e-2))
    assert scale == pytest.approx(np.median(spreads), rel=0.05)
    assert float(robot_scale(meas * 0, 1e-2)) == pytest.approx(1e-2)


def test_more_steps_per_epoch_fit_better(rng):
    """The default batch (64) reaches a lower loss in the same epochs than large batches: the fit is
    limited by optimizer steps, which is why the default is small."""
    rec = random_robot_recording(rng, n_joints=3, seconds=20.0, imus_per_link=(2, 2)).derived()
    args = (rec.q, rec.qd, rec.qdd, rec.gyro, rec.acc, rec.gravity)
    _, small = train_sensor_networks(*args, hidden=(16, 16, 16), epochs=8, seed=0)
    _, large = train_sensor_networks(*args, hidden=(16, 16, 16), epochs=8, batch_size=1024, seed=0)
    assert small[-1] < 0.5 * large[-1]
