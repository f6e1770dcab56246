"""Lever-arm pools through the worker's real cycle: the geometry baseline's pool and the newest
estimate's fill in the store as estimates come, outlive a restart, and follow the frame the settings
set; a healthy UR5e raises nothing meanwhile (tests/service/test_drift_worker.py has the drift alerts).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bodyschema.lever_pool import POOL_KEY
from service.settings import Settings
from service.store import Store, open_store
from service.worker import FRAME_KEY, Worker
from simulators.farm import Farm
from tests.service.damage_runs import ROBOT, cycle_once, feed_farm

pytestmark = pytest.mark.slow


def _pools(store: Store, baseline_id: int) -> tuple[list, list]:
    """The lever-arm pools kept under ``baseline_id``: the geometry baseline's, the newest estimate's."""
    kept, newest = store.kinematics_baseline(ROBOT, baseline_id), store.kinematics_latest(ROBOT, baseline_id)
    assert kept is not None and newest is not None
    return kept.data.get(POOL_KEY) or [], (newest.data.get(POOL_KEY) or []) if newest.id != kept.id else []


def test_lever_pools_fill_in_the_store_and_outlive_a_restart(tmp_path: Path) -> None:
    """The geometry baseline's pool takes the estimates after it until it holds
    ``kinematics_pool_base`` of them, then the newest estimate's pool the last ``kinematics_pool_recent``;
    both are in the store, so a restarted worker goes on with them (the baseline's pool unchanged, the
    recent one moved on by the new estimate) and a healthy robot raises nothing meanwhile."""
    settings = Settings(database_url="sqlite://", kinematics_pool_base=5, kinematics_pool_recent=3)
    interval, every = settings.worker_interval_seconds, settings.kinematics_interval_cycles
    farm = Farm({ROBOT: "ur5e"}, seed=7, sensing="robot")
    store = open_store(f"sqlite:///{tmp_path / 'pool.db'}", settings=settings)
    history: list[list[tuple[str, str]]] = []
    alerts: list[tuple[str, str, int]] = []
    judged: list[bool] = []  # per geometry comparison: were the lever arms judged?

    class Seen(Worker):
        def run_cycle(self):  # type: ignore[no-untyped-def]
            out = super().run_cycle()
            judged.extend(r.slides_judged for r in out.values() if r.drift_judged)
            return out

    def cycles(worker: Worker, n: int) -> None:
        for _ in range(n):
            feed_farm(farm, store, interval)
            cycle_once(worker, history, alerts)

    worker = Seen(store, settings)
    feed_farm(farm, store, settings.window_seconds - interval)
    while store.baseline(ROBOT) is None:
        assert len(history) < 3 * settings.baseline_repeat_k
        cycles(worker, 1)
    base_id = store.baseline(ROBOT).id
    sizes: list[tuple[int, int]] = []
    while not sizes or sizes[-1] != (5, 3):
        assert len(sizes) < 12, sizes
        cycles(worker, every)  # one geometry estimate per `every` cycles
        if store.kinematics_baseline(ROBOT, base_id) is not None:
            sizes.append(tuple(len(p) for p in _pools(store, base_id)))  # type: ignore[arg-type]
    # the geometry baseline's own lever arms, four more estimates', then the recent pool's three
    assert sizes == [(1, 0), (2, 0), (3, 0), (4, 0), (5, 0), (5, 1), (5, 2), (5, 3)]
    # the first geometry is kept, not compared; the lever arms are judged once the baseline's pool is full
    assert judged == [False] * 4 + [True] * 3
    base_pool, recent = _pools(store, base_id)
    worker = Worker(store, settings)  # a restart: the pools come from the store
    cycles(worker, 2 * every)
    after_base, after_recent = _pools(store, base_id)
    assert after_base == base_pool
    assert len(after_recent) == 3 and after_recent[0] == recent[2]
    assert alerts == [] and all(h == [] for h in history[-len(sizes) * every :])
    # the geometry was kept in the frame the settings set; a worker set to the other frame keeps the
    # next estimate in its place, with a pool of its own lever arms, rather than compare lever arms
    # fitted about other axes
    frame = settings.kinematics_accelerometer_frame
    kept = store.kinematics_baseline(ROBOT, base_id)
    assert kept is not None and kept.data[FRAME_KEY] is frame
    other = settings.model_copy(update={"kinematics_accelerometer_frame": not frame})
    cycles(Worker(store, other), every)
    again = store.kinematics_baseline(ROBOT, base_id)
    assert again is not None and again.id == kept.id and again.data[FRAME_KEY] is (not frame)
    assert again.wall_time > kept.wall_time and [len(p) for p in _pools(store, base_id)] == [1, 0]
    assert alerts == []
    store.close()
