"""Multi-rate frames in the store (encoders on stamps of their own) on real SQLite and PostgreSQL:
exact round trips, windows and retention cut each stream by its own stamps, bad batches refused."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from service.frames import FrameBatch, FrameError
from service.store import build_chunks, open_store

IMU_RATE, ENC_RATE, SKEW = 100.0, 250.0, 0.008
JOINTS, IMUS = ("j1", "j2"), ("imu0", "imu1", "imu2")


def multirate_batch(
    rng: np.random.Generator,
    seconds: float = 1.0,
    t0: float = 0.0,
    robot: str = "r1",
    qd: bool = False,
    jitter: float = 2e-4,
) -> FrameBatch:
    """Both streams over ``[t0, t0 + seconds)``, the IMU stamps late by ``SKEW`` and jittered."""
    ti = t0 + SKEW + np.arange(round(seconds * IMU_RATE)) / IMU_RATE
    tq = t0 + np.arange(round(seconds * ENC_RATE)) / ENC_RATE
    ti = ti + rng.uniform(-jitter, jitter, ti.shape)
    tq = tq + rng.uniform(-jitter, jitter, tq.shape)
    return FrameBatch(
        robot,
        ti,
        JOINTS,
        rng.normal(size=(tq.shape[0], len(JOINTS))),
        IMUS,
        rng.normal(size=(ti.shape[0], len(IMUS), 3)),
        rng.normal(size=(ti.shape[0], len(IMUS), 3)),
        t_q=tq,
        qd=rng.normal(size=(tq.shape[0], len(JOINTS))) if qd else None,
    )


def split(b: FrameBatch, cuts: np.ndarray) -> list[FrameBatch]:
    """``b`` cut at the times ``cuts`` (each stream by its own stamps)."""
    assert b.t_q is not None
    edges = [-math.inf, *cuts, math.inf]
    out = []
    for lo, hi in itertools.pairwise(edges):
        m = (b.t >= lo) & (b.t < hi)
        mq = (b.t_q >= lo) & (b.t_q < hi)
        if m.any() and mq.any():
            out.append(
                FrameBatch(
                    b.robot,
                    b.t[m],
                    b.joint_names,
                    b.q[mq],
                    b.imu_names,
                    b.acc[m],
                    b.gyro[m],
                    t_q=b.t_q[mq],
                    qd=None if b.qd is None else b.qd[mq],
                )
            )
    return out


def expect_window(b: FrameBatch, start: float, end: float) -> dict[str, np.ndarray]:
    assert b.t_q is not None
    m = (b.t > start) & (b.t <= end)
    mq = (b.t_q > start) & (b.t_q <= end)
    out = {"t": b.t[m], "acc": b.acc[m], "gyro": b.gyro[m], "t_q": b.t_q[mq], "q": b.q[mq]}
    if b.qd is not None:
        out["qd"] = b.qd[mq]
    return out


def assert_window(rec, ref: dict[str, np.ndarray]) -> None:
    assert rec is not None and rec.is_multirate
    for k, v in ref.items():
        np.testing.assert_array_equal(getattr(rec, k), v, err_msg=k)


@pytest.mark.parametrize("chunk", [5, 40, 1000])
def test_multirate_round_trip_and_windows_are_exact(
    db_url: str, rng: np.random.Generator, chunk: int
) -> None:
    whole = multirate_batch(rng, seconds=3.0, qd=True)
    parts = split(whole, np.arange(0.1, 3.0, 0.1) + rng.uniform(-0.01, 0.01, 29))
    with open_store(db_url, chunk_max_samples=chunk) as store:
        for i in range(0, len(parts), 4):
            assert store.write_many(parts[i : i + 4]) == sum(p.n_samples for p in parts[i : i + 4])
        assert store.sample_count("r1") == 300
        rec = store.read_between("r1", -math.inf, math.inf)
        assert rec.joint_names == JOINTS and rec.imu_names == IMUS and rec.n_samples == 300
        assert rec.t_q.shape == (750,) and rec.qd is not None
        assert_window(rec, expect_window(whole, -math.inf, math.inf))
        # The store's last frame is the later of the two streams' last stamps.
        assert store.robot("r1").last_frame_t == max(whole.t[-1], whole.t_q[-1])
        for end, seconds in [(1.5, 0.5), (0.05, 0.05), (2.999, 1.0), (float(whole.t_q[100]), 0.035)]:
            rec = store.read_window("r1", seconds, end=end)
            assert_window(rec, expect_window(whole, end - seconds, end))
        # The default end is the last frame; the window holds both streams' own samples.
        rec = store.read_window("r1", 1.0)
        assert abs(rec.n_samples - 100) <= 1 and abs(rec.t_q.shape[0] - 250) <= 1
        assert rec.sample_rate == pytest.approx(100, rel=0.03) and rec.encoder_rate == pytest.approx(
            250, rel=0.03
        )


def test_multirate_random_batching_matches_a_plain_slice(rng: np.random.Generator) -> None:
    """Any cut of the streams, chunk size and window gives each stream's own plain slice."""
    for _case in range(8):
        whole = multirate_batch(rng, seconds=float(rng.uniform(0.3, 2.0)), qd=bool(rng.integers(2)))
        cuts = np.sort(rng.uniform(0, whole.t[-1], size=int(rng.integers(0, 20))))
        with open_store("sqlite://", chunk_max_samples=int(rng.integers(1, 60))) as store:
            parts = split(whole, cuts)
            k = 0
            while k < len(parts):
                step = int(rng.integers(1, 5))
                store.write_many(parts[k : k + step])
                k += step
            kept = np.concatenate([p.t for p in parts])
            kept_q = np.concatenate([p.t_q for p in parts])
            ref = FrameBatch(
                "r1",
                kept,
                JOINTS,
                np.concatenate([p.q for p in parts]),
                IMUS,
                np.concatenate([p.acc for p in parts]),
                np.concatenate([p.gyro for p in parts]),
                t_q=kept_q,
                qd=None if whole.qd is None else np.concatenate([p.qd for p in parts]),
            )
            for _w in range(5):
                end = float(rng.uniform(0.1, whole.t[-1] + 0.01))
                seconds = float(rng.uniform(0.05, 1.5))
                rec = store.read_window("r1", seconds, end=end)
                want = expect_window(ref, end - seconds, end)
                if rec is None:  # a window too short to hold both streams overlapping
                    assert (
                        want["t"].size == 0
                        or want["t_q"].size == 0
                        or not (min(want["t"][-1], want["t_q"][-1]) > max(want["t"][0], want["t_q"][0]))
                    )
                    continue
                assert_window(rec, want)


