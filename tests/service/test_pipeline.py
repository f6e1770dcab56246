"""The ingest pipeline on a real store, SQLite and PostgreSQL: everything stored exactly, backpressure
drops and counts, bad batches and failing sources never stop it, stop drains."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable, Sequence

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.ingest.replay import ReplaySource
from service.settings import Settings
from service.store import Store, open_store
from tests.waits import cpu_bound


def recording(
    rng: np.random.Generator, seconds: float = 2.0, imus: int = 4, rate: float = 100.0
) -> Recording:
    n = round(seconds * rate)
    return Recording(
        t=np.arange(n) / rate,
        joint_names=["j1", "j2"],
        q=rng.normal(size=(n, 2)),
        imu_names=[f"imu{k}" for k in range(imus)],
        acc=rng.normal(size=(n, imus, 3)),
        gyro=rng.normal(size=(n, imus, 3)),
    )


class ListSource(Source):
    """Hands out prepared batches, a few per read; raises once when told to (a flaky transport)."""

    def __init__(
        self, name: str, batches: Sequence[FrameBatch], per_read: int = 3, fail_at: int = -1
    ) -> None:
        super().__init__(name)
        self._batches = list(batches)
        self._per_read = per_read
        self._fail_at = fail_at
        self._reads = 0
        self.exhausted = False

    def _read_raw(self, timeout: float) -> Iterable[FrameBatch]:
        self._reads += 1
        if self._reads == self._fail_at:
            raise OSError("transport hiccup")
        out, self._batches = self._batches[: self._per_read], self._batches[self._per_read :]
        self.exhausted = not self._batches
        return out


class SlowStore(Store):
    """A real store whose commits take a while (a database that cannot keep up)."""

    delay = 0.05

    def write_many(self, batches: Sequence[FrameBatch]) -> int:
        time.sleep(self.delay)
        return super().write_many(batches)


def assert_same(rec: Recording, ref: Recording) -> None:
    assert rec.imu_names == ref.imu_names and rec.joint_names == ref.joint_names
    for k in ("t", "q", "acc", "gyro"):
        np.testing.assert_array_equal(getattr(rec, k), getattr(ref, k))


def test_replay_into_store_is_exact(store: Store, rng: np.random.Generator) -> None:
    ref = recording(rng)
    a = ReplaySource(ref, robot="a", speed=math.inf, chunk_seconds=0.05)
    b = ReplaySource(recording(rng, imus=2), robot="b", speed=math.inf, chunk_seconds=0.3)
    commits: list[int] = []
    with Pipeline(store, [a, b], on_commit=lambda bs: commits.append(sum(x.n_samples for x in bs))) as pipe:
        assert pipe.wait_exhausted(timeout=60)
        totals = pipe.totals()
    assert a.counters.as_dict() == {"received": 200, "stored": 200, "dropped": 0, "malformed": 0}
    assert totals["stored"] == 400 and totals["queue_depth"] == 0 and sum(commits) == 400
    assert_same(store.read_between("a", -math.inf, math.inf), ref)
    assert store.sample_count("b") == 200


def test_backpressure_blocks_then_drops_and_counts(db_url: str, rng: np.random.Generator) -> None:
    ref = recording(rng, seconds=4.0)
    src = ReplaySource(ref, robot="r", speed=math.inf, chunk_seconds=0.01)  # 400 one-sample batches
    with SlowStore(db_url) as store:
        store.upgrade()
        pipe = Pipeline(store, [src], queue_max_batches=2, put_timeout=0.005, coalesce_max_samples=2)
        with pipe:
            assert pipe.wait_exhausted(timeout=120)
        c = src.counters.as_dict()
        assert c["dropped"] > 0 and c["stored"] > 0
        assert c["received"] == 400 == c["stored"] + c["dropped"] + c["malformed"]
        assert store.sample_count("r") == c["stored"]
        # What was stored is exactly the recording's frames at those times.
        rec = store.read_between("r", -math.inf, math.inf)
        idx = np.searchsorted(ref.t, rec.t)
        np.testing.assert_array_equal(ref.t[idx], rec.t)
        np.testing.assert_array_equal(ref.acc[idx], rec.acc)


def test_blocking_put_loses_nothing_when_the_store_catches_up(db_url: str, rng: np.random.Generator) -> None:
    ref = recording(rng, seconds=0.6)
    src = ReplaySource(ref, robot="r", speed=math.inf, chunk_seconds=0.01)
    with SlowStore(db_url) as store:
        store.upgrade()
        with Pipeline(store, [src], queue_max_batches=2, put_timeout=5.0, coalesce_max_samples=4) as pipe:
            assert pipe.wait_exhausted(timeout=120)
        assert src.counters.dropped == 0 and store.sample_count("r") == 60


def test_bad_batches_and_failing_reads_do_not_stop_ingest(store: Store, rng: np.random.Generator) -> None:
    def batch(i: int, imus: tuple[str, ...] = ("i0", "i1")) -> FrameBatch:
        k = len(imus)
        return FrameBatch(
            "r",
            np.array([i / 100.0]),
            (),
            np.zeros((1, 0)),
            imus,
            rng.normal(size=(1, k, 3)),
            rng.normal(size=(1, k, 3)),
        )

    batches = [batch(i) for i in range(30)]
    batches[7] = batch(7, ("i0", "i0"))  # passes the source's checks, the store rejects it
    nan = batch(12)
    nan.gyro[0, 0, 0] = np.nan  # the source itself counts this one
    batches[12] = nan
    src = ListSource("list", batches, per_read=4, fail_at=3)
    with Pipeline(store, [src], coalesce_max_samples=100) as pipe:
        assert pipe.wait_exhausted(timeout=60)
    c = src.counters.as_dict()
    assert c["malformed"] == 2 and c["stored"] == 28 and c["read_errors"] == 1 and c["received"] == 30
    rec = store.read_between("r", -math.inf, math.inf)
    assert store.sample_count("r") == 28 and rec.n_samples == 28 and 0.07 not in rec.t and 0.12 not in rec.t


def test_stop_drains_everything_received(db_url: str, rng: np.random.Generator) -> None:
    ref = recording(rng, seconds=30.0)
    src = ReplaySource(ref, robot="r", speed=20.0, chunk_seconds=0.1)  # 1.5 s of wall time in all
    with open_store(db_url) as store:
        pipe = Pipeline(store, [src]).start()
        time.sleep(0.5)
        assert pipe.running
        pipe.stop()
        assert not pipe.running
        c = src.counters.as_dict()
        assert 0 < c["received"] < 3000 and c["stored"] == c["received"] and c["dropped"] == 0
        assert store.sample_count("r") == c["stored"]
        assert not [t for t in threading.enumerate() if t.name.startswith("ingest-")]
    pipe.stop()  # idempotent


def test_pacing_follows_speed(db_url: str, rng: np.random.Generator) -> None:
    ref = recording(rng, seconds=1.0)
    src = ReplaySource(ref, robot="r", speed=4.0, chunk_seconds=0.1)
    # the writer commits what is queued at once: the default lingers up to a second for more frames,
    # which would hide the pacing
    eager = Settings(database_url=db_url, ingest_commit_interval_seconds=0)
    with open_store(db_url) as store, Pipeline(store, [src], settings=eager) as pipe:
        t0 = time.monotonic()
        assert pipe.wait_exhausted(timeout=30)
        wall = time.monotonic() - t0
    # 1 s of data at 4x: 0.25 s of pacing plus the writes; at 1x it would take a second. The writes'
    # share is stretched by the machine's load, so a busy machine does not fail the pacing
    assert 0.2 <= wall < 0.25 + cpu_bound(0.75)


def test_duplicate_source_names_rejected(store: Store, rng: np.random.Generator) -> None:
    a = ReplaySource(recording(rng), robot="x")
    with pytest.raises(ValueError, match="unique"):
        Pipeline(store, [a, a])
