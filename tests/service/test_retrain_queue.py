"""The retrain queue: pinned windows, admission control, the queue's status (real SQLite, real Dask).

* retention keeps every chunk of a pinned window, of that robot and clock epoch only, until the pin
  is released or lapses;
* wants beyond the cap wait, oldest first and round-robin over robots; a full queue refuses a new
  want and says, from the retrains' expected wall times, when one fits;
* a retrain queued on a busy cluster while retention passes its window trains on that window, and
  the frames go once it is collected;
* the retrain route answers 429 with ``Retry-After`` from the recent wall times while the queue is
  full (at least 1 s, also once the one in flight ran past its expected time), and 202 for a retrain
  already in flight.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from distributed import Client, Event, LocalCluster
from fastapi.testclient import TestClient

from service.api import create_app
from service.cluster import ClusterOptions, TrainingCluster
from service.metrics import Metrics
from service.retrain import NetworkOptions, RemoteRetrains, RetrainLimits, RetrainQueueEntry, TrainingOptions
from service.retrain.queue import ASSUMED_RETRAIN_SECONDS
from service.settings import Settings
from service.store import Store, open_store
from service.store.pins import WindowPin
from service.worker import Worker
from tests.builders import synth
from tests.service.builders import GOOD, Scripted, feed, stream

WINDOW = 4.0
RETENTION = 5.0
SEED = 5
#: one retrain's wall time at most here (2 epochs on a 4 s window, torch's import included): the bound
#: every wait on a retrain derives from, as the service's own pins do
MAX_WALL = 120.0


class Ticks:
    """A clock that reads what the test sets."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


# ------------------------------------------------------------------------------------------- pins
def test_prune_keeps_a_pinned_window_until_it_is_released_or_lapses(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    with open_store(
        f"sqlite:///{tmp_path / 'pins.db'}", retention_seconds=0.995, chunk_max_samples=10
    ) as store:
        store.write_many(stream(rng, 5.0))  # r1: t = 0.00 .. 4.99 in chunks of 0.1 s
        before = store.read_window("r1", 1.0, end=2.0, epoch=0)
        ticks = Ticks()
        pins = store.window_pins
        pins.clock = ticks
        pins.pin("job", WindowPin("r1", 0, 1.0, 2.0), ttl=10.0)
        pins.pin("another-epoch", WindowPin("r1", 1, 0.0, 5.0), ttl=10.0)  # keeps nothing of epoch 0
        pins.pin("another-robot", WindowPin("r2", 0, 0.0, 5.0), ttl=10.0)
        # cutoff 3.995: the 40 chunks ending before it are aged; the 11 chunks overlapping (1, 2]
        # (t_start <= 2.0 and t_end > 1.0: t from 1.00 to 2.09) stay
        assert store.prune() == 400 - 110
        assert store.sample_count("r1") == 100 + 110
        after = store.read_window("r1", 1.0, end=2.0, epoch=0)
        assert after is not None and before is not None and after.n_samples == 100
        for k in ("t", "q", "acc", "gyro"):
            np.testing.assert_array_equal(getattr(after, k), getattr(before, k))

        assert pins.unpin("job") and not pins.unpin("job")
        assert store.prune() == 110 and store.sample_count("r1") == 100

        pins.pin("late", WindowPin("r1", 0, 4.0, 4.5), ttl=10.0)
        ticks.now = 9.99
        # only the 6 chunks overlapping (4.0, 4.5] stay (t from 4.00 to 4.59)
        assert store.prune(now_t=100.0) == 40
        ticks.now = 10.0  # the pin lapsed: nothing holds the frames any more
        assert store.prune(now_t=100.0) == 60 and store.sample_count("r1") == 0
        assert len(pins) == 0


# -------------------------------------------------------------------------------------- admission
def test_wants_beyond_the_cap_wait_in_a_fair_order_and_a_full_queue_says_when(tmp_path: Path) -> None:
    store = open_store(f"sqlite:///{tmp_path / 'fair.db'}")
    # never started: nothing here submits, the queue is all in this process
    cluster = TrainingCluster(ClusterOptions(scheduler="tcp://127.0.0.1:9"))
    ticks = Ticks(1000.0)
    metrics = Metrics()
    remote = RemoteRetrains(
        cluster, store, WINDOW, metrics=metrics, limits=RetrainLimits(max_queued=3), clock=ticks
    )
    try:
        for robot, method in (("a", "network"), ("a", "mlp"), ("a", "network-paper"), ("b", "network")):
            remote.want(robot, method)
            ticks.now += 1.0
        remote.want("a", "network")  # asked again: keeps its place and its time
        status = remote.queue_status()
        assert [(e.robot, e.method, e.position) for e in status] == [
            ("a", "network", 0),
            ("b", "network", 1),  # b's first before a's second: round-robin over robots
            ("a", "mlp", 2),
            ("a", "network-paper", 3),
        ]
        assert [e.since for e in status] == [1000.0, 1003.0, 1001.0, 1002.0]
        assert all(e.state == "waiting" and e.window_end is None for e in status)
        assert all(e.expected_seconds is None and e.cpu_seconds is None for e in status)
        assert status[1].to_json() == {
            "robot": "b",
            "method": "network",
            "state": "waiting",
            "position": 1,
            "since": 1003.0,
            "expected_seconds": None,
            "cpu_seconds": None,
            "window_end": None,
        }
        assert metrics.retrains_waiting._value.get() == 4

        # full (4 waiting, cap 3): two must finish before a fifth fits; on the one thread an external
        # scheduler counts before it answers, at the assumed wall time each, one after the other
        assert remote.capacity() == 3
        assert remote.admit("c", "network") == 2 * ASSUMED_RETRAIN_SECONDS
        assert ("c", "network") not in remote.wanted()
        assert remote.admit("b", "network") == 0.0  # answered by the one waiting
        assert len(remote.wanted()) == 4
    finally:
        cluster.close()
        store.close()


# ---------------------------------------------------------------------------------- on a cluster
def _hold(started: str, gate: str, seconds: float) -> None:
    """Hold the worker's one thread until ``gate`` is set (a task the queued retrain waits behind)."""
    Event(started).set()
    Event(gate).wait(seconds)


class Occupied:
    """The cluster's one thread held by a :func:`_hold` task (named ``name``) until :meth:`release`:
    whatever is submitted meanwhile waits behind it."""

    def __init__(self, client: Client, name: str) -> None:
        self.gate = Event(f"gate-{name}", client=client)
        self.task = client.submit(
            _hold, f"held-{name}", f"gate-{name}", MAX_WALL, key=f"hold-{name}", pure=False
        )
        assert Event(f"held-{name}", client=client).wait(MAX_WALL)  # the one thread is busy now

    def release(self) -> None:
        self.gate.set()
        self.task.result(timeout=MAX_WALL)


@pytest.fixture(scope="module")
def one_thread() -> Iterator[LocalCluster]:
    """One worker process of one thread: a second task waits for the first."""
    cluster = LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
    )
    try:
        yield cluster
    finally:
        cluster.close()