def test_long_multirate_batches_split_into_chunks_by_both_streams(rng: np.random.Generator) -> None:
    b = multirate_batch(rng, seconds=1.0)
    chunks = build_chunks([b], max_samples=30)
    assert all(c.n <= 30 and c.n_q <= 30 for c in chunks)
    assert sum(c.n for c in chunks) == 100 and sum(c.n_q for c in chunks) == 250
    np.testing.assert_array_equal(np.concatenate([np.concatenate(c.t_q) for c in chunks]), b.t_q)
    np.testing.assert_array_equal(np.concatenate([np.concatenate(c.t) for c in chunks]), b.t)
    # Cut at stamps: consecutive chunks cover consecutive stretches of time in both streams.
    for a, c in itertools.pairwise(chunks):
        assert a.t_end < c.t_start
    # A single-clock batch after a multi-rate one starts a chunk of its own.
    single = FrameBatch(
        "r1", np.array([2.0, 2.01]), JOINTS, np.zeros((2, 2)), IMUS, np.zeros((2, 3, 3)), np.zeros((2, 3, 3))
    )
    assert [c.multirate for c in build_chunks([b, single], 10_000)] == [True, False]


def test_single_clock_history_joins_a_multirate_window(db_url: str, rng: np.random.Generator) -> None:
    """Data stored before a robot's encoders got their own stamps stays readable, alone and together."""
    with open_store(db_url) as store:
        t = np.arange(50) / 100.0
        old = FrameBatch(
            "r1",
            t,
            JOINTS,
            rng.normal(size=(50, 2)),
            IMUS,
            rng.normal(size=(50, 3, 3)),
            rng.normal(size=(50, 3, 3)),
        )
        store.write(old)
        rec = store.read_window("r1", 1.0)
        assert not rec.is_multirate and rec.qd is None
        np.testing.assert_array_equal(rec.q, old.q)
        new = multirate_batch(rng, seconds=0.5, t0=0.5)
        store.write(new)
        rec = store.read_window("r1", 10.0)
        assert rec.is_multirate and rec.n_samples == 100 and rec.t_q.shape == (50 + 125,)
        np.testing.assert_array_equal(rec.t_q, np.concatenate([t, new.t_q]))
        np.testing.assert_array_equal(rec.q, np.concatenate([old.q, new.q]))
        np.testing.assert_array_equal(rec.t, np.concatenate([t, new.t]))
        np.testing.assert_array_equal(rec.gyro, np.concatenate([old.gyro, new.gyro]))
        # A window of old data only stays single-clock.
        assert not store.read_window("r1", 0.2, end=0.45).is_multirate


