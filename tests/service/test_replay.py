"""Recording replay: chunking, pacing at N× speed, looping, resuming after what the store holds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.ingest.replay import ReplaySource
from service.store import open_store
from simulators.recording_io import save_recording


class FakeClock:
    """A wall clock that only moves when someone sleeps."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += max(s, 0.0)


def make_rec(rng: np.random.Generator, n: int = 100, rate: float = 100.0, with_q: bool = True) -> Recording:
    return Recording(
        t=5.0 + np.arange(n) / rate,
        joint_names=["j1"] if with_q else [],
        q=rng.normal(size=(n, 1)) if with_q else None,
        imu_names=["a", "b"],
        acc=rng.normal(size=(n, 2, 3)),
        gyro=rng.normal(size=(n, 2, 3)),
        ref_quat=None if with_q else np.tile([1.0, 0, 0, 0], (n, 1)),
    )


def drain(src: ReplaySource, limit: int = 10_000) -> list:
    out = []
    for _ in range(limit):
        if src.exhausted:
            break
        out.extend(src.read(0.1))
    return out


def test_chunks_cover_the_recording_exactly(rng: np.random.Generator) -> None:
    rec = make_rec(rng, n=95)
    batches = drain(ReplaySource(rec, robot="r", speed=math.inf, chunk_seconds=0.1))
    assert [b.n_samples for b in batches] == [10] * 9 + [5]
    np.testing.assert_array_equal(np.concatenate([b.t for b in batches]), rec.t)
    np.testing.assert_array_equal(np.concatenate([b.gyro for b in batches]), rec.gyro)
    assert all(b.robot == "r" and b.imu_names == ("a", "b") for b in batches)


def test_recording_without_encoders_gives_no_joints(rng: np.random.Generator) -> None:
    batches = drain(ReplaySource(make_rec(rng, with_q=False), speed=math.inf))
    assert batches[0].joint_names == () and batches[0].q.shape == (10, 0)


def test_paced_at_speed_on_the_wall_clock(rng: np.random.Generator) -> None:
    clock = FakeClock()
    rec = make_rec(rng, n=200)  # 2 s of device time
    src = ReplaySource(rec, speed=4.0, chunk_seconds=0.1, clock=clock, sleep=clock.sleep)
    start = clock.now
    seen = []
    while not src.exhausted:
        for b in src.read(0.05):
            # A batch is never handed out before its last frame is due at 4x.
            assert clock.now - start >= (b.t[-1] - rec.t[0]) / 4.0 - 1e-9
            seen.append(b)
    assert sum(b.n_samples for b in seen) == 200
    assert clock.now - start == pytest.approx((rec.t[-1] - rec.t[0]) / 4.0, abs=0.06)


def test_loop_keeps_device_time_increasing(rng: np.random.Generator) -> None:
    rec = make_rec(rng, n=30)
    src = ReplaySource(rec, speed=math.inf, chunk_seconds=0.1, loop=True, max_batches_per_read=7)
    batches = src.read() + src.read()
    t = np.concatenate([b.t for b in batches])
    assert not src.exhausted and t.shape[0] == 140 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(t[30:60], rec.t + 0.3)  # one period = duration + one sample
    np.testing.assert_array_equal(np.concatenate([b.acc for b in batches])[30:60], rec.acc)


def test_resumes_after_the_stores_last_frame(tmp_path, rng: np.random.Generator) -> None:
    rec = make_rec(rng, n=100)
    path = tmp_path / "arm-7.npz"
    save_recording(rec, path)
    with open_store(f"sqlite:///{tmp_path / 's.db'}") as store:
        first = ReplaySource(path, speed=math.inf, chunk_seconds=0.07)
        assert first.robot == "arm-7"
        store.write_many(first.read()[:3])  # 21 samples, then the process "died"
        assert store.robot("arm-7").last_frame_t == rec.t[20]
        resumed = ReplaySource(path, speed=math.inf, chunk_seconds=0.1)
        resumed.resume_after({"arm-7": store.robot("arm-7").last_frame_t})
        rest = drain(resumed)
        assert rest[0].t[0] == rec.t[21] and rest[0].n_samples == 9  # the cut chunk, then whole ones
        store.write_many(rest)
        got = store.read_between("arm-7", -math.inf, math.inf)
        assert store.sample_count("arm-7") == 100
        np.testing.assert_array_equal(got.acc, rec.acc)
        fresh = ReplaySource(path, speed=math.inf, resume=False)
        fresh.resume_after({"arm-7": store.robot("arm-7").last_frame_t})
        assert sum(b.n_samples for b in drain(fresh)) == 100


def test_bad_arguments(tmp_path, rng: np.random.Generator) -> None:
    with pytest.raises(ValueError):
        ReplaySource(make_rec(rng), speed=0)
    with pytest.raises(ValueError):
        ReplaySource(make_rec(rng), chunk_seconds=-1)
    (tmp_path / "junk.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not a readable"):
        ReplaySource(tmp_path / "junk.npz")


def test_names_outside_the_pattern_are_refused_at_start(tmp_path, rng: np.random.Generator) -> None:
    path = tmp_path / "run 1.npz"
    save_recording(make_rec(rng), path)
    with pytest.raises(ValueError, match=r"robot name 'run 1' is not allowed.*\?robot=NAME"):
        ReplaySource(path)
    assert ReplaySource(path, robot="run-1").robot == "run-1"