def _until(what: str, done: Any, seconds: float, step: Any = None) -> None:
    """Call ``step`` until ``done()``, at most ``seconds``."""
    t0 = time.monotonic()
    while not done():
        assert time.monotonic() - t0 < seconds, f"not within {seconds} s: {what}"
        if step is not None:
            step()
        time.sleep(0.05)


def _network_rows(store: Store, robot: str = "arm") -> list[Any]:
    return [r for r in store.topology_history(robot, limit=100) if r.method == "network"]


@pytest.mark.slow
def test_a_queued_retrain_trains_on_its_window_while_retention_passes_it(
    tmp_path: Path, one_thread: LocalCluster
) -> None:
    url = f"sqlite:///{tmp_path / 'queue.db'}"
    store = open_store(url, retention_seconds=RETENTION, chunk_max_samples=100)
    cluster = TrainingCluster(ClusterOptions(scheduler=one_thread.scheduler_address))
    client = Client(one_thread, set_as_default=False)
    metrics = Metrics()
    limits = RetrainLimits(max_queued=1, max_wall_seconds=MAX_WALL)
    options = TrainingOptions(network=NetworkOptions(seed=SEED, epochs=2))
    remote = RemoteRetrains(cluster, store, WINDOW, options=options, metrics=metrics, limits=limits)
    try:
        end = feed(store, synth(np.random.default_rng(3), seconds=8)) - 0.01  # last frame 7.99
        held = Occupied(client, "1")

        remote.want("arm", "network")
        _until("the retrain submitted", lambda: bool(remote.in_flight()), MAX_WALL, remote.submit_wanted)
        ((_, key),) = remote.in_flight().items()
        assert key == f"retrain-network-arm-e0-{end:.6f}"
        (entry,) = remote.queue_status()
        assert (entry.robot, entry.state, entry.position, entry.window_end) == ("arm", "running", 0, end)
        assert metrics.retrains_in_flight._value.get() == 1

        # the farm runs on while the retrain waits: retention (5 s) passes its window (3.99, 7.99]
        window = store.read_window("arm", WINDOW, end=end, epoch=0)
        feed(store, synth(np.random.default_rng(4), seconds=8), offset=8.0)  # last frame 15.99
        # cutoff 10.99: of the ten 1 s chunks before it, the four of the window (t from 4 to 8) stay
        assert store.prune() == 600
        kept = store.read_window("arm", WINDOW, end=end, epoch=0)
        assert window is not None and kept is not None
        np.testing.assert_array_equal(kept.t, window.t)
        np.testing.assert_array_equal(kept.gyro, window.gyro)

        held.release()
        _until(
            "the retrain stored",
            lambda: bool(_network_rows(store)),
            MAX_WALL,
            lambda: remote.collect(time.time),
        )
        (row,) = _network_rows(store)
        (res,) = remote.results
        assert row.window_end_t == res.window_end == end and res.key == key
        assert metrics.retrain_failures.labels(method="network")._value.get() == 0
        assert remote.expected_wall("network") == res.wall_seconds > 0
        # collected: the pin is gone, and retention takes the window it held
        assert len(store.window_pins) == 0 and remote.queue_status() == []
        store.prune()
        assert store.read_window("arm", WINDOW, end=end, epoch=0) is None
        _full_queue_is_429(store, remote, client, res.wall_seconds)
    finally:
        client.close()
        cluster.close()
        store.close()


