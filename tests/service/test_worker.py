"""The worker on a real store: baseline after K repeats, alerts after M cycles, heartbeats, requests.

The estimator is injected: a scripted one (the topology each cycle is what the test says) isolates the
worker's own logic; signal health and the diff run for real on the frames in the store.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from tests.builders import LAYOUT, synth
from tests.service.builders import GOOD, MOVED, ByMethod, Scripted, feed, ticking
from tests.waits import cpu_bound


@pytest.fixture
def settings() -> Settings:
    return Settings(
        database_url="sqlite://",
        window_seconds=10.0,
        baseline_repeat_k=3,
        alert_hysteresis_m=2,
        worker_interval_seconds=0.05,
    )


@pytest.fixture
def sqlite_store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'w.db'}")
    yield s
    s.close()


def test_baseline_after_k_identical_cycles_then_alert_after_m(
    store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    w = Worker(store, settings, estimator=est, clock=lambda: 1000.0)
    for cycle in range(1, 3):
        assert not w.run_cycle()["arm"].baseline_set
        assert store.baseline("arm") is None, cycle
    assert w.run_cycle()["arm"].baseline_set
    base = store.baseline("arm")
    assert base is not None and base.source == "auto" and base.topology.same_structure(GOOD)
    assert len(store.topology_history("arm")) == 3
    # same body: no finding, no alert
    assert w.run_cycle()["arm"].diff.findings == ()
    est.next = MOVED
    r = w.run_cycle()["arm"]
    assert [f.kind for f in r.diff.findings] == ["imu_moved"] and r.transitions == []
    # seen once: a pending alert at once, raised after M cycles
    assert [(t.state, t.part) for t in r.pending] == [("pending", "imu:c1")]
    assert [(a.state, a.part) for a in store.alerts("arm")] == [("pending", "imu:c1")]
    r = w.run_cycle()["arm"]
    assert [(t.state, t.part) for t in r.transitions] == [("active", "imu:c1")]
    (a,) = store.alerts("arm", active=True)
    assert (a.kind, a.imu, a.finding["from"], a.finding["to"]) == ("imu_moved", "c1", "j3", "j2")
    est.next = GOOD
    w.run_cycle()
    assert len(store.alerts("arm", active=True)) == 1
    w.run_cycle()
    assert store.alerts("arm", active=True) == []
    assert store.alerts("arm")[0].state == "resolved"
    assert store.last_heartbeat("worker") == 1000.0


def test_baseline_waits_for_a_stable_structure(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    w = Worker(sqlite_store, settings, estimator=est)
    for topo in (GOOD, MOVED, GOOD, GOOD):
        est.next = topo
        w.run_cycle()
        assert sqlite_store.baseline("arm") is None
    w.run_cycle()
    assert sqlite_store.baseline("arm") is not None


def test_dead_imu_raises_imu_dead_from_real_signals(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    rec = synth(rng, seconds=12)
    end = feed(sqlite_store, rec)
    w = Worker(sqlite_store, settings, estimator=Scripted(GOOD))
    for _ in range(3):
        w.run_cycle()
    assert sqlite_store.baseline("arm") is not None
    feed(sqlite_store, synth(rng, seconds=12), offset=end, dead="b2")
    assert w.run_cycle()["arm"].transitions == []
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.kind, tr.part) == ("imu_dead", "imu:b2")
    assert w.metrics.alerts_active.labels(robot="arm")._value.get() == 1.0


def test_locked_joint_from_real_signals(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    end = feed(sqlite_store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    w = Worker(sqlite_store, settings, estimator=est)
    for _ in range(3):
        w.run_cycle()
    feed(sqlite_store, synth(rng, seconds=12, locked="j2"), offset=end)
    est.next = Topology(
        dict(LAYOUT.joint_parent),
        {**LAYOUT.imu_joint, "b1": "j1", "b2": "j1"},
        undetermined=("j2",),
        excitation={**LAYOUT.excitation, "j2": 0.0},
    )
    w.run_cycle()
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.kind, tr.part) == ("joint_locked", "joint:j2")


def test_network_schedule_and_requests(sqlite_store: Store, rng: np.random.Generator) -> None:
    feed(sqlite_store, synth(rng, seconds=6))
    s = Settings(database_url="sqlite://", window_seconds=5.0, network_interval_cycles=2)
    est = Scripted(GOOD)
    w = Worker(sqlite_store, s, estimator=est)
    w.run_cycle()
    w.run_cycle()
    assert [m for m, _ in est.calls] == ["fast", "fast", "network"]
    w.request("arm", "mlp")
    w.run_cycle()
    assert [m for m, _ in est.calls][3:] == ["fast", "mlp"]
    assert sqlite_store.latest_topology("arm", method="network") is not None
    assert sqlite_store.latest_topology("arm", method="mlp") is not None
    assert est.calls[0][1] == 500  # 5 s window at 100 Hz


def test_a_new_finding_of_the_fast_screen_asks_for_a_network_retrain_once(
    sqlite_store: Store, rng: np.random.Generator
) -> None:
    """The fast method is the screen: a finding it did not report the cycle before asks for a network
    retrain in the next cycle (in-process here: no cluster), once, not in every cycle it lasts."""
    feed(sqlite_store, synth(rng, seconds=12))
    s = Settings(database_url="sqlite://", window_seconds=5.0, network_interval_cycles=1000)
    est = Scripted(GOOD)
    w = Worker(sqlite_store, s, estimator=est)
    for _ in range(4):  # cycle 0 is a scheduled one; three more make the baseline
        w.run_cycle()
    assert sqlite_store.baseline("arm") is not None
    calls = len(est.calls)
    est.next = MOVED
    w.run_cycle()  # the screen sees the move
    w.run_cycle()  # ... and the network retrain runs in this cycle
    w.run_cycle()  # the same finding again: no new retrain
    methods = [m for m, _ in est.calls[calls:]]
    assert methods == ["fast", "fast", "network", "fast"]
    off = Worker(sqlite_store, s.model_copy(update={"network_on_change": False}), estimator=Scripted(GOOD))
    off.run_cycle()
    off.estimator.next = MOVED
    off.run_cycle()
    off.run_cycle()
    assert "network" not in [m for m, _ in off.estimator.calls[1:]]


def _networks_on(settings: Settings) -> Settings:
    return settings.model_copy(update={"network_interval_cycles": 1000})  # on, never due in a test


def test_with_networks_on_the_baseline_is_the_network_topology_once_it_agrees(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """The networks are the authority for baselines: a complete fast streak waits for a network
    topology of the same body, asks for one, and the baseline adopted is the network's."""
    feed(sqlite_store, synth(rng, seconds=12))
    est = ByMethod(GOOD)
    est.by_method["network"] = MOVED  # the networks disagree with the screen
    w = Worker(sqlite_store, _networks_on(settings), estimator=est)
    for _ in range(5):
        w.run_cycle()
    assert sqlite_store.baseline("arm") is None
    methods = [m for m, _ in est.calls]
    # asked for once, when the streak was complete (third cycle, run in the fourth); the networks'
    # answer on that window stands: not asked again in the fifth
    assert methods == ["fast"] * 4 + ["network", "fast"], methods
    est.by_method["network"] = GOOD
    w.request("arm", "network")  # the next retrain (the schedule's, or one asked for) agrees
    w.run_cycle()
    base = sqlite_store.baseline("arm")
    assert base is not None and base.method == "network"
    assert base.topology.imu_joint == GOOD.imu_joint


