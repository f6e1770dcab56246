"""Signal health on synthetic gyro/encoder data of a small branching robot.

The robot (:data:`tests.builders.LAYOUT`): j1 (z axis) on the base, j2 (y axis) and j3 (x axis) both
under j1. Link gyros follow the rigid-body relation ω_child = R(q)ᵀ ω_parent + axis·q̇ exactly, plus
MPU-6050-like noise and bias (:func:`tests.builders.synth`), so a wrong judgement here is the code's
fault, not the data's.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodyschema.health import HealthThresholds, imu_health, relative_motion, signal_health
from bodyschema.impacts import drop_impacts
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from tests.builders import AXES, LAYOUT, rot_about, synth


def test_healthy_robot_is_all_ok(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng), LAYOUT)
    assert {n: j.state for n, j in h.joints.items()} == {"j1": "ok", "j2": "ok", "j3": "ok"}
    assert h.dead_imus == []
    assert all(j.explained is not None and j.explained > 0.95 for j in h.joints.values())
    assert all(j.excitation > 0.3 for j in h.joints.values())


def test_locked_joint_is_still(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng, locked="j2"), LAYOUT)
    assert h.joints["j2"].state == "still"
    assert h.joints["j2"].relative_motion < 0.05
    assert h.joints["j1"].state == h.joints["j3"].state == "ok"


def test_frozen_encoder_while_link_turns(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng, frozen_encoder="j3"), LAYOUT)
    assert h.joints["j3"].state == "frozen_encoder"
    assert h.joints["j3"].relative_motion > 0.3
    assert h.joints["j1"].state == h.joints["j2"].state == "ok"


def test_wrong_encoder_is_caught(rng: np.random.Generator) -> None:
    rec = synth(rng)
    q = rec.q.copy()
    q[:, 1] = np.roll(q[:, 2], 700)  # the encoder reports some other motion
    h = signal_health(
        Recording(
            t=rec.t, joint_names=rec.joint_names, q=q, imu_names=rec.imu_names, acc=rec.acc, gyro=rec.gyro
        ),
        LAYOUT,
    )
    assert h.joints["j2"].state == "wrong_encoder"
    # below the threshold; how far below depends on the draw: the other joint's motion, shifted by 7 s,
    # is a sum of slow sines and can share much of j2's (0.66 explained on one draw)
    assert h.joints["j2"].explained < HealthThresholds().explained


def test_lost_link_is_unfollowed(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng, lost="j2"), LAYOUT)
    assert h.joints["j2"].state == "unfollowed"
    assert h.joints["j1"].state == "ok"


def test_one_detached_imu_does_not_fault_the_encoder(rng: np.random.Generator) -> None:
    rec = synth(rng)
    gyro = rec.gyro.copy()
    gyro[:, 2] = rng.normal(0, 0.005, gyro[:, 2].shape) + 0.1  # b1 came off and lies still
    h = signal_health(
        Recording(
            t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=rec.imu_names, acc=rec.acc, gyro=gyro
        ),
        LAYOUT,
    )
    assert h.joints["j2"].state == "ok"


@pytest.mark.parametrize("kind", ["zero", "frozen", "silent"])
def test_dead_imus(rng: np.random.Generator, kind: str) -> None:
    rec = synth(rng)
    acc, gyro, names = rec.acc.copy(), rec.gyro.copy(), rec.imu_names
    if kind == "zero":
        acc[:, 3] = 0.0
        gyro[:, 3] = 0.0
    elif kind == "frozen":
        acc[:, 3] = acc[0, 3]
        gyro[:, 3] = gyro[0, 3]
    else:
        keep = [0, 1, 2, 4]
        acc, gyro, names = acc[:, keep], gyro[:, keep], tuple(names[k] for k in keep)
    rec2 = Recording(t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=names, acc=acc, gyro=gyro)
    h = signal_health(rec2, LAYOUT)
    assert h.dead_imus == ["b2"]
    assert h.imus["b2"].state == kind
    # the other IMU on the same link keeps the joint judged
    assert h.joints["j2"].state == "ok"


def test_zero_and_frozen_single_imu() -> None:
    assert imu_health(np.zeros((30, 3)), np.zeros((30, 3))).state == "zero"
    assert imu_health(np.zeros((0, 3)), np.zeros((0, 3))).state == "silent"
    noisy = np.random.default_rng(1).normal(0, 0.01, (30, 3))
    assert imu_health(noisy + 9.8, noisy).state == "ok"


def test_without_layout_joints_judged_by_encoder(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng, locked="j2"), None)
    assert {n: j.state for n, j in h.joints.items()} == {"j1": "moving", "j2": "flat", "j3": "moving"}
    assert h.joints["j2"].relative_motion is None


def test_short_window_judges_nothing(rng: np.random.Generator) -> None:
    rec = synth(rng).select(slice(0, 5))
    h = signal_health(rec, LAYOUT, thresholds=HealthThresholds(min_samples=20))
    assert h.joints == {}
    assert h.dead_imus == []


def test_relative_motion_with_moving_parent(rng: np.random.Generator) -> None:
    t = np.linspace(0, 20, 2000)
    q = np.sin(0.7 * t)
    qd = 0.7 * np.cos(0.7 * t)
    parent = np.c_[np.sin(t), np.cos(1.3 * t), 0.5 * np.sin(0.4 * t)]
    child = np.einsum("tji,tj->ti", rot_about(AXES["j2"], q), parent) + qd[:, None] * AXES["j2"]
    rms, explained = relative_motion(child, parent, q, qd)
    assert rms > 0.3 and explained > 0.999
    rigid = parent @ rot_about(AXES["j1"], np.array([0.4]))[0].T + 0.2
    rms_r, _ = relative_motion(rigid, parent, np.zeros_like(q), np.zeros_like(q))
    assert rms_r < 1e-9


def test_to_json_round_numbers(rng: np.random.Generator) -> None:
    h = signal_health(synth(rng, locked="j2"), LAYOUT)
    js = json.loads(json.dumps(h.to_json()))  # plain JSON types only
    assert set(js["joints"]) == {"j1", "j2", "j3"} and set(js["imus"]) == set(h.imus)
    assert js["joints"]["j2"]["state"] == "still" and js["joints"]["j1"]["state"] == "ok"
    for name, j in h.joints.items():
        for field in ("excitation", "relative_motion", "explained"):
            value = getattr(j, field)
            assert js["joints"][name][field] == round(float(value), 6), (name, field)
    for name, imu in h.imus.items():
        assert js["imus"][name] == {"state": imu.state, "gyro_rms": round(float(imu.gyro_rms), 6)}


def test_drop_impacts_removes_only_the_jump(rng: np.random.Generator) -> None:
    rec = synth(rng, seconds=10)
    assert drop_impacts(rec).n_samples == rec.n_samples  # smooth motion: nothing dropped
    q = rec.q.copy()
    q[500:, 1] += 0.4  # a stop: the position jumps within one sample
    hit = Recording(
        t=rec.t, joint_names=rec.joint_names, q=q, imu_names=rec.imu_names, acc=rec.acc, gyro=rec.gyro
    )
    kept = drop_impacts(hit)
    assert 0 < rec.n_samples - kept.n_samples <= 8
    assert not np.any((kept.t > 4.97) & (kept.t < 5.02))
    # velocities come from the full window: away from the jump they equal the clean derivative
    clean = rec.derived().qd
    far = np.abs(rec.t - 5.0) > 0.1
    np.testing.assert_allclose(kept.qd[np.abs(kept.t - 5.0) > 0.1], clean[far], atol=1e-9)


def test_locked_joint_with_a_loose_reference_imu_is_still(rng: np.random.Generator) -> None:
    rec = synth(rng, locked="j2")
    gyro = rec.gyro.copy()
    gyro[:, 0] = rng.normal(0, 1.0, gyro[:, 0].shape)  # a1 on the parent link swings on a tether
    h = signal_health(
        Recording(
            t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=rec.imu_names, acc=rec.acc, gyro=gyro
        ),
        LAYOUT,
    )
    assert h.joints["j2"].state == "still"
    assert h.joints["j3"].state == "ok"


def test_moved_reference_imu_is_not_trusted_when_the_estimate_says_so(rng: np.random.Generator) -> None:
    rec = synth(rng)
    gyro = rec.gyro.copy()
    gyro[:, 0] = gyro[:, 2] + 0.05  # a1 (parent link of j2) now sits rigidly on j2's link
    moved = Recording(
        t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=rec.imu_names, acc=rec.acc, gyro=gyro
    )
    current = Topology(dict(LAYOUT.joint_parent), {**LAYOUT.imu_joint, "a1": "j2"})
    h = signal_health(moved, LAYOUT, current=current)
    assert h.joints["j2"].state == "ok" and h.joints["j2"].explained > 0.95


def test_fingerprint_catches_a_constant_encoder_offset(rng: np.random.Generator) -> None:
    from bodyschema.health import fingerprints

    rec = synth(rng, seconds=40)
    first, second = rec.window(0.0, 20.0), rec.window(20.0, 40.0)
    fps = fingerprints(first, LAYOUT)
    assert set(fps) == {"j1", "j2", "j3"}
    healthy = signal_health(second, LAYOUT, fingerprints=fps)
    assert {n: j.state for n, j in healthy.joints.items()} == {"j1": "ok", "j2": "ok", "j3": "ok"}
    q = second.q.copy()
    q[:, 1] += 0.3  # j2's encoder now reads 0.3 rad high
    shifted = Recording(
        t=second.t,
        joint_names=second.joint_names,
        q=q,
        imu_names=second.imu_names,
        acc=second.acc,
        gyro=second.gyro,
    )
    without = signal_health(shifted, LAYOUT)
    assert without.joints["j2"].state == "ok"  # invisible within one window
    h = signal_health(shifted, LAYOUT, fingerprints=fps)
    assert h.joints["j2"].state == "shifted_encoder"
    assert h.joints["j1"].state == h.joints["j3"].state == "ok"


# ------------------------------------------------------------------------------------ multi-rate
def _robot_sensed(rng: np.random.Generator, **kw: object) -> Recording:
    """``synth`` at a 1 kHz physics rate as the ``robot`` sensing preset logs it: 14-bit encoders at
    250 Hz, 100 Hz IMUs behind a 42 Hz filter, 8 ms skew, drift, jitter and drops."""
    from simulators.sensing import apply_sensing

    return apply_sensing(synth(rng, rate=1000.0, **kw), "robot", rng)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("damage", "want"),
    [
        ({}, {"j1": "ok", "j2": "ok", "j3": "ok"}),
        ({"locked": "j2"}, {"j1": "ok", "j2": "still", "j3": "ok"}),
        ({"frozen_encoder": "j3"}, {"j1": "ok", "j2": "ok", "j3": "frozen_encoder"}),
        ({"lost": "j2"}, {"j1": "ok", "j2": "unfollowed", "j3": "ok"}),
    ],
)
def test_multirate_windows_judge_joints_like_single_clock_ones(
    rng: np.random.Generator, damage: dict[str, str], want: dict[str, str]
) -> None:
    rec = _robot_sensed(rng, **damage)
    assert rec.is_multirate and rec.qd is None
    h = signal_health(rec, LAYOUT)
    assert {n: j.state for n, j in h.joints.items()} == want
    assert h.dead_imus == []
    for n, j in h.joints.items():
        if want[n] == "ok":
            assert j.explained is not None and j.explained > 0.95, (n, j)


def test_multirate_dead_imus_judged_on_their_own_stream(rng: np.random.Generator) -> None:
    rec = _robot_sensed(rng)
    acc, gyro = rec.acc.copy(), rec.gyro.copy()
    acc[:, 1], gyro[:, 1] = 0.0, 0.0  # a2 reads exact zeros
    acc[:, 3], gyro[:, 3] = acc[0, 3], gyro[0, 3]  # b2 repeats one sample
    from dataclasses import replace

    h = signal_health(replace(rec, acc=acc, gyro=gyro), LAYOUT)
    assert h.imus["a2"].state == "zero" and h.imus["b2"].state == "frozen"
    assert h.dead_imus == ["a2", "b2"]
    assert {n: j.state for n, j in h.joints.items()} == {"j1": "ok", "j2": "ok", "j3": "ok"}


def test_multirate_fingerprint_catches_a_constant_encoder_offset(rng: np.random.Generator) -> None:
    from dataclasses import replace

    from bodyschema.health import fingerprints

    rec = _robot_sensed(rng, seconds=40.0)
    first, second = rec.window(0.0, 20.0), rec.window(20.0, 40.0)
    fps = fingerprints(first, LAYOUT)
    assert set(fps) == {"j1", "j2", "j3"}
    healthy = signal_health(second, LAYOUT, fingerprints=fps)
    assert {n: j.state for n, j in healthy.joints.items()} == {"j1": "ok", "j2": "ok", "j3": "ok"}
    q = second.q.copy()
    q[:, 1] += 0.3
    h = signal_health(replace(second, q=q), LAYOUT, fingerprints=fps)
    assert h.joints["j2"].state == "shifted_encoder"
    assert h.joints["j1"].state == h.joints["j3"].state == "ok"


def test_drop_impacts_leaves_multirate_windows_to_their_estimators(rng: np.random.Generator) -> None:
    rec = _robot_sensed(rng, seconds=2.0)
    assert drop_impacts(rec) is rec


def _stopping_knee(lag: float) -> tuple[Recording, Topology]:
    """Two joints about z; j2 swings (1 rad/s peak) and stops dead at full speed 2.1 s before the end;
    the IMUs (100 Hz) report ``lag`` seconds after the encoders (100 Hz, their own stamps)."""
    t_q = np.arange(0.0, 10.0, 0.01)
    stop = 2.5 * np.pi  # q2' = cos(2 t) = 1 there
    q1 = 0.5 * np.sin(t_q)
    q2 = 0.5 * np.sin(2.0 * np.minimum(t_q, stop))
    t = t_q + lag
    gyro = np.zeros((t.size, 2, 3))
    gyro[:, 0, 2] = 0.5 * np.cos(t_q)  # what the encoders saw at t_q, reported at t_q + lag
    gyro[:, 1, 2] = gyro[:, 0, 2] + np.where(t_q < stop, np.cos(2.0 * t_q), 0.0)
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 2, 1))
    rec = Recording(
        t=t,
        t_q=t_q,
        joint_names=("j1", "j2"),
        q=np.c_[q1, q2],
        imu_names=("imu1", "imu2"),
        acc=acc,
        gyro=gyro,
    )
    return rec, Topology({"j1": None, "j2": "j1"}, {"imu1": "j1", "imu2": "j2"})


def test_a_joint_that_stops_dead_is_not_a_frozen_encoder_on_the_imus_late_clock() -> None:
    """The still stretch starts when the encoder stopped, on the encoders' clock; the IMUs show the
    stop a lag later. Judged from the encoder's instant, the last 30 ms of motion at 1 rad/s made
    0.12 rad/s RMS over the 2.1 s still stretch, above ``motion_rad_s``: a healthy joint read as a
    frozen encoder. Mapped onto the IMU's clock, and past the settling margin, the stretch is still."""
    rec, layout = _stopping_knee(lag=0.03)
    timed = Topology(
        layout.joint_parent, layout.imu_joint, timing={"lag_ms": 30.0, "drift_ppm": 0.0, "at_s": 0.0}
    )
    assert signal_health(rec, layout, current=timed).joints["j2"].state != "frozen_encoder"
    # what it was: the stretch taken on the encoders' clock and with no margin
    old = HealthThresholds(stop_margin_s=0.0)
    assert signal_health(rec, layout, thresholds=old).joints["j2"].state == "frozen_encoder"
    # and a real frozen encoder still reads as one: the link keeps turning, the encoder does not
    rec.gyro[:, 1, 2] = rec.gyro[:, 0, 2] + np.cos(2.0 * rec.t)
    assert signal_health(rec, layout, current=timed).joints["j2"].state == "frozen_encoder"
