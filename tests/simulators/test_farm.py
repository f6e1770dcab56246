"""The farm: continuous, seeded, reproducible, independent of chunking and of the other robots."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.recording import Recording
from simulators.farm import Farm


def _cat(chunks: list, name: str, field: str) -> np.ndarray:
    return np.concatenate([getattr(c[name], field) for c in chunks])


def test_chunks_continue_in_time_and_do_not_depend_on_chunking(seed: int) -> None:
    robots = {"ur5e-1": "ur5e", "paper-3-1": "paper-3"}
    a = Farm(robots, seed=seed)
    b = Farm(robots, seed=seed)
    ca = [a.advance(0.1) for _ in range(6)]
    cb = [b.advance(0.25), b.advance(0.35)]
    for name in robots:
        t = _cat(ca, name, "t")
        assert np.allclose(np.diff(t), 0.01) and t[0] == 0.0
        for field in ("t", "q", "acc", "gyro"):
            assert np.allclose(_cat(ca, name, field), _cat(cb, name, field), atol=1e-9), (name, field)
    assert a.time == pytest.approx(0.6)


def test_seeded_reproducible_and_robots_independent_of_each_other(seed: int) -> None:
    one = Farm({"r": "paper-2"}, seed=seed).advance(0.3)["r"]
    two = Farm({"x": "ur5e", "r": "paper-2"}, seed=seed).advance(0.3)["r"]
    other = Farm({"r": "paper-2"}, seed=seed + 1).advance(0.3)["r"]
    assert np.array_equal(one.gyro, two.gyro) and np.array_equal(one.q, two.q)
    assert not np.allclose(one.gyro, other.gyro)
    # two robots of the same kind in one farm are different robots
    f = Farm({"a": "paper-2", "b": "paper-2"}, seed=seed).advance(0.2)
    assert not np.allclose(f["a"].q, f["b"].q)


def test_inject_truth_and_names(seed: int) -> None:
    farm = Farm({"ur5e-1": "ur5e", "paper-3-1": "paper-3"}, seed=seed, imu_model="ideal")
    assert farm.robot_names == ["ur5e-1", "paper-3-1"]
    assert farm.catalog_name("paper-3-1") == "paper-3"
    before = farm.truth("ur5e-1")
    diff = farm.apply_damage("ur5e-1", "imu_moved", imu="imu3")
    f = diff.findings[0]
    assert f.kind == "imu_moved" and f.from_ == before.imu_joint["imu3"] and f.to != f.from_
    assert farm.truth("ur5e-1").imu_joint["imu3"] == f.to
    assert farm.truth("paper-3-1") == Farm({"p": "paper-3"}, seed=seed).truth("p")
    chunk = farm.advance(0.1)["ur5e-1"]
    assert chunk.truth_imu_joint[3] == f.to
    assert farm.diff("ur5e-1") == diff
    with pytest.raises(KeyError):
        farm.truth("nope")
    with pytest.raises(ValueError):
        farm.apply_damage("ur5e-1", "warp_drive")


def test_stream_paces_faster_than_real_time() -> None:
    import time

    farm = Farm({"p": "paper-1"}, seed=0, imu_model="ideal")
    start = time.monotonic()
    chunks = list(farm.stream(chunk=0.1, speed=10.0, seconds=0.5))
    elapsed = time.monotonic() - start
    assert len(chunks) == 5 and sum(c["p"].n_samples for c in chunks) == 50
    assert elapsed >= 0.05 - 1e-3  # paced: 0.5 s at 10x takes at least 50 ms


def test_rejects_bad_configuration() -> None:
    with pytest.raises(ValueError, match="at least one robot"):
        Farm({}, seed=0)
    with pytest.raises(ValueError, match="unknown robot 'not-a-robot'"):
        Farm({"a": "not-a-robot"}, seed=0)
    with pytest.raises(ValueError, match="unknown excitation 'dance'"):
        Farm({"a": "ur5e"}, seed=0, excitation="dance")


def test_readahead_changes_nothing_even_around_damage(seed: int) -> None:
    robots = {"u": "ur5e", "p": "paper-5"}
    runs = []
    for readahead in (0.0, 0.45):
        farm = Farm(robots, seed=seed, readahead=readahead)
        chunks = [farm.advance(0.1) for _ in range(3)]
        diff = farm.apply_damage("p", "imu_moved")  # parts picked by the damage generator
        farm.apply_damage("u", "joint_locked", joint="elbow")
        chunks += [farm.advance(0.1) for _ in range(4)]
        runs.append((chunks, diff, farm.simulation("p").diff.findings[0].to))
    (a, da, _), (b, db, _) = runs
    assert da == db
    for name in robots:
        for field in ("t", "q", "qd", "qdd", "acc", "gyro"):
            assert np.array_equal(_cat(a, name, field), _cat(b, name, field)), (name, field)
    assert np.allclose(a[-1]["p"].extra["damage_time"], [0.3])


# ----------------------------------------------------------------------------------- sensing presets
def _streams(chunks: list, name: str) -> dict[str, np.ndarray]:
    recs = [c[name] for c in chunks if name in c]
    return {f: np.concatenate([getattr(r, f) for r in recs]) for f in ("t", "t_q", "q", "acc", "gyro")}


def test_robot_sensing_gives_continuous_multirate_chunks_independent_of_chunking(seed: int) -> None:
    robots = {"u": "ur5e", "p": "paper-3"}
    a = Farm(robots, seed=seed, sensing="robot")
    b = Farm(robots, seed=seed, sensing="robot")
    ca = [a.advance(0.1) for _ in range(8)]
    cb = [b.advance(0.25), b.advance(0.05), b.advance(0.5)]
    for name in robots:
        recs = [c[name] for c in ca]
        assert all(r.is_multirate and r.qd is None for r in recs)
        # each step after the first brings 0.1 s of both streams (minus the rare drop)
        assert all(9 <= r.n_samples <= 10 and 23 <= r.t_q.shape[0] <= 25 for r in recs[1:])
        sa, sb = _streams(ca, name), _streams(cb, name)
        for stamps in ("t", "t_q"):
            assert np.all(np.diff(sa[stamps]) > 0), (name, stamps)  # continuous, never restarted
        # the encoder clock starts at 0, the IMU's stamps are late by the skew and filter delay
        assert abs(sa["t_q"][0]) < 0.005 and 0.012 < sa["t"][0] < 0.025
        # what came out of both farms so far is the same samples, bit for bit up to float rounding
        n, nq = min(len(sa["t"]), len(sb["t"])), min(len(sa["t_q"]), len(sb["t_q"]))
        assert n > 70 and nq > 180
        for f in ("t", "acc", "gyro"):
            np.testing.assert_allclose(sa[f][:n], sb[f][:n], rtol=0, atol=1e-9, err_msg=f"{name} {f}")
        for f in ("t_q", "q"):
            np.testing.assert_allclose(sa[f][:nq], sb[f][:nq], rtol=0, atol=1e-9, err_msg=f"{name} {f}")
        # 14-bit encoders: positions on the quantization grid
        lsb = 2 * np.pi / 2**14
        np.testing.assert_allclose(sa["q"] / lsb, np.round(sa["q"] / lsb), atol=1e-6)


def test_robot_sensing_stream_equals_the_sensing_model_on_the_whole_run(seed: int) -> None:
    """The farm's per-step sensing is the one-shot model applied to the whole physics run: the filter
    and the stamps carry on across steps instead of starting over."""
    from dataclasses import replace

    from simulators.sensing import PRESETS, apply_sensing

    opts = replace(PRESETS["robot"], jitter=0.0, drop=0.0)
    fine = Farm({"p": "paper-3"}, seed=seed, sensing="ideal", rate=1000.0, imu_model="ideal")
    sensed = Farm({"p": "paper-3"}, seed=seed, sensing=opts, imu_model="ideal")
    fine_chunks = [fine.advance(0.1)["p"] for _ in range(10)]
    steps = [sensed.advance(0.1) for _ in range(10)]
    whole = apply_sensing(
        Recording(
            t=np.concatenate([c.t for c in fine_chunks]),
            joint_names=fine_chunks[0].joint_names,
            q=np.concatenate([c.q for c in fine_chunks]),
            qd=np.concatenate([c.qd for c in fine_chunks]),
            imu_names=fine_chunks[0].imu_names,
            acc=np.concatenate([c.acc for c in fine_chunks]),
            gyro=np.concatenate([c.gyro for c in fine_chunks]),
        ),
        opts,
        np.random.default_rng(0),
    )
    got = _streams(steps, "p")
    n, nq = len(got["t"]), len(got["t_q"])
    # everything but the last ~latency of the run came out
    assert whole.t[n - 1] > 0.9 and whole.t_q[nq - 1] > 0.9
    np.testing.assert_array_equal(got["t"], whole.t[:n])
    np.testing.assert_array_equal(got["t_q"], whole.t_q[:nq])
    np.testing.assert_array_equal(got["q"], whole.q[:nq])
    scale = np.abs(whole.gyro).max()
    np.testing.assert_allclose(got["gyro"], whole.gyro[:n], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(got["acc"], whole.acc[:n], rtol=0, atol=1e-9 * np.abs(whole.acc).max())


def test_sensing_preset_is_checked() -> None:
    with pytest.raises(ValueError, match="unknown sensing 'blurry'"):
        Farm({"a": "ur5e"}, seed=0, sensing="blurry")
    ideal = Farm({"a": "paper-1"}, seed=0, sensing="ideal").advance(0.1)["a"]
    assert not ideal.is_multirate and ideal.n_samples == 10 and ideal.qd is not None
