"""The sensor networks train to convergence, on data logged the way real robots log it.

Multi-rate recordings (position-only encoders on their own clock, a low-passed IMU with a skew) are
aligned by the fast estimator's lag before the networks see them
(:func:`bodyschema.timing.aligned_recording`), and training stops on a flat loss instead of after a
fixed count (:func:`bodyschema.networks.train_sensor_networks`).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from bodyschema.estimate import estimate_topology
from bodyschema.networks import train_sensor_networks
from bodyschema.threads import set_torch_threads
from simulators.random_robot import random_robot
from simulators.sensing import apply_sensing
from simulators.simulation import Simulation

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread() -> Iterator[None]:
    import torch

    before = torch.get_num_threads()
    set_torch_threads(1)
    yield
    set_torch_threads(before)


def _robot_preset_recording(seed: int, n_joints: int, seconds: float):
    ss = np.random.SeedSequence(seed)
    robot_ss, sim_ss, sense_ss = ss.spawn(3)
    robot = random_robot(np.random.default_rng(robot_ss), n_joints, rate=1000.0)
    fine = Simulation(robot, seed=sim_ss, rate=1000.0).advance(seconds=seconds)
    return fine, apply_sensing(fine, "robot", np.random.default_rng(sense_ss))


def test_network_on_a_multirate_random_robot_is_exact_and_reports_its_epochs(seed):
    fine, rec = _robot_preset_recording(seed, 6, 40.0)
    topo = estimate_topology(rec, "network", seed=1)
    assert topo.joint_parent == fine.truth_parent_map
    assert topo.imu_joint == fine.truth_imu_map
    assert topo.unique and not topo.undetermined
    # trained to a flat loss, well inside the bound, and said so in the JSON
    assert topo.training["converged"] == 1.0
    assert 10 <= topo.training["epochs"] < 200
    assert topo.to_json()["training"]["epochs"] == topo.training["epochs"]
    # the lag the networks were aligned by: skew 8 ms + 30 ppm drift to the middle, within 1 ms
    truth_ms = 8.0 + 30e-3 * topo.timing["at_s"]
    assert abs(topo.timing["skew_ms"] - truth_ms) < 1.0


def test_training_stops_on_a_flat_loss_not_at_a_count(seed):
    fine, _ = _robot_preset_recording(seed, 3, 20.0)
    d = fine.select(slice(None, None, 10)).derived()
    _, hist = train_sensor_networks(d.q, d.qd, d.qdd, d.gyro, d.acc, d.gravity, seed=0, max_epochs=200)
    assert len(hist) < 200
    # the last epochs improved by less than the plateau tolerance over the patience window
    tail = np.array(hist[-4:])
    assert (tail[0] - tail.min()) / tail[0] < 0.05
    # and the loss fell a long way before that: not a run that stopped at once
    assert hist[-1] < 0.2 * hist[0]
    _, fixed = train_sensor_networks(d.q, d.qd, d.qdd, d.gyro, d.acc, d.gravity, seed=0, epochs=7)
    assert len(fixed) == 7
