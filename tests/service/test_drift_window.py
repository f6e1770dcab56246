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
from service.monitor.state import RobotState
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
    states: dict[str, RobotState] = {}
    state = lambda robot: states.setdefault(robot, RobotState())  # noqa: E731
    return GeometryDrift(None, settings, Metrics(), lambda f, *a: f(*a), lambda: 0.0, state)  # type: ignore[arg-type]


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


def _turns(drift: GeometryDrift, ends: list[float]) -> list[int]:
    """The cycles on which the robot's geometry is due when cycle k's window ends at ``ends[k]``
    (each due estimate taken, as :meth:`GeometryDrift.judge` does)."""
    due = []
    for cycle, end in enumerate(ends):
        if drift.turn("r", cycle, end):
            drift.state("r").geometry_last = (cycle, end)
            due.append(cycle)
    return due


def test_the_turn_follows_the_data_not_the_wall_clock(drift: GeometryDrift) -> None:
    """Every N cycles while each cycle advances the data by one interval, however long the cycle took
    in wall time (a test or a replay feeding data faster than real time gets the same estimates); when
    cycles overrun, so that each brings two intervals of data, every N intervals of data instead."""
    n, dt = drift.settings.kinematics_interval_cycles, drift.settings.worker_interval_seconds
    first = next(c for c in range(n) if drift.turn("r", c, 0.0))
    paced = _turns(drift, [c * dt for c in range(4 * n)])
    assert paced == [first + k * n for k in range(4) if first + k * n < 4 * n]
    drift.state("r").geometry_last = None
    slow = _turns(drift, [2 * c * dt for c in range(4 * n)])
    steps = np.diff(slow)
    assert len(steps) and set(steps.tolist()) == {-(-n // 2)}
    drift.state("r").geometry_last = (10, 1e6)  # the robot's clock went back: staggered, as at the start
    again = first + n * (10 // n + 1)
    assert drift.turn("r", again, 5.0)
    assert not drift.turn("r", again + 1, 5.0)
