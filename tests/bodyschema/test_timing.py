"""Multi-rate recordings (docs/recording-format.md) and the timing tools of the fast estimator."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from bodyschema.recording import Recording, RecordingError, find_gaps
from simulators.recording_io import load_recording, save_recording


def _multirate(t: np.ndarray | None = None, t_q: np.ndarray | None = None) -> Recording:
    t = np.arange(100) * 0.01 if t is None else t
    t_q = np.arange(250) * 0.004 if t_q is None else t_q
    return Recording(
        t=t,
        t_q=t_q,
        joint_names=("a", "b"),
        q=np.stack([np.sin(t_q), np.cos(t_q)], 1),
        imu_names=("i0",),
        acc=np.zeros((len(t), 1, 3)),
        gyro=np.ones((len(t), 1, 3)) * t[:, None, None],
    )


def test_multirate_round_trip_and_single_clock_files_load_unchanged(tmp_path):
    rec = _multirate()
    save_recording(rec, tmp_path / "m.npz")
    back = load_recording(tmp_path / "m.npz")
    assert back.is_multirate and back.q.shape == (250, 2) and back.gyro.shape == (100, 1, 3)
    np.testing.assert_array_equal(back.t_q, rec.t_q)
    np.testing.assert_array_equal(back.q, rec.q)
    single = Recording(
        t=rec.t, joint_names=("a",), q=np.zeros((100, 1)), imu_names=("i0",), acc=rec.acc, gyro=rec.gyro
    )
    save_recording(single, tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as z:
        assert "t_q" not in z.files
    one = load_recording(tmp_path / "s.npz")
    assert not one.is_multirate and one.encoder_t is one.t


def test_window_and_select_cut_each_stream_by_its_own_stamps():
    rec = _multirate()
    w = rec.window(0.2, 0.5)
    assert w.t[0] == pytest.approx(0.2) and w.t[-1] == pytest.approx(0.49)
    assert w.t_q[0] == pytest.approx(0.2) and w.t_q[-1] == pytest.approx(0.496)
    assert w.q.shape == (75, 2)
    s = rec.select(slice(10, 20))  # IMU samples 0.10..0.19 s: encoder samples in that span
    assert s.t_q[0] == pytest.approx(0.1) and s.t_q[-1] == pytest.approx(0.188)
    synced = rec.synced()
    assert synced.t_q is None and synced.q.shape == (100, 2)
    np.testing.assert_allclose(synced.q[:, 0], np.sin(synced.t), atol=1e-8)
    d = rec.derived()
    np.testing.assert_allclose(d.qd[5:-5, 0], np.cos(rec.t_q[5:-5]), atol=1e-4)


@pytest.mark.parametrize("stream", ["t", "t_q"])
def test_stamps_going_backwards_are_refused_naming_the_place(stream):
    t, t_q = np.arange(100) * 0.01, np.arange(250) * 0.004
    bad = (t if stream == "t" else t_q).copy()
    bad[40], bad[41] = bad[41], bad[40]
    kw = {"t": bad} if stream == "t" else {"t_q": bad}
    with pytest.raises(RecordingError, match=rf"{stream} goes backwards at index 41"):
        _multirate(**kw)


def test_duplicate_stamps_are_refused_or_dropped_with_a_warning(tmp_path, caplog):
    rec = _multirate()
    path = tmp_path / "dup.npz"
    save_recording(rec, path)
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    # the encoder logger sent samples 30 and 31 twice each
    idx = np.r_[0:31, 30, 31, 31:250]
    for k in ("t_q", "q"):
        data[k] = data[k][idx]
    np.savez(path, **data)
    with pytest.raises(RecordingError, match=r"t_q has duplicate stamps at index 31 .*2 in all"):
        load_recording(path)
    with caplog.at_level(logging.WARNING):
        back = load_recording(path, repair=True)
    np.testing.assert_array_equal(back.t_q, rec.t_q)
    np.testing.assert_array_equal(back.q, rec.q)
    assert "dropped 2 sample(s) with a repeated t_q stamp" in caplog.text


def test_gaps_are_kept_and_reported(tmp_path, caplog):
    t = np.r_[np.arange(50) * 0.01, 0.8 + np.arange(50) * 0.01]  # 0.49 -> 0.80: 31 periods missing
    rec = _multirate(t=t, t_q=np.arange(400) * 0.004)
    assert find_gaps(rec.t) == [(pytest.approx(0.49), pytest.approx(0.8))]
    assert find_gaps(rec.t_q) == []
    save_recording(rec, tmp_path / "g.npz")
    with caplog.at_level(logging.WARNING):
        back = load_recording(tmp_path / "g.npz")
    assert back.n_samples == 100
    assert "1 gap(s) in t (longest 0.31 s, first at 0.49 s)" in caplog.text


def test_streams_that_do_not_overlap_are_refused():
    with pytest.raises(RecordingError, match=r"do not overlap in time"):
        _multirate(t_q=20.0 + np.arange(250) * 0.004)


def test_encoder_arrays_must_match_their_own_stamps():
    with pytest.raises(RecordingError, match=r"q must have shape \(240, 2\) \(on t_q\)"):
        Recording(
            t=np.arange(100) * 0.01,
            t_q=np.arange(240) * 0.004,
            joint_names=("a", "b"),
            q=np.zeros((100, 2)),
            imu_names=("i0",),
            acc=np.zeros((100, 1, 3)),
            gyro=np.zeros((100, 1, 3)),
        )


def test_a_lag_hint_moves_the_encoders_and_puts_the_move_back_only_where_it_moved_them():
    """The monitor's one alignment step (bodyschema.timing.LagHint): a hint beyond half the search
    range moves a multi-rate window's encoder stamps, and the timing learned there is put back on the
    original stamps; a single-clock window with measured velocities has no lag to move, so nothing is
    put back either (an estimator's own timing of it stays as it reported it)."""
    from dataclasses import replace

    from bodyschema.timing import LagHint
    from bodyschema.topology import Topology

    assert LagHint.centre(0.049) == LagHint(0.0) and LagHint.centre(None) == LagHint(0.0)
    assert LagHint.centre(-0.051) == LagHint(-0.051)
    assert LagHint.centre(0.03, max_lag=0.05) == LagHint(0.03)
    topo = Topology({"a": None, "b": "a"}, {"i0": "a"}, timing={"lag_ms": 12.0, "skew_ms": 7.0})
    rec = _multirate()
    moved, applied = LagHint(0.12).apply(rec)
    assert applied == LagHint(0.12)
    np.testing.assert_allclose(moved.t_q, rec.t_q + 0.12)
    assert applied.put_back(topo).timing == {"lag_ms": 132.0, "skew_ms": 127.0}
    single = replace(rec, t_q=None, t=rec.t, q=rec.q[: len(rec.t)], qd=np.zeros((len(rec.t), 2)))
    same, none = LagHint(0.12).apply(single)
    assert same is single and none == LagHint(0.0) and none.put_back(topo) is topo
    seen: list[Recording] = []
    assert LagHint(0.12).estimate(lambda r: seen.append(r) or topo, rec).timing["lag_ms"] == 132.0
    np.testing.assert_allclose(seen[0].t_q, rec.t_q + 0.12)


def _filtered_noise(shape: str, bandwidth: float, seed: int = 5) -> tuple[np.ndarray, float]:
    """60 s of white gyro noise at 1 kHz through a low-pass of ``shape`` at ``bandwidth`` Hz, taken to
    100 Hz, plus slow motion; and the noise's true in-band std in 0..choose_band (from the noise alone)."""
    from scipy.signal import lfilter

    from bodyschema.timing import choose_band, lowpass
    from simulators.sensing import dlpf_filter

    rng = np.random.default_rng(seed)
    noise = rng.normal(scale=2e-2, size=(60_000, 2, 3))
    if shape == "windowed sinc":  # the simulator's on-chip filter
        noise = dlpf_filter(noise, 1000.0, bandwidth)
    else:  # two equal one-pole stages with the same -3 dB frequency
        a = 1.0 - np.exp(-2 * np.pi * bandwidth / np.sqrt(np.sqrt(2.0) - 1.0) / 1000.0)
        for _ in range(2):
            noise = lfilter([a], [1.0, a - 1.0], noise, axis=0)
    noise = noise[::10]
    t = np.arange(len(noise)) / 100.0
    motion = 0.5 * np.sin(2 * np.pi * 0.7 * t)[:, None, None] * np.ones((1, 2, 3))
    fc = choose_band(100.0, 100.0, bandwidth)
    truth = float(np.std(lowpass(noise, 100.0, fc, axis=0)[500:-500]))
    return noise + motion, truth


@pytest.mark.parametrize("shape", ["windowed sinc", "two-pole"])
@pytest.mark.parametrize("bandwidth", [20.0, 42.0])
def test_gyro_band_noise_reads_the_noise_a_stated_low_pass_leaves_in_band(shape, bandwidth):
    # the third difference reads the top of the spectrum, which a low-pass below Nyquist empties: at
    # 20 Hz it sees a small fraction of the in-band noise. Read through the stated filter, the estimate
    # is right to within the filter's unknown shape, erring high (more models fit), never low
    from bodyschema.fast_core import noise_level
    from bodyschema.timing import choose_band, gyro_band_noise

    gyro, truth = _filtered_noise(shape, bandwidth)
    fc = choose_band(100.0, 100.0, bandwidth)
    est = gyro_band_noise(gyro, 100.0, fc, bandwidth)
    assert np.all(est > 0.9 * truth) and np.all(est < np.sqrt(2.0) * truth), (est / truth, shape, bandwidth)
    blind = noise_level(gyro) * np.sqrt(fc / 50.0)
    assert np.all(blind < 0.95 * truth)  # what the white-noise model read: too low
    if bandwidth == 20.0 and shape == "windowed sinc":
        assert np.all(blind < 0.1 * truth)  # a hundredth of the variance: the 20 Hz cell's failure
    # no filter stated below Nyquist: the white-noise estimate, unchanged
    np.testing.assert_array_equal(gyro_band_noise(gyro, 100.0, fc, None), blind)
