"""Coarse encoders on the timed path: the derived rate's error per joint (crossings per sample), the
tests' floors per model, and a joint moving a third of a count per sample tested and placed right."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema import timing as tm
from bodyschema.fast_core import FastOptions, _fit, _TimedTerms, noise_level

COUNT_12 = 2 * np.pi / 4096


def test_encoder_count_is_the_lattice_the_positions_sit_on():
    t = np.arange(3000) / 100.0
    x = 0.3 * np.sin(0.7 * t) + 0.1 * np.sin(2.3 * t + 1)
    q12 = np.round(x / COUNT_12) * COUNT_12
    rng = np.random.default_rng(0)
    counts = tm.encoder_count(np.stack([q12, x, q12 + rng.normal(0, 1e-5, t.size)], axis=1))
    assert counts[0] == pytest.approx(COUNT_12, rel=1e-9)
    assert counts[1] == 0.0 and counts[2] == 0.0  # no lattice: off-lattice values or noise after it


def test_rate_noise_is_the_white_figure_for_a_joint_that_crosses_counts_every_sample():
    t = np.arange(6000) / 100.0
    x = 0.4 * np.sin(2 * np.pi * 0.5 * t) + 0.2 * np.sin(2 * np.pi * 0.31 * t)  # >= 1 count per sample
    q = (np.round(x / COUNT_12) * COUNT_12)[:, None]
    white = tm.derivative_noise(tm.position_noise(q), 100.0, 10.0)
    ratio = float(tm.rate_noise(q, 100.0, 10.0)[0] / white[0])
    moved = float(np.mean(np.minimum(np.abs(np.diff(q[:, 0])) / COUNT_12, 1.0)))
    assert ratio == pytest.approx(np.sqrt(moved), rel=1e-9)
    assert 0.9 < ratio <= 1.0  # only the samples about the turnarounds move less than a count


def test_rate_noise_scales_the_white_figure_by_the_counts_crossed_per_sample():
    t = np.arange(6000) / 100.0
    x = 0.15 * np.sin(2 * np.pi * 0.05 * t)  # 0.47 rad/s at most: under a count (0.15 rad/s) per sample
    q = (np.round(x / COUNT_12) * COUNT_12)[:, None]
    steps = np.abs(np.diff(q[:, 0])) / COUNT_12
    assert steps.max() <= 1.0 + 1e-9
    expected = tm.derivative_noise(tm.position_noise(q), 100.0, 10.0) * np.sqrt(steps.mean())
    np.testing.assert_allclose(tm.rate_noise(q, 100.0, 10.0), expected, rtol=1e-12)


def _two_links(T: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two links, the second on an x-hinge of the first: it moves 0.03 rad/s relative to it."""
    rng = np.random.default_rng(3)
    t = np.arange(T) / 100.0
    q = np.stack([np.sin(0.9 * t), 0.05 * np.cos(0.6 * t + 1)], 1)
    qd = np.stack([0.9 * np.cos(0.9 * t), -0.03 * np.sin(0.6 * t + 1)], 1)
    w1 = np.stack([0 * t, 0 * t, qd[:, 0]], 1)
    c, s = np.cos(q[:, 1]), np.sin(q[:, 1])
    w2 = np.stack([qd[:, 1], s * w1[:, 2], c * w1[:, 2]], 1)
    gyro = np.stack([w1, w2], 1) + rng.normal(scale=1e-4, size=(T, 2, 3))
    return q, qd, gyro


def test_a_derived_rate_error_enters_the_gyro_only_tests_per_channel():
    """A joint's derived rate error n enters a model as e n over three channels: n² / 3 per channel.
    The hinge models carry their own joint's; the gyro-only tests (on base, same link) the largest.
    The old form, n² in every floor, merged two links that the gyros tell apart."""
    q, qd, gyro = _two_links()
    n2 = 3e-5  # the second joint's derived rate: 5.5 mrad/s of error

    def groups(floor_add: float, rate_var: float) -> list[int]:
        timed = _TimedTerms(
            apply=lambda x, axis=-1: x,
            sigma=noise_level(gyro),
            floor_add=np.full(2, floor_add),
            rate_var=np.array([0.0, rate_var]),
            n_eff=1.0,
            undetermined=np.zeros(2, dtype=bool),
        )
        return _fit(q, qd, gyro, FastOptions(), timed).group.tolist()

    assert groups(0.0, n2 / 3) == [0, 1]
    assert groups(n2, 0.0) == [0, 0]


@pytest.mark.slow
def test_a_slow_joint_on_12_bit_encoders_is_tested_and_placed_right():
    """A generated robot (``bench shapes`` robot 28) whose joint j04 moves 0.05 rad/s, a third of a
    12-bit count per 100 Hz sample: its derived rate's error is the crossings' figure, not the white
    one (checked against the same robot's unquantized positions), and it is tested and placed in
    both recording shapes."""
    from bench.generator import GeneratorOptions, generate
    from bench.generator_sensing import SensingSpec
    from bodyschema.estimate import estimate_topology

    opts = GeneratorOptions(joints=(5, 20), seconds=60.0, sensing=SensingSpec(encoder_bits=12))
    gen = generate(28, opts)
    raw = generate(28, GeneratorOptions(joints=(5, 20), seconds=60.0))
    j = gen.multi.joint_names.index("j04")
    q, q0 = gen.multi.q, raw.multi.q
    err = tm.lowpass(q, 100.0, 10.0, derivative=True) - tm.lowpass(q0, 100.0, 10.0, derivative=True)
    true_err = float(np.sqrt(np.mean(err[300:-300, j] ** 2)))
    white = float(tm.derivative_noise(tm.position_noise(q), 100.0, 10.0)[j])
    assert tm.rate_noise(q, 100.0, 10.0)[j] == pytest.approx(true_err, rel=0.1)
    assert white > 1.6 * true_err
    for rec in (gen.multi, gen.single):
        topo = estimate_topology(rec, "fast")
        assert topo.unique and not topo.undetermined
        assert topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map
