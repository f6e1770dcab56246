"""Warm starts of the sensor networks: training begins from a robot's earlier weights.

On one simulated robot recorded the way robots record (``robot`` sensing: encoder positions only,
quantized, on their own clock, a low-passed IMU), the networks trained on one window start the next
window's training. The warm run must learn the true tree, as the cold run on the first window does,
in fewer epochs than that cold run; weights of another shape must not be taken. (A cold run on the
second window too would triple the test's cost; ``bodyhealth bench warmstart`` compares warm and cold on
the same window.)
The robot, seed and windows are fixed: the test is deterministic (torch on one thread).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from bodyschema import dependency
from bodyschema.dependency import StableDependency
from bodyschema.estimate import fit_topology
from bodyschema.network_weights import NetworkWeights
from bodyschema.networks import SensorNetworks
from simulators.simulation import simulate

SEED = 1


@pytest.fixture(scope="module")
def windows():
    rec = simulate("paper-1", seconds=24.0, seed=3, sensing="robot")
    first, second = rec.select(rec.t < 12.0), rec.select(rec.t >= 12.0)
    return rec, first, second


@pytest.fixture(scope="module")
def cold(windows):
    """The cold run on the first window, whose weights start the warm runs."""
    return fit_topology(windows[1], "network", seed=SEED)


@pytest.mark.slow
def test_a_warm_start_learns_the_true_tree_in_fewer_epochs(windows, cold) -> None:
    rec, _, second = windows
    truth = (rec.truth_parent_map, rec.truth_imu_map)
    before = cold
    assert before.weights is not None and before.topology.training["warm"] == 0.0
    warm = fit_topology(second, "network", seed=SEED, warm_start=before.weights)
    assert warm.topology.training["warm"] == 1.0 and warm.topology.training["converged"] == 1.0
    assert (before.topology.joint_parent, before.topology.imu_joint) == truth
    assert (warm.topology.joint_parent, warm.topology.imu_joint) == truth
    assert warm.topology.training["epochs"] < before.topology.training["epochs"]
    # the weights are the warm run's own, not the ones it started from
    a, b = warm.weights.arrays["weights.0"], before.weights.arrays["weights.0"]
    assert a.shape == b.shape and not np.array_equal(a, b)


@pytest.mark.slow
def test_a_warm_start_reads_the_stored_weights_first_at_half_the_configurations(
    windows, cold, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The watcher sees the stored weights' reading of the new window (epoch -1), then one after each
    epoch, each at every other of the final reading's 1000 configurations; a healthy window's matrix is
    the same from the start, so training stops after three epochs."""
    _, _, second = windows
    seen: list[int] = []
    jacobians: list[int] = []
    watch, jacobian = StableDependency.__call__, dependency.invariant_jacobian

    def seen_watch(self: StableDependency, jbar: np.ndarray, epoch: int) -> bool:
        seen.append(epoch)
        return watch(self, jbar, epoch)

    def counted(net: object, theta: torch.Tensor) -> object:
        jacobians.append(theta.shape[0])
        return jacobian(net, theta)

    monkeypatch.setattr(StableDependency, "__call__", seen_watch)
    monkeypatch.setattr(dependency, "invariant_jacobian", counted)
    warm = fit_topology(second, "network", seed=SEED, warm_start=cold.weights)
    assert warm.topology.training["warm"] == 1.0 and warm.topology.training["epochs"] == 3
    assert seen == [-1, 0, 1, 2] and jacobians == [500, 500, 500, 500, 1000]
    assert (warm.topology.joint_parent, warm.topology.imu_joint) == (
        windows[0].truth_parent_map,
        windows[0].truth_imu_map,
    )


@pytest.mark.slow
def test_weights_of_another_shape_start_cold_and_say_so(windows, caplog) -> None:
    _, first, _ = windows
    other = NetworkWeights.from_model(SensorNetworks(first.n_imus + 1, first.n_joints, hidden=(32, 32, 32)))
    with caplog.at_level(logging.INFO, logger="bodyschema.networks"):
        fit = fit_topology(first, "network", seed=SEED, warm_start=other, epochs=2)
    assert fit.topology.training["warm"] == 0.0
    assert any("cold start" in r.getMessage() for r in caplog.records)


def test_training_stops_once_the_matrix_stayed_the_same_for_three_epochs() -> None:
    """Two IMUs, two joints: the first IMU hangs on joint 0, the second on both. A Jacobian whose
    second IMU loses joint 1 for one epoch resets the count; three unchanged epochs after it stop."""
    rng = np.random.default_rng(0)

    def jbar(second_on_1: bool) -> np.ndarray:
        j = np.abs(rng.normal(1.0, 0.05, size=(2, 200, 4, 2)))
        j[0, ..., 1] = 1e-4  # IMU 0 does not move with joint 1
        if not second_on_1:
            j[1, ..., 1] = 1e-4
        return j

    watch = StableDependency("moment", np.zeros(2, dtype=bool), lam=0.1, seed=0, epochs=3)
    seq = [True, True, False, True, True, True, True]
    stops = [watch(jbar(s), e) for e, s in enumerate(seq)]
    assert stops == [False, False, False, False, False, False, True] and watch.stopped_at == 6
