"""The two predictions' clocks: the lag between them recovered with an honest interval, and the
closure of the IMU's two offsets over it (sim2real.robot_clocks)."""

from __future__ import annotations

import numpy as np

from sim2real.robot_clocks import clock_closure, prediction_lag


def _walk(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A base's angular velocity: a few gait harmonics with drifting amplitude (T, 3)."""
    amp = 1.0 + 0.3 * np.sin(0.1 * t)[:, None]
    return amp * np.stack(
        [np.sin(2 * np.pi * f * t + p) for f, p in zip((0.9, 1.8, 0.45), rng.uniform(0, 6, 3), strict=True)],
        1,
    )


def test_the_lag_between_two_predictions_is_found_with_its_interval() -> None:
    """Seeds 0-19: a 3 ms lag under white noise is found, and the 95 % intervals hold it in at least
    17 of 20 (a binomial 20 at 0.95 gives fewer than 17 with probability 0.016)."""
    t = np.arange(0, 40, 0.01)
    held, errors = 0, []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        w = _walk(t, rng)
        late = np.stack([np.interp(t - 0.003, t, w[:, i]) for i in range(3)], 1)
        lag = prediction_lag(t, late + rng.normal(0, 0.05, w.shape), w, np.ones(t.size, bool))
        lo, hi = lag["interval_s"]
        held += lo <= 0.003 <= hi
        errors.append(lag["estimate_s"] - 0.003)
    assert held >= 17
    assert np.max(np.abs(errors)) < 1e-3


def test_clocks_close_when_the_offsets_differ_by_the_lag() -> None:
    offsets = {
        "encoders": {"estimate": [0.0037], "stderr": [0.0006]},
        "mocap": {"estimate": [0.0001], "stderr": [0.0008]},
    }
    lag = {"estimate_s": -0.0030, "stderr_s": 0.0005, "interval_s": [-0.0042, -0.0018]}
    out = clock_closure(offsets, lag)
    assert abs(out["offsets_difference_s"] + 0.0036) < 1e-12 and out["closes"]
    assert abs(out["gap_s"] - 0.0006) < 1e-12
    # the same offsets against predictions on one clock: a gap of 3.6 ms is 3.3 standard errors
    one_clock = clock_closure(offsets, {**lag, "estimate_s": 0.0})
    assert not one_clock["closes"]
