"""Extra channels (foot forces) in the store, on real SQLite and PostgreSQL: exact round trips on the
IMU stamps, a channel heard in only part of a window left out, bad channels refused without losing
what was stored, and the replay source sending a recording's time-long extras as channels."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.frames import FrameBatch, FrameError
from service.ingest.replay import ReplaySource, recording_batch
from service.store import Store

FORCES = ("lf_force_z", "rf_force_z")


def _batch(rng: np.random.Generator, t0: float, n: int = 50, names: tuple[str, ...] = FORCES) -> FrameBatch:
    t = t0 + np.arange(n) * 0.01
    return FrameBatch(
        "walker",
        t,
        ("j1", "j2"),
        rng.normal(size=(n, 2)),
        ("imu0",),
        rng.normal(size=(n, 1, 3)),
        rng.normal(size=(n, 1, 3)),
        channel_names=names,
        channels=None if not names else rng.uniform(0.0, 400.0, (n, len(names))),
    )


def test_channels_come_back_with_their_window_sample_for_sample(store: Store) -> None:
    rng = np.random.default_rng(0)
    batches = [_batch(rng, 0.5 * k) for k in range(4)]
    store.write_many(batches)
    w = store.read_between("walker", -math.inf, math.inf)
    assert w is not None and set(w.extra) == set(FORCES)
    for i, name in enumerate(FORCES):
        assert np.array_equal(w.extra[name], np.concatenate([b.channels[:, i] for b in batches]))
    w = store.read_window("walker", 0.6)  # a window cut inside a chunk keeps its own samples only
    assert w is not None and w.extra["rf_force_z"].shape == w.t.shape == (60,)
    every = np.concatenate([b.channels[:, 1] for b in batches])
    assert np.array_equal(w.extra["rf_force_z"], every[-60:])


def test_a_channel_heard_in_part_of_the_window_is_left_out(store: Store) -> None:
    rng = np.random.default_rng(1)
    store.write(_batch(rng, 0.0, names=FORCES))
    store.write(_batch(rng, 0.5, names=FORCES[:1]))
    w = store.read_between("walker", -math.inf, math.inf)
    assert w is not None and set(w.extra) == {"lf_force_z"} and w.extra["lf_force_z"].shape == (100,)
    store.write(_batch(rng, 1.0, names=()))  # a source that stopped sending them: none is kept
    w = store.read_between("walker", -math.inf, math.inf)
    assert w is not None and w.extra == {} and w.n_samples == 150
    w = store.read_between("walker", -math.inf, 0.995)  # the part before still has them
    assert w is not None and set(w.extra) == {"lf_force_z"}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"channels": np.zeros((50, 3))}, r"channels must have shape \(50, 2\)"),
        ({"channels": None}, r"channels must have shape \(50, 2\)"),
        ({"channel_names": ()}, r"channels must have shape \(50, 0\)"),
        ({"channel_names": ("lf force",)}, "channel name 'lf force' is not allowed"),
        ({"channel_names": ("f", "f")}, "channel_names must be unique"),
        ({"channels": np.full((50, 2), np.nan)}, "channels contains NaN or Inf"),
        ({"channels": np.full((50, 2), 1e7)}, "is beyond the bound"),
    ],
)
def test_bad_channels_are_refused_and_nothing_stored_is_lost(
    store: Store, change: dict, message: str
) -> None:
    rng = np.random.default_rng(2)
    good = _batch(rng, 0.0)
    store.write(good)
    with pytest.raises(FrameError, match=message):
        store.write(dataclasses.replace(_batch(rng, 0.5), **change))
    w = store.read_between("walker", -math.inf, math.inf)
    assert w is not None and w.n_samples == 50 and np.array_equal(w.extra["lf_force_z"], good.channels[:, 0])


def test_a_multirate_window_keeps_its_channels_on_the_imu_stamps(store: Store) -> None:
    rng = np.random.default_rng(3)
    b = _batch(rng, 0.0, n=100, names=("foot_force.0",))
    tq = np.arange(250) / 250.0  # encoders at 250 Hz on a clock of their own
    b = dataclasses.replace(b, t_q=tq, q=rng.normal(size=(250, 2)))
    store.write(b)
    w = store.read_between("walker", -math.inf, math.inf)
    assert w is not None and w.t_q is not None and np.array_equal(w.t_q, tq)
    assert np.array_equal(w.t, b.t) and np.array_equal(w.extra["foot_force.0"], b.channels[:, 0])


def test_replay_sends_the_time_long_extras_as_channels() -> None:
    n = 30
    rec = Recording(
        t=np.arange(n) * 0.01,
        joint_names=["j"],
        q=np.zeros((n, 1)),
        imu_names=["i"],
        acc=np.zeros((n, 1, 3)),
        gyro=np.zeros((n, 1, 3)),
        extra={
            "foot_force": np.arange(2 * n, dtype=float).reshape(n, 2),
            "lf_force_z": np.ones(n),
            "floating_base": np.array([1]),  # not along t: stays with the file
        },
    )
    b = recording_batch("dog", rec, slice(10, 20))
    assert b.channel_names == ("foot_force.0", "foot_force.1", "lf_force_z")
    assert b.channels is not None and np.array_equal(b.channels[:, 1], rec.extra["foot_force"][10:20, 1])
    src = ReplaySource(rec, robot="dog", speed=math.inf, chunk_seconds=0.1)
    src.skip_until(0.125)  # the first batch after a resume keeps its channels' samples after it
    first = src.read()[0]
    assert first.t[0] == pytest.approx(0.13) and np.array_equal(first.channels[:, 2], np.ones(7))
