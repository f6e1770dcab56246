"""The geometry is judged only on one stretch of motion as long as its baseline's windows: after a
restart the first windows of the new clock epoch are short, and frames lost while the service was
down leave a hole; an estimate on either is not comparable with the baseline's (a restart mid-run
raised axis_changed on three healthy UR5e joints from a 6 s window)."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.metrics import Metrics
from service.monitor.drift import MAX_HOLE_SECONDS, GeometryDrift
from service.settings import Settings


def window(t: np.ndarray, t_q: np.ndarray | None = None) -> Recording:
    n, m = len(t), len(t if t_q is None else t_q)
    return Recording(
        t=t,
        t_q=t_q,
        joint_names=("j1",),
        q=np.zeros((m, 1)),
        imu_names=("i0",),
        acc=np.zeros((n, 1, 3)),
        gyro=np.zeros((n, 1, 3)),
    )


@pytest.fixture
def drift() -> GeometryDrift:
    settings = Settings(database_url="sqlite://", window_seconds=30.0)
    return GeometryDrift(None, settings, Metrics(), lambda f, *a: f(*a), lambda: 0.0)  # type: ignore[arg-type]


def test_a_full_continuous_window_is_one_motion(drift: GeometryDrift) -> None:
    assert drift.one_motion(window(np.arange(0.0, 30.0, 0.01)))


def test_a_short_window_after_a_restart_is_not(drift: GeometryDrift) -> None:
    assert not drift.one_motion(window(np.arange(0.0, 6.0, 0.01)))
    assert drift.one_motion(window(np.arange(0.0, 24.5, 0.01)))  # over 80 % of the window


def test_a_hole_in_either_stream_is_not(drift: GeometryDrift) -> None:
    t = np.arange(0.0, 30.0, 0.01)
    holed = np.concatenate([t[t < 10.0], t[t >= 10.0 + 2 * MAX_HOLE_SECONDS]])
    assert not drift.one_motion(window(holed))
    t_q = np.arange(0.0, 30.0, 0.004)
    assert drift.one_motion(window(t, t_q))
    q_holed = np.concatenate([t_q[t_q < 5.0], t_q[t_q >= 6.0]])
    assert not drift.one_motion(window(t, q_holed))