def _full_queue_is_429(store: Store, remote: RemoteRetrains, client: Client, wall: float) -> None:
    """With one retrain in flight (cap 1) the route refuses another robot's with ``Retry-After`` the
    rest of the recent wall time, and takes the robot's own (answered by the one in flight). The one
    in flight waits behind a held task: a 2-epoch retrain can end before the request comes, and a
    finished one frees its slot."""
    feed(store, synth(np.random.default_rng(5), seconds=4), robot="arm2")
    settings = Settings(database_url=store.url, window_seconds=WINDOW, retrain_min_interval_seconds=0)
    worker = Worker(store, settings, estimator=Scripted(GOOD), remote=remote, metrics=remote.metrics)
    feed(store, synth(np.random.default_rng(6), seconds=4), offset=16.0)  # a window not learned yet
    held = Occupied(client, "2")
    t0 = time.monotonic()
    remote.want("arm", "network")
    assert remote.submit_wanted()
    app = create_app(store, settings=settings, worker=worker)
    with TestClient(app, headers={"X-Requested-With": "bodyhealth"}) as http:
        refused = http.post("/api/v1/robots/arm2/topology/retrain", params={"method": "network"})
        elapsed = time.monotonic() - t0
        assert refused.status_code == 429 and "queue is full" in refused.json()["detail"]
        retry = int(refused.headers["Retry-After"])
        # the one in flight is expected to finish after the recent wall time, less what it ran so far
        assert max(1, math.floor(wall - elapsed)) <= retry <= max(1, math.ceil(wall))
        assert ("arm2", "network") not in remote.wanted()
        # past its expected wall time the one in flight is expected any moment, but it holds its slot
        # until a cycle collects it: still refused, retry in a second
        time.sleep(max(0.0, wall - (time.monotonic() - t0)) + 0.5)
        late = http.post("/api/v1/robots/arm2/topology/retrain", params={"method": "network"})
        assert late.status_code == 429 and late.headers["Retry-After"] == "1", late.text
        again = http.post("/api/v1/robots/arm/topology/retrain", params={"method": "network"})
        assert again.status_code == 202 and remote.wanted() == set()
    remote.want("arm2", "mlp")  # the worker's own wants beyond the cap wait, holding no window
    assert remote.submit_wanted() == [] and remote.wanted() == {("arm2", "mlp")}
    running, waiting = remote.queue_status()
    assert isinstance(running, RetrainQueueEntry)
    assert (running.robot, running.state, running.position) == ("arm", "running", 0)
    assert (waiting.robot, waiting.state, waiting.position, waiting.window_end) == (
        "arm2",
        "waiting",
        1,
        None,
    )
    assert running.expected_seconds is not None and running.expected_seconds <= wall
    assert waiting.expected_seconds is None  # no mlp retrain finished here yet
    assert remote.metrics.retrains_waiting._value.get() == 1
    held.release()
    _until(
        "the second retrain stored",
        lambda: len(_network_rows(store)) == 2,
        MAX_WALL,
        lambda: remote.collect(time.time),
    )