def test_multirate_retention_prunes_each_stream_by_its_own_stamps(
    db_url: str, rng: np.random.Generator
) -> None:
    whole = multirate_batch(rng, seconds=3.0, jitter=0.0)
    with open_store(db_url, retention_seconds=1.0, chunk_max_samples=25) as store:
        store.write_many(split(whole, np.arange(0.1, 3.0, 0.1)))
        dropped = store.prune()
        last = max(whole.t[-1], whole.t_q[-1])
        rec = store.read_between("r1", -math.inf, math.inf)
        # Whole chunks go: nothing kept ended before the cutoff, and every sample after it is kept.
        cutoff = last - 1.0
        assert dropped == 300 - rec.n_samples > 0
        np.testing.assert_array_equal(rec.t, whole.t[whole.t >= rec.t[0]])
        np.testing.assert_array_equal(rec.t_q, whole.t_q[whole.t_q >= rec.t_q[0]])
        assert rec.t[0] <= cutoff + 0.25 and rec.t_q[0] <= cutoff + 0.25
        assert (whole.t[whole.t > cutoff] >= rec.t[0]).all() and (
            whole.t_q[whole.t_q > cutoff] >= rec.t_q[0]
        ).all()
        assert store.prune(now_t=100.0) == rec.n_samples and store.sample_count() == 0


def _variant(b: FrameBatch, **kw: object) -> FrameBatch:
    fields = {
        k: getattr(b, k) for k in ("robot", "t", "joint_names", "q", "imu_names", "acc", "gyro", "t_q", "qd")
    }
    fields.update(kw)
    return FrameBatch(**fields)  # type: ignore[arg-type]


def test_bad_multirate_batches_refused_with_clear_messages(db_url: str, rng: np.random.Generator) -> None:
    with open_store(db_url) as store:
        good = multirate_batch(rng, seconds=0.5, qd=True)
        store.write(good)
        nxt = multirate_batch(rng, seconds=0.5, t0=0.5, qd=True)
        tq = nxt.t_q
        nan_tq, back_tq, dup_tq, nan_qd = tq.copy(), tq.copy(), tq.copy(), nxt.qd.copy()
        nan_tq[7] = np.nan
        back_tq[[10, 11]] = back_tq[[11, 10]]
        dup_tq[20] = dup_tq[19]
        nan_qd[3, 1] = np.inf
        cases = [
            (_variant(nxt, q=nxt.q[:-1]), r"q must have shape \(125, 2\) \(on t_q\)"),
            (_variant(nxt, qd=nxt.qd[:, :1]), r"qd must have shape \(125, 2\) \(on t_q\)"),
            (_variant(nxt, t_q=nan_tq), "t_q contains NaN or Inf"),
            (_variant(nxt, qd=nan_qd), "qd contains NaN or Inf"),
            (_variant(nxt, t_q=back_tq), r"t_q goes backwards at index 11"),
            (_variant(nxt, t_q=dup_tq), r"t_q has a duplicate stamp at index 20"),
            (_variant(nxt, t_q=np.zeros((0,))), r"t_q must have shape \(T_q,\) with T_q >= 1"),
            (_variant(nxt, t_q=tq.reshape(-1, 1)), r"t_q must have shape \(T_q,\)"),
            (_variant(nxt, t_q=tq.astype(object)), "t_q must be a numeric numpy array"),
            (_variant(nxt, t_q=None), r"q must have shape \(50, 2\) \(on t\)"),
        ]
        for bad, msg in cases:
            with pytest.raises(FrameError, match=rf"batch 1 \(robot 'r1'\): {msg}"):
                store.write_many([multirate_batch(rng, seconds=0.5, t0=2.0, qd=True), bad])
        # Nothing of the refused calls was written, and what was stored before is intact.
        assert store.sample_count() == 50
        assert_window(store.read_between("r1", -math.inf, math.inf), expect_window(good, -math.inf, math.inf))
        assert store.write(nxt) == 50 and store.sample_count() == 100