def test_a_broken_streak_asks_the_networks_again_for_the_next_one(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """A streak the networks disagreed with, broken by a window that places no joint j2: the next
    complete streak, on newer frames, asks for a network retrain of its own."""
    rec = synth(rng, seconds=24)
    feed(sqlite_store, rec.select(rec.t < 12.0))
    est = ByMethod(GOOD)
    est.by_method["network"] = MOVED
    w = Worker(sqlite_store, _networks_on(settings), estimator=est)
    for _ in range(5):  # the streak completes, asks once, the networks disagree
        w.run_cycle()
    assert [m for m, _ in est.calls].count("network") == 1
    est.next = dataclasses.replace(GOOD, undetermined=("j2",))
    w.run_cycle()  # breaks the streak
    feed(sqlite_store, rec.select(rec.t >= 12.0))
    est.next = GOOD
    for _ in range(4):  # a new streak on newer frames completes, asks, and the retrain runs
        w.run_cycle()
    assert [m for m, _ in est.calls].count("network") == 2
    assert sqlite_store.baseline("arm") is None


def test_with_networks_on_a_structural_finding_needs_the_networks_to_alert(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """The fast method is the screen: its structural finding is a pending alert until a network
    topology from a window that ended after it was first seen shows a change there too; one that does
    not withdraws it (resolved, with the reason)."""
    rec = synth(rng, seconds=24)
    feed(sqlite_store, rec.select(rec.t < 12.0))
    est = ByMethod(GOOD)
    est.by_method["network"] = GOOD
    w = Worker(sqlite_store, _networks_on(settings), estimator=est, clock=ticking())
    for _ in range(4):  # three make the streak, the fourth runs the networks it asked for
        w.run_cycle()
    assert sqlite_store.baseline("arm") is not None
    feed(sqlite_store, rec.select(rec.t >= 12.0))  # newer frames: the old network window is too early
    est.next = MOVED  # the screen sees c1 on j2; the networks still see the baseline body
    first = w.run_cycle()["arm"]  # pending: no network topology since the finding; one asked for
    assert first.transitions == [] and [f.kind for f in first.diff.findings] == ["imu_moved"]
    assert [(t.state, t.part) for t in first.pending] == [("pending", "imu:c1")]
    assert w.tracker.pending("arm") == [("arm", "imu_moved", "imu:c1")]
    assert [m for m, _ in est.calls[-1:]] == ["fast"]
    second = w.run_cycle()["arm"]  # the retrain runs in this cycle and shows no change: withdrawn
    assert [m for m, _ in est.calls[-2:]] == ["fast", "network"]
    assert [t.state for t in second.transitions] == ["resolved"] and second.diff.findings == ()
    assert second.transitions[0].note.startswith("withdrawn: the sensor networks' topology")
    for _ in range(2):
        assert w.run_cycle()["arm"].transitions == []
    (gone,) = sqlite_store.alerts("arm")
    assert gone.state == "resolved" and "no change of imu:c1" in gone.note
    assert w.tracker.pending("arm") == []
    est.by_method["network"] = MOVED  # the networks now see it too
    w.request("arm", "network")
    transitions = []
    for _ in range(3):
        transitions += w.run_cycle()["arm"].transitions
    assert [(t.kind, t.part, t.state) for t in transitions] == [("imu_moved", "imu:c1", "active")]


def test_restart_keeps_active_alerts_without_raising_twice(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    clock = ticking()  # a slow cycle on a loaded machine must not make the robot read as idle
    w = Worker(sqlite_store, settings, estimator=est, clock=clock)
    for _ in range(3):
        w.run_cycle()
    est.next = MOVED
    w.run_cycle()
    w.run_cycle()
    assert len(sqlite_store.alerts("arm", active=True)) == 1
    w2 = Worker(sqlite_store, settings, estimator=est, clock=clock)
    assert w2.run_cycle()["arm"].transitions == []
    assert len(sqlite_store.alerts("arm")) == 1
    est.next = GOOD
    w2.run_cycle()
    assert [t.state for t in w2.run_cycle()["arm"].transitions] == ["resolved"]


def test_operator_baseline_resolves_open_alerts(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    w = Worker(sqlite_store, settings, estimator=est)
    for _ in range(3):
        w.run_cycle()
    est.next = MOVED
    w.run_cycle()
    w.run_cycle()
    base = w.approve_baseline("arm")
    assert base.source == "operator" and base.topology.imu_joint["c1"] == "j2"
    assert sqlite_store.alerts("arm", active=True) == []
    assert w.run_cycle()["arm"].diff.findings == ()


def test_short_window_is_skipped_but_heartbeat_written(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=0.3))
    est = Scripted(GOOD)
    w = Worker(sqlite_store, settings, estimator=est, clock=lambda: 42.0)
    assert w.run_cycle()["arm"].skipped
    assert est.calls == []
    assert sqlite_store.last_heartbeat("worker") == 42.0


def test_failing_estimator_does_not_stop_the_thread(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=6))

    def broken(rec: Recording, method: str) -> Topology:
        raise RuntimeError("estimator blew up")

    w = Worker(sqlite_store, settings, estimator=broken)
    w.start()
    try:
        deadline = time.monotonic() + cpu_bound(10)  # three short cycles
        while w.metrics.cycles._value.get() < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        w.stop()
    assert w.metrics.cycles._value.get() >= 3
    assert w.metrics.cycle_errors._value.get() >= 3
    assert not w.running
    assert sqlite_store.last_heartbeat("worker") is not None


def test_no_baseline_from_an_ambiguous_or_short_window(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=12))
    ambiguous = Topology(
        dict(GOOD.joint_parent), dict(GOOD.imu_joint), unique=False, candidates=(GOOD,), method="fast"
    )
    w = Worker(sqlite_store, settings, estimator=Scripted(ambiguous))
    for _ in range(4):
        w.run_cycle()
    assert sqlite_store.baseline("arm") is None
    short = Settings(database_url="sqlite://", window_seconds=30.0, baseline_repeat_k=1)
    w2 = Worker(sqlite_store, short, estimator=Scripted(GOOD))
    w2.run_cycle()  # 12 s of data in a 30 s window: too short to trust
    assert sqlite_store.baseline("arm") is None


def test_ambiguous_cycles_neither_count_nor_break_the_streak(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    feed(sqlite_store, synth(rng, seconds=12))
    est = Scripted(GOOD)
    w = Worker(sqlite_store, settings, estimator=est)
    ambiguous = dataclasses.replace(GOOD, unique=False, candidates=(GOOD,))
    for topo in (GOOD, ambiguous, GOOD, ambiguous):
        est.next = topo
        w.run_cycle()
        assert sqlite_store.baseline("arm") is None
    est.next = GOOD
    assert w.run_cycle()["arm"].baseline_set


def test_encoder_offset_raises_after_the_fingerprint_is_learned(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    rec = synth(rng, seconds=36)
    w = Worker(sqlite_store, settings, estimator=Scripted(GOOD))
    feed(sqlite_store, rec.window(0.0, 12.0))
    for _ in range(3):
        w.run_cycle()
    assert sqlite_store.baseline("arm") is not None and "arm" not in w.fingerprints_
    feed(sqlite_store, rec.window(12.0, 24.0))
    assert w.run_cycle()["arm"].diff.findings == ()
    assert set(w.fingerprints_["arm"].joints) == {"j1", "j2", "j3"}
    late = rec.window(24.0, 36.0)
    q = late.q.copy()
    q[:, 1] += 0.3
    feed(sqlite_store, dataclasses.replace(late, q=q))
    w.run_cycle()
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.kind, tr.part, tr.state) == ("encoder_fault", "joint:j2", "active")


def test_the_cpu_bound_steps_run_where_compute_says(
    store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """The service hands impact removal, signal health and fingerprints to the estimator's child
    (off the API's interpreter lock); the worker calls them through ``compute`` and uses its answers."""
    from bodyschema.health import baseline_fingerprints, signal_health
    from bodyschema.impacts import drop_impacts

    feed(store, synth(rng, seconds=12))
    calls: list[str] = []

    def compute(fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        calls.append(fn.__name__)
        return fn(*args, **kwargs)

    w = Worker(store, settings, estimator=Scripted(GOOD), compute=compute)
    results = [w.run_cycle()["arm"] for _ in range(4)]
    assert results[2].baseline_set and results[3].diff is not None
    assert calls.count(drop_impacts.__name__) == 4 and calls.count(signal_health.__name__) == 4
    assert calls.count(baseline_fingerprints.__name__) == 1  # once, on the first window after the baseline
    assert "arm" in w.fingerprints_


def test_after_a_restart_the_fingerprints_wait_for_a_full_window(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """Fingerprints fitted on the first seconds of a new clock epoch miss the encoder relation, and later
    full windows then read as a shifted encoder (three false ``encoder_fault`` alerts after a late
    restart in docs/bench/alerts.md): they are learned on the first full window with no hole."""
    rec = synth(rng, seconds=36)
    feed(sqlite_store, rec.window(0.0, 12.0), offset=50.0)
    w = Worker(sqlite_store, settings, estimator=Scripted(GOOD))
    for _ in range(4):
        w.run_cycle()
    assert "arm" in w.fingerprints_
    w2 = Worker(sqlite_store, settings, estimator=Scripted(GOOD))  # restarted, and so is the robot's clock
    feed(sqlite_store, rec.window(12.0, 15.0), offset=-12.0)
    res = w2.run_cycle()["arm"]
    assert res.diff is not None and res.diff.findings == ()  # judged, healthy, but 3 s long
    assert "arm" not in w2.fingerprints_
    feed(sqlite_store, rec.window(15.0, 24.0), offset=-12.0)
    assert w2.run_cycle()["arm"].diff.findings == ()
    assert set(w2.fingerprints_["arm"].joints) == {"j1", "j2", "j3"}
