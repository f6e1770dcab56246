"""The sensing and timing model: what each stream holds, on which stamps, through which filter."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from bodyschema.recording import Recording
from simulators.kinematic_tree import random_robot_recording
from simulators.recording_io import load_recording
from simulators.sensing import (
    DLPF_GYRO,
    PRESETS,
    SensingOptions,
    apply_sensing,
    dlpf_filter,
    resolve_sensing,
)
from simulators.simulation import simulate


def _sine_recording(f: float = 2.0, seconds: float = 4.0, rate: float = 1000.0) -> Recording:
    """One joint and one IMU whose gyro x reads sin(2π f t) and q = t (rad): easy to check by hand."""
    t = np.arange(round(seconds * rate)) / rate
    gyro = np.zeros((len(t), 1, 3))
    gyro[:, 0, 0] = np.sin(2 * np.pi * f * t)
    return Recording(
        t=t,
        joint_names=("j",),
        q=t[:, None].copy(),
        qd=np.ones((len(t), 1)),
        imu_names=("imu",),
        acc=np.zeros((len(t), 1, 3)),
        gyro=gyro,
    )


def test_ideal_is_todays_output_and_the_default(seed):
    base = simulate("paper-2", seconds=0.5, seed=seed, imu_model="ideal")
    same = simulate("paper-2", seconds=0.5, seed=seed, imu_model="ideal", sensing="ideal")
    assert same.t_q is None and same.qd is not None
    np.testing.assert_array_equal(same.t, base.t)
    np.testing.assert_array_equal(same.gyro, base.gyro)
    np.testing.assert_array_equal(same.q, base.q)
    rec = _sine_recording()
    assert apply_sensing(rec, "ideal", np.random.default_rng(seed)) is rec


def test_dlpf_passes_its_band_and_stops_above_it():
    rate, bw = 1000.0, DLPF_GYRO[3][0]  # 42 Hz
    t = np.arange(4000) / rate
    low = dlpf_filter(np.sin(2 * np.pi * 5 * t), rate, bw)
    high = dlpf_filter(np.sin(2 * np.pi * 150 * t), rate, bw)
    mid = slice(500, -500)
    assert np.max(np.abs(low[mid] - np.sin(2 * np.pi * 5 * t)[mid])) < 0.01  # flat (zero phase) in band
    assert np.sqrt(np.mean(high[mid] ** 2)) < 0.01 * np.sqrt(0.5)  # > 40 dB down at 150 Hz


def test_imu_reading_is_the_motion_skew_plus_filter_delay_before_its_stamp(seed):
    opts = SensingOptions(name="t", imu_rate=100.0, encoder_rate=250.0, skew=7e-3, drift_ppm=40.0, dlpf_cfg=3)
    rec = apply_sensing(_sine_recording(), opts, np.random.default_rng(seed))
    drift = 40e-6
    lag = 7e-3 + DLPF_GYRO[3][1]
    expect = np.sin(2 * np.pi * 2.0 * (rec.t / (1 + drift) - lag))
    inner = (rec.t > 0.1) & (rec.t < 3.9)  # the filter's start-up at the ends of the run
    assert np.max(np.abs(rec.gyro[inner, 0, 0] - expect[inner])) < 2e-3
    # without the lag the same comparison is off by 2π f lag ≈ 0.15: the lag is really there
    assert np.max(np.abs(rec.gyro[:, 0, 0] - np.sin(2 * np.pi * 2.0 * rec.t))) > 0.1
    assert float(rec.extra["truth_skew"]) == pytest.approx(lag)
    # encoders are the reference clock: q = t exactly at their stamps (no jitter asked)
    np.testing.assert_allclose(rec.q[:, 0], rec.t_q, atol=1e-12)
    # each stream is regular on its own clock: the drift shows in what the samples hold, not in the stamps
    assert rec.encoder_rate == pytest.approx(250.0) and rec.sample_rate == pytest.approx(100.0)


def test_robot_preset_quantizes_positions_drops_velocity_and_jitters_stamps(seed):
    fine = random_robot_recording(np.random.default_rng(seed), n_joints=4, seconds=20.0, rate=1000.0)
    rec = apply_sensing(fine, "robot", np.random.default_rng(seed + 1))
    opts = PRESETS["robot"]
    assert rec.qd is None and rec.t_q is not None and rec.q.shape == (rec.t_q.shape[0], 4)
    lsb = 2 * np.pi / 2**14
    counts = rec.q / lsb
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    # against the true position at the (un-jittered) instant: within half a count plus what the jitter moves
    period = np.diff(rec.t_q)
    assert 1 / np.median(period) == pytest.approx(250.0, rel=1e-3)
    nominal = np.round(rec.t_q * 250.0) / 250.0
    jit = rec.t_q - nominal
    assert 0.5 * opts.jitter < np.std(jit) < 1.5 * opts.jitter
    truth = np.stack([np.interp(nominal, fine.t, fine.q[:, j]) for j in range(4)], 1)
    assert np.max(np.abs(rec.q - truth)) < lsb / 2 + 1e-4
    # drops: 0.5 % of each stream, independently; the streams keep their ends
    n_enc = round(20.0 * 250.0)
    lost = n_enc + 1 - rec.t_q.shape[0]
    assert 0 < lost < 0.015 * n_enc
    assert np.max(period) > 1.5 / 250.0  # a dropped sample leaves a double period
    info = json.loads(str(rec.extra["sensing"]))
    assert info["encoder_bits"] == 14 and info["dlpf_cfg"] == 3


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"dlpf_cfg": 7}, "dlpf_cfg"),
        ({"imu_rate": 20.0}, "imu_rate"),
        ({"encoder_rate": 2000.0}, "encoder_rate"),
        ({"drop": 0.6}, "drop"),
        ({"encoder_bits": 2}, "encoder_bits"),
    ],
)
def test_bad_options_are_refused_for_their_own_reason(kw, message):
    with pytest.raises(ValueError, match=message):
        SensingOptions(**kw)


def test_presets_and_json_resolve():
    assert resolve_sensing("robot") is PRESETS["robot"]
    assert resolve_sensing('{"skew": 0.01}').skew == 0.01
    with pytest.raises(ValueError, match="unknown sensing"):
        resolve_sensing("nope")


def test_cli_writes_a_multirate_recording_that_loads(tmp_path):
    out = tmp_path / "r.npz"
    cmd = [sys.executable, "-m", "cli", "simulate", "paper-2", "--seconds", "1", "--sensing", "robot"]
    res = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert re.search(r"at 100 Hz, encoders 2[45]\d samples at 2(49|50) Hz", res.stdout), res.stdout
    rec = load_recording(out)
    assert rec.is_multirate and rec.qd is None
    assert 240 <= rec.t_q.shape[0] <= 251 and 90 <= rec.n_samples <= 100
    assert rec.truth_joint_parent == ("", "j1", "j2", "j1", "j4")


def test_advance_refuses_a_float_sample_count():
    from simulators.simulation import Simulation

    sim = Simulation("paper-1", seed=0)
    with pytest.raises(TypeError, match="use seconds="):
        sim.advance(60.0)
    assert sim.advance(seconds=0.05).n_samples == 5
    assert sim.advance(np.int64(3)).n_samples == 3
