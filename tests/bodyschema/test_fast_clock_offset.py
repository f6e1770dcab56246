"""Encoders on a clock hundreds of ms off the IMUs': the fast estimator follows the lag past its search
range (two free-running clocks 30 ppm apart drift 108 ms an hour) and learns the same tree."""

from __future__ import annotations

import dataclasses

import pytest

from bodyschema.estimate import estimate_topology
from simulators.farm import Farm


@pytest.fixture(scope="module")
def window():
    return Farm({"r": "ur5e"}, seed=0, sensing="robot").advance(30.0)["r"]


@pytest.mark.parametrize("offset", [0.25, -0.4])
def test_lag_past_the_search_range_is_followed(window, offset: float) -> None:
    base = estimate_topology(window, method="fast")
    moved = estimate_topology(dataclasses.replace(window, t_q=window.t_q + offset), method="fast")
    assert base.joint_parent == moved.joint_parent == window.truth_parent_map
    assert base.imu_joint == moved.imu_joint == window.truth_imu_map
    # encoder stamps later by ``offset``: the IMU lags the stamps by that much less
    assert moved.timing["lag_ms"] == pytest.approx(base.timing["lag_ms"] - 1e3 * offset, abs=1.0)
    assert abs(base.timing["lag_ms"]) < 100.0  # the usual case: one search, as before
