"""Excitations: the paper's random torque, Table I sines, motion that shows every joint."""

from __future__ import annotations

import numpy as np
import pytest

from simulators.excitation import TABLE_I_FREQS, TABLE_I_PHASES, excitation_rms, make_excitation
from simulators.robot import Robot


def _run(name: str, excitation: str, seconds: float, rng: np.random.Generator):
    robot = Robot.from_catalog(name)
    exc = make_excitation(excitation).bind(robot, rng)
    t = np.arange(int(seconds * robot.rate)) / robot.rate
    return robot, exc, robot.sample(exc.ctrl(robot, t))


def test_random_torque_is_piecewise_constant_uniform(rng: np.random.Generator) -> None:
    robot = Robot.from_catalog("paper-1")
    exc = make_excitation("random-torque").bind(robot, rng)
    t = np.arange(1000) / 100.0
    tau, _, _ = exc.targets(t)
    seg = (t / 0.2 + 1e-9).astype(int)
    for s in range(3):
        block = tau[seg == s]
        assert np.all(block == block[0])  # renewed every 0.2 s, constant in between
    assert not np.allclose(tau[seg == 0][0], tau[seg == 1][0])
    u = tau / exc.bound_
    assert np.all(np.abs(u) <= 1) and abs(u.mean()) < 0.2 and 0.45 < u.std() < 0.7  # uniform: std 1/sqrt(3)


def test_sine_tracks_table_one_velocities(rng: np.random.Generator) -> None:
    robot, _, s = _run("ur5e", "sine", 6.0, rng)
    want = 0.2 * np.sin(2 * np.pi * np.outer(s.t, TABLE_I_FREQS) + np.array(TABLE_I_PHASES))
    late = s.t > 1.0
    assert np.abs(s.qd[late] - want[late]).max() < 0.05
    assert robot.warnings() == {}


@pytest.mark.parametrize("name", ["humanoid", "quadruped", "dual-arm", "ur5e", "paper-4"])
def test_observable_moves_every_joint(name: str, rng: np.random.Generator) -> None:
    robot, _, s = _run(name, "observable", 6.0, rng)
    rms = excitation_rms(s.qd)
    assert rms.min() > 0.1, dict(zip(robot.joint_names, rms.round(3), strict=True))
    assert robot.warnings() == {}


def test_observable_excites_more_evenly_than_random_torque(rng: np.random.Generator) -> None:
    seed = int(rng.integers(2**31))
    _, _, rt = _run("humanoid", "random-torque", 6.0, np.random.default_rng(seed))
    _, _, ob = _run("humanoid", "observable", 6.0, np.random.default_rng(seed))
    spread = lambda x: excitation_rms(x.qd).max() / excitation_rms(x.qd).min()  # noqa: E731
    assert spread(ob) < spread(rt)


def test_hold_stays_still_and_unknown_names_fail(rng: np.random.Generator) -> None:
    _, _, s = _run("quadruped", "hold", 1.0, rng)
    assert np.abs(s.qd).max() < 1e-3
    with pytest.raises(ValueError, match="observable"):
        make_excitation("dance")
