"""The farm: continuous, seeded, reproducible, independent of chunking and of the other robots."""

from __future__ import annotations

import numpy as np
import pytest

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
    diff = farm.inject("ur5e-1", "imu_moved", imu="imu3")
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
        farm.inject("ur5e-1", "warp_drive")


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
        diff = farm.inject("p", "imu_moved")  # parts picked by the damage generator
        farm.inject("u", "joint_locked", joint="elbow")
        chunks += [farm.advance(0.1) for _ in range(4)]
        runs.append((chunks, diff, farm.simulation("p").diff.findings[0].to))
    (a, da, _), (b, db, _) = runs
    assert da == db
    for name in robots:
        for field in ("t", "q", "qd", "qdd", "acc", "gyro"):
            assert np.array_equal(_cat(a, name, field), _cat(b, name, field)), (name, field)
    assert np.allclose(a[-1]["p"].extra["damage_time"], [0.3])
