"""Health on the measured floating-base robots: untouched windows give no finding, injected faults are
found with the right kind first (baseline: the log's first half; windows: 10 s of its second half)."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.faults import inject, parse_fault
from bodyschema.floating_health import floating_baseline, floating_diff
from tests.robot_data import MAPS, ROBOTS

LOGS = {
    "icub": (ROBOTS / "icub-walking" / "sync-walkingFrontAndBackGoodTrial.mat", "icub-walking.toml", "mat"),
    "go1": (ROBOTS / "go1-trot" / "go1.csv", "go1-trot.toml", "csv"),
}

pytestmark = pytest.mark.slow


def _split(name: str):
    from sim2real.robot_logs import import_log

    path, mp, fmt = LOGS[name]
    if not path.is_file():
        pytest.skip(f"robot log missing: {path}")
    rec = import_log(path, MAPS / mp, fmt)[0]
    half = rec.t[0] + rec.duration / 2
    starts = np.arange(half, rec.t[-1] - 10 + 1e-9, 10.0)
    return rec, floating_baseline(rec.window(rec.t[0], half)), [rec.window(s, s + 10) for s in starts]


@pytest.fixture(scope="module")
def icub():
    return _split("icub")


@pytest.fixture(scope="module")
def go1():
    return _split("go1")


def _first(base, win, spec: str):
    d = floating_diff(base, inject(win, parse_fault(spec)))
    assert d.findings, f"{spec}: nothing found"
    return d.findings[0]


@pytest.mark.parametrize("robot", ["icub", "go1"])
def test_untouched_halves_and_windows_give_no_finding(robot, request):
    rec, base, _ = request.getfixturevalue(robot)
    half = rec.t[0] + rec.duration / 2
    assert floating_diff(base, rec.window(half, rec.t[-1] + 1)).to_json() == {
        "changed": False,
        "findings": [],
    }
    starts = np.arange(rec.t[0], rec.t[-1] - 10 + 1e-9, 10.0)  # every 10 s window, the baseline's too
    assert len(starts) >= 2
    for s in starts:
        assert floating_diff(base, rec.window(s, s + 10)).findings == (), s


@pytest.mark.parametrize(
    ("robot", "joints"), [("icub", ("r_hip_roll", "l_knee")), ("go1", ("RL_thigh", "FR_calf"))]
)
def test_frozen_encoder_named_first(robot, joints, request):
    _, base, wins = request.getfixturevalue(robot)
    for j in joints:
        f = _first(base, wins[0], f"encoder_frozen:joint={j},at=2")
        assert (f.kind, f.joint) == ("encoder_fault", j)
    # the frozen knee also tilts its stance foot; the tilt that the knee is among the causes of is the
    # same fault, not a second finding on a joint beside it
    if robot == "icub":
        d = floating_diff(base, inject(wins[0], parse_fault("encoder_frozen:joint=l_knee,at=2")))
        assert [f.part for f in d.findings] == ["joint:l_knee"], d.findings


def test_sign_flip_over_a_whole_window_found_on_the_stance_chain(icub):
    _, base, wins = icub
    for j in ("r_hip_roll", "r_knee"):
        f = _first(base, wins[0], f"encoder_sign:joint={j}")
        assert (f.kind, f.joint) == ("encoder_fault", j)


@pytest.mark.parametrize(
    ("robot", "joints"), [("icub", ("r_knee", "l_knee")), ("go1", ("RL_calf", "FR_calf"))]
)
def test_sign_flip_mid_window_found_as_a_jump(robot, joints, request):
    _, base, wins = request.getfixturevalue(robot)
    for j in joints:
        f = _first(base, wins[0], f"encoder_sign:joint={j},at=3")
        assert (f.kind, f.joint) == ("encoder_fault", j)


@pytest.mark.parametrize("robot", ["icub", "go1"])
def test_silent_imu_found_as_dead(robot, request):
    rec, base, wins = request.getfixturevalue(robot)
    imu = rec.imu_names[0]
    for w in wins[:2]:
        f = _first(base, w, f"imu_silent:imu={imu},seconds=2,at=3")
        assert (f.kind, f.imu) == ("imu_dead", imu)


def test_offset_found_from_the_stance_feet_gravity(icub):
    """A knee (pitch axis) offset tilts the sagittal plane, where the baseline's spread is small: found
    in both windows, on the knee alone. The ankle roll's axis is parallel to the hip roll's in these
    stances, so an offset on either tilts the stance foot alike and both fit within the error model:
    the damage is decided, its joint is not, and the finding says so (both parts, at a confidence that
    is not sure, and what would decide) instead of naming the one that rounding puts first."""
    _, base, wins = icub
    for w in wins[:2]:
        f = _first(base, w, "encoder_offset:joint=l_knee,deg=2")
        assert (f.kind, f.joint, f.candidates) == ("encoder_fault", "l_knee", ())
        assert "offset +" in f.detail
    rolls = {"joint:r_hip_roll", "joint:r_ankle_roll"}
    f = _first(base, wins[1], "encoder_offset:joint=r_hip_roll,deg=2")
    assert f.kind == "encoder_fault" and {f.part, *f.candidates} == rolls, f
    assert "undetermined between them" in f.detail and "would decide" in f.detail
    assert f.confidence < 0.9
    # in the first window the T² is smaller: found or not, never another kind or another leg's joint
    for f in floating_diff(
        base, inject(wins[0], parse_fault("encoder_offset:joint=r_hip_roll,deg=2"))
    ).findings:
        assert f.kind == "encoder_fault" and {f.part, *f.candidates} <= rolls, f


def test_rotated_imu_found_from_the_stance_feet_gravity(icub):
    rec, base, wins = icub
    imu = rec.imu_names[0]
    for w in wins[:2]:
        f = _first(base, w, f"imu_rotated:imu={imu},deg=2")
        assert (f.kind, f.imu) == ("imu_rotated", imu)


def test_tilt_statistic_does_not_follow_the_last_bits_of_the_input(icub):
    """The stance chains' axes, which the tilt check turns the feet's gravity with, are fitted to
    convergence: a relative change of 1e-13 in the gyro (another CPU's rounding) moves a faulted
    window's T² by under 1e-5 of itself. Stopped at 1 % of the cost, the fit moved it from 586 to 218."""
    import dataclasses

    from bodyschema.floating_health import FloatingOptions
    from bodyschema.stance_chains import foot_forces
    from bodyschema.stance_tilt import tilt_test

    rec, base, wins = icub
    half = rec.t[0] + rec.duration / 2
    nudged = dataclasses.replace(rec, gyro=rec.gyro * (1 + 1e-13))
    w = inject(wins[0], parse_fault("encoder_sign:joint=r_hip_roll,at=3"))
    t2 = []
    for b in (base, floating_baseline(nudged.window(rec.t[0], half))):
        assert b.tilt is not None and b.force_threshold is not None
        down = foot_forces(w)[0] > b.force_threshold
        t2.append(tilt_test(b.tilt, w.q, w.acc[:, 0], down, w.sample_rate, FloatingOptions().tilt)[0])
    assert t2[0] > 100 and abs(t2[1] - t2[0]) < 1e-5 * t2[0], t2


def test_go1_has_no_flat_foot_tilt_model(go1):
    """Point feet fix no rotation: no stance chain, so no leg predicts gravity and a 2 deg offset or
    mount turn stays unseen (reported undetermined by the bench, not faked)."""
    rec, base, wins = go1
    assert base.chains == () and base.tilt is None
    bad = inject(wins[0], parse_fault(f"imu_rotated:imu={rec.imu_names[0]},deg=2"))
    assert floating_diff(base, bad).findings == ()


def test_go1_feet_plane_moves_more_on_a_healthy_trot_than_under_a_2deg_fault(go1):
    """With the URDF the point feet's plane is a gravity reference. It reads a 2 deg mount turn about the
    IMU's x axis as the 2 deg it is; but between the log's two halves the healthy trot moves the plane's
    tilt further than any 2 deg fault does, so a 10 s window cannot tell them: undetermined is the
    measured answer, not a missing check."""
    from sim2real.foot_plane import foot_plane_tilt
    from sim2real.robots import read_robot

    rec, _, _ = go1
    imu = rec.imu_names[0]
    specs = (
        f"imu_rotated:imu={imu},deg=2",
        "encoder_offset:joint=FR_calf,deg=2",
        "encoder_offset:joint=RL_thigh,deg=2",
    )
    got = foot_plane_tilt(rec, read_robot(ROBOTS / "go1-trot" / "go1.urdf", rec.joint_names), specs)
    shift = got["fault_shift_deg"]
    assert 1.9 <= shift[specs[0]] <= 2.05
    assert max(shift.values()) < got["halves_change_norm_deg"]
