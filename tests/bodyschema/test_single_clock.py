"""Single-clock recordings without measured velocities (one ``t``, positions ``q``, no ``qd``, no ``t_q``).

docs/recording-format.md promises that such a file loads exactly as before; the fast estimator must then
read it as encoders sampled at the IMU stamps (``t_q = t``), through the timed path: central-difference
velocities are about 2 % off the true ones at 100 Hz (docs/design.md §3) and fail every synced test.

Each case is a multi-rate recording of the ``robot`` sensing preset (14-bit encoders at 250 Hz on their
own clock, MPU-6050 errors, 42 Hz low-pass, 8 ms skew, 30 ppm drift) and its single-clock form,
:meth:`Recording.synced` (the encoder positions interpolated at the IMU stamps, as a logger that stamps
every stream on one clock writes them). The two carry the same information up to cubic interpolation of
250 Hz positions inside a 10 Hz band (about 1e-4 relative, :mod:`bodyschema.timing`), so the single-clock
answers must agree with the multi-rate ones far inside the estimates' own reported stds, and both must
meet the truth within the error model of tests/bodyschema/test_kinematics.py (5 stds plus a floor).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from bodyschema.diff import UNDETERMINED_HERE, diff_bodies, open_parts
from bodyschema.estimate import estimate_topology
from bodyschema.fast import fast_fit
from bodyschema.health import signal_health
from bodyschema.kinematics import Kinematics, estimate_kinematics
from bodyschema.recording import Recording
from simulators.kinematics_truth import ImuTruth, axis_error_deg, kinematics_truth
from simulators.random_robot import random_robot
from simulators.sensing import apply_sensing
from simulators.simulation import Simulation

SECONDS = 20.0
#: The floors of tests/bodyschema/test_kinematics.py for the MPU-6050 model: the gyro's lean left in
#: the axis, 3 % accelerometer gain on lever arms up to 0.15 m.
AXIS_FLOOR_DEG, LEVER_FLOOR_M = 0.2, 4.5e-3


@dataclass(frozen=True)
class Pair:
    multi: Recording
    single: Recording
    truth: dict[str, ImuTruth]


def _single_clock(rec: Recording) -> Recording:
    single = rec.synced()
    assert single.t_q is None and single.qd is None and single.q is not None
    return single


@pytest.fixture(scope="module")
def pair() -> Pair:
    robot = random_robot(np.random.default_rng(3), 5, rate=1000.0)
    fine = Simulation(robot, seed=1, rate=1000.0).advance(seconds=SECONDS)
    rec = apply_sensing(fine, "robot", np.random.default_rng(1001))
    return Pair(multi=rec, single=_single_clock(rec), truth=kinematics_truth(robot))


def test_the_single_clock_form_gives_the_multirate_tree_and_lag(pair: Pair) -> None:
    multi, single = estimate_topology(pair.multi), estimate_topology(pair.single)
    assert fast_fit(pair.single).path == "timed"
    for topo in (multi, single):
        assert topo.unique and not topo.undetermined
        assert topo.joint_parent == pair.multi.truth_parent_map
        assert topo.imu_joint == pair.multi.truth_imu_map
    # the skew is still estimated: the IMU data lag the positions stamped with them by the same amount
    # (8 ms skew + 4.8 ms filter delay + drift); the lag search is good to a quarter ms
    assert abs(single.timing["lag_ms"] - multi.timing["lag_ms"]) < 0.25
    assert 10.0 < single.timing["lag_ms"] < 16.0


def _placed(kin: Kinematics, truth: dict[str, ImuTruth]) -> dict[str, tuple[float, float]]:
    """Every IMU on a moving link has an axis and a lever arm on its true joint: name -> errors."""
    out = {}
    for name, t in truth.items():
        k = kin.imus[name]
        if t.joint is None:
            assert k.joint is None and k.reason.startswith("on the base"), name
            continue
        assert k.joint == t.joint and k.axis is not None and k.lever_arm is not None, (name, k.reason)
        assert t.axis is not None and t.lever_arm is not None
        out[name] = (axis_error_deg(k.axis, t.axis), float(np.linalg.norm(k.lever_arm - t.lever_arm)))
    return out


@pytest.mark.slow
def test_kinematics_on_the_single_clock_form_places_every_imu(pair: Pair) -> None:
    multi, single = estimate_kinematics(pair.multi), estimate_kinematics(pair.single)
    err_m, err_s = _placed(multi, pair.truth), _placed(single, pair.truth)
    assert err_s.keys() == err_m.keys() and len(err_s) >= 5
    assert abs(single.lag_ms - multi.lag_ms) < 0.25
    for name, (ea, el) in err_s.items():
        k, m = single.imus[name], multi.imus[name]
        assert ea < 5 * k.axis_std_deg + AXIS_FLOOR_DEG, (name, ea)
        assert el < 5 * k.lever_arm_std_m + LEVER_FLOOR_M, (name, el)
        # the same information: the two answers agree far inside one reported std
        assert axis_error_deg(k.axis, m.axis) < 0.5 * m.axis_std_deg, name
        assert np.linalg.norm(k.lever_arm - m.lever_arm) < 0.5 * m.lever_arm_std_m, name


@pytest.mark.slow
def test_diff_of_an_imu_moved_pair_in_single_clock_form_finds_it() -> None:
    robot = random_robot(np.random.default_rng(3), 5, rate=1000.0)
    sim = Simulation(robot, seed=2, rate=1000.0)
    base_fine = sim.advance(seconds=SECONDS)
    truth = sim.apply_damage("imu_moved", imu="imu3", to="j1").findings[0]
    cur_fine = sim.advance(seconds=SECONDS)
    rng = np.random.default_rng(7)
    base_rec = _single_clock(apply_sensing(base_fine, "robot", rng))
    cur_rec = _single_clock(apply_sensing(cur_fine, "robot", rng))
    base, cur = estimate_topology(base_rec), estimate_topology(cur_rec)
    assert base.unique and cur.unique
    diff = diff_bodies(base, cur, signal_health(cur_rec, base, current=cur))
    assert diff.changed is True
    assert [(f.kind, f.imu, f.from_, f.to) for f in diff.findings] == [
        ("imu_moved", "imu3", truth.from_, "j1")
    ]


@pytest.mark.slow
def test_an_undetermined_tree_is_said_so_never_placed_on_the_base() -> None:
    # a chain j1 -> j2 -> j3 with the IMUs of j2's link left out: j2 and j3 can hang either way round,
    # so the IMUs below ride j3 in one tree and j2 in the other (completion, paper III-F/G)
    robot = random_robot(np.random.default_rng(5), 5, rate=1000.0)
    rec = apply_sensing(
        Simulation(robot, seed=1, rate=1000.0).advance(seconds=SECONDS), "robot", np.random.default_rng(3)
    )
    assert rec.truth_parent_map is not None and rec.truth_parent_map["j3"] == "j2"
    keep = [k for k, j in enumerate(rec.truth_imu_joint) if j != "j2"]
    cut = _single_clock(
        replace(
            rec,
            imu_names=[rec.imu_names[k] for k in keep],
            acc=rec.acc[:, keep],
            gyro=rec.gyro[:, keep],
            truth_imu_joint=[rec.truth_imu_joint[k] for k in keep],
        )
    )
    topo = estimate_topology(cut)
    assert not topo.unique and topo.candidates
    diff = diff_bodies(topo, topo, signal_health(cut, topo, current=topo))
    assert diff.changed is None and not diff.findings
    assert any("j2" in r and "j3" in r and "move" in r for r in diff.reasons)
    kin = estimate_kinematics(cut, topo)
    open_ = open_parts(topo)
    checked = 0
    for name, k in kin.imus.items():
        if f"imu:{name}" in open_ or f"joint:{k.joint}" in open_:
            assert k.reason.startswith(UNDETERMINED_HERE) and "on the base" not in k.reason, (name, k.reason)
            assert k.axis is None
            checked += 1
    assert checked >= 1


def test_a_lag_hint_moves_a_single_clock_recordings_encoders_too(pair: Pair) -> None:
    from bodyschema.timing import encoders_moved, lag_hinted

    moved = encoders_moved(pair.single, 0.05)
    assert moved.t_q is not None and np.array_equal(moved.t_q, pair.single.t + 0.05)
    hinted = lag_hinted(estimate_topology, pair.single, 0.05)  # the search centred 50 ms off the lag
    assert hinted.joint_parent == pair.multi.truth_parent_map
    assert abs(hinted.timing["lag_ms"] - estimate_topology(pair.single).timing["lag_ms"]) < 0.25
