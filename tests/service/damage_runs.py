"""The damage suite's machinery: every damage kind on a catalog robot, through the worker's real cycle.

Each robot runs in the simulated farm under the ``robot`` sensing preset (multi-rate, quantized
position-only encoders on their own clock, low-passed IMUs, skew, drift, drops), its frames go into a
real :class:`~service.store.Store` on an SQLite file, and a :class:`~service.worker.Worker` with the
production settings (30 s window, a cycle every 5 s of device time, K=3, M=2; the geometry's
estimates only where asked for, :func:`run_robot`) learns the baseline and watches it. Then one
damage is injected and cycles run until the first alert. :func:`check` asserts:

* the nominal run (no damage) raises no alert, ever;
* after a damage, the first alert raised is of the injected kind and names the injected part,
  within the time a window needs to pass the change (``POST_CYCLES``).

The healthy history (baseline learning and the first nominal cycles) is shared: at the injection
instant the farm is forked (:meth:`simulators.farm.Farm.fork`), the database copied and a worker with
the same learned state opened on the copy, so every damage continues exactly the history it would
have had alone, and the suite simulates and learns that history once per robot instead of seven
times.

The catalog's robots are split over ``SHARES`` test files (tests/service/test_damage_worker*.py,
:func:`share`): the suite's workers take whole files, and one file of every robot kept one worker
busy for minutes while the other had run out of work.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from service.ingest.replay import recording_batch
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from simulators.catalog import CATALOG
from simulators.damage import DAMAGES
from simulators.farm import Farm
from tests.conftest import node_seed

__all__ = [
    "POST_CYCLES",
    "SHARES",
    "DamageRun",
    "RobotRuns",
    "check",
    "cycle_once",
    "feed_farm",
    "quiet_alert_log",
    "robot_seed",
    "run_robot",
    "share",
]

#: Test files the catalog's robots are split over (:func:`share`).
SHARES = 3
#: The node id the robots' seeds are drawn from (:func:`robot_seed`).
SEED_ID = "tests/service/test_damage_worker.py::test_every_damage_alerts_first_with_its_kind_on_robot_sensing"
ROBOT = "r"
#: Device seconds per farm chunk written to the store (the worker reads by device time: the chunk
#: size changes nothing but the number of writes).
CHUNK = 1.0
#: Cycles after the damage within which its alert must come: the window needs
#: ``window / interval`` cycles to pass the change, and M more cycles to raise it.
POST_CYCLES = 9
#: Nominal cycles after the fork point (besides the healthy history the damages share).
NOMINAL_CYCLES = 4


@dataclass
class DamageRun:
    """One damage on one robot: what was injected, every alert raised in order, and when."""

    kind: str
    part: str
    truth: dict
    alerts: list[tuple[str, str, int]] = field(default_factory=list)
    first_finding: dict | None = None
    findings: list[list[tuple[str, str]]] = field(default_factory=list)

    @property
    def first(self) -> tuple[str, str, int] | None:
        return self.alerts[0] if self.alerts else None


@dataclass
class RobotRuns:
    """The nominal run and every damage run of one robot."""

    robot: str
    baseline_cycle: int
    nominal_alerts: list[tuple[str, str, int]]
    nominal_findings: list[list[tuple[str, str]]]
    damages: dict[str, DamageRun]
    cpu_seconds: float


def feed_farm(farm: Farm, store: Store, seconds: float) -> None:
    """Write ``seconds`` of the farm's device time into ``store``, in chunks of :data:`CHUNK`."""
    for _ in range(round(seconds / CHUNK)):
        for name, rec in farm.advance(CHUNK).items():
            store.write(recording_batch(name, rec))


def cycle_once(
    worker: Worker, log: list[list[tuple[str, str]]], alerts: list[tuple[str, str, int]]
) -> dict | None:
    """One worker cycle; appends its findings and raised alerts, returns the first raised finding."""
    res = worker.run_cycle()[ROBOT]
    log.append([(f.kind, f.part) for f in (res.diff.findings if res.diff is not None else ())])
    raised = [tr for tr in res.transitions if tr.state == "active"]
    alerts += [(tr.kind, tr.part, len(log)) for tr in raised]
    return raised[0].finding.to_json() if raised else None


def _copy_db(src: Path, dst: Path) -> None:
    a, b = sqlite3.connect(src), sqlite3.connect(dst)
    try:
        a.backup(b)
    finally:
        b.close()
        a.close()


def run_robot(
    catalog_name: str,
    seed: int,
    tmp: Path,
    *,
    sensing: str = "robot",
    kinds: tuple[str, ...] = DAMAGES,
    post_cycles: int = POST_CYCLES,
    nominal_cycles: int = NOMINAL_CYCLES,
    damage_kwargs: dict[str, dict[str, Any]] | None = None,
    settings: Settings | None = None,
    healthy_cycles: int = 1,
    geometry: bool = False,
) -> RobotRuns:
    """Run the healthy history, the nominal continuation and each damage of ``kinds`` (see the module
    doc) for one catalog robot; a damage run stops at its first alert. ``damage_kwargs`` gives a kind's
    parts and magnitude (default: the robot's seeded picks); ``settings`` default to production's,
    with the geometry's estimates only when ``geometry``: the damages of :data:`DAMAGES` change the
    structure, which the diff finds and the geometry then does not judge, while its first estimate
    (kept, never compared within these runs) cost half a robot's CPU time; the geometry's own kinds run
    with it on (tests/service/test_drift_worker.py)."""
    cpu0 = time.process_time()
    # production window, interval, K and M
    settings = settings or Settings(
        database_url="sqlite://", **({} if geometry else {"kinematics_interval_cycles": 0})
    )
    interval = settings.worker_interval_seconds
    farm = Farm({ROBOT: catalog_name}, seed=seed, sensing=sensing)
    path = tmp / f"{catalog_name}-{sensing}.db"
    store = open_store(f"sqlite:///{path}", settings=settings)
    worker = Worker(store, settings)
    history: list[list[tuple[str, str]]] = []
    nominal_alerts: list[tuple[str, str, int]] = []
    feed_farm(farm, store, settings.window_seconds - interval)
    while store.baseline(ROBOT) is None:
        assert len(history) < 3 * settings.baseline_repeat_k, f"{catalog_name}: no baseline learned"
        feed_farm(farm, store, interval)
        cycle_once(worker, history, nominal_alerts)
    baseline_cycle = len(history)
    for _ in range(healthy_cycles):  # healthy cycles on the baseline: the worker learns its fingerprints
        feed_farm(farm, store, interval)
        cycle_once(worker, history, nominal_alerts)

    damages: dict[str, DamageRun] = {}
    for kind in kinds:
        branch = farm.fork()
        copy = tmp / f"{catalog_name}-{sensing}-{kind}.db"
        _copy_db(path, copy)
        with Store(f"sqlite:///{copy}", settings=settings) as bstore:  # a copy of an upgraded file
            bworker = Worker(bstore, settings)
            bworker.fingerprints_ = dict(worker.fingerprints_)
            (truth,) = branch.apply_damage(ROBOT, kind, **(damage_kwargs or {}).get(kind, {})).findings
            run = DamageRun(kind, truth.part, truth.to_json())
            while run.first is None and len(run.findings) < post_cycles:
                feed_farm(branch, bstore, interval)
                run.first_finding = cycle_once(bworker, run.findings, run.alerts)
            damages[kind] = run

    for _ in range(nominal_cycles):
        feed_farm(farm, store, interval)
        cycle_once(worker, history, nominal_alerts)
    store.close()
    return RobotRuns(
        catalog_name,
        baseline_cycle,
        nominal_alerts,
        history,
        damages,
        time.process_time() - cpu0,
    )


@pytest.fixture(autouse=True)
def quiet_alert_log() -> None:
    """The worker logs every alert it raises: hundreds in a damage run, none of them news here."""
    logging.getLogger("service.worker").setLevel(logging.ERROR)


def matrix(runs: RobotRuns) -> dict[str, tuple[str, str, int] | None]:
    """Per damage kind: the first alert (kind, part, cycles after the damage)."""
    return {k: r.first for k, r in runs.damages.items()}


#: Damages the monitor does not see, by (robot, kind), with why. Each is asserted to stay unseen, so
#: a change that makes it visible fails here and the entry is removed. (None now: the loose IMU on
#: the base joint's link of paper-1 and paper-2, which the estimators still place on its link, is
#: found against its own residual share on the baseline, bodyschema.health.loose_imus.)
KNOWN_MISSES: dict[tuple[str, str], str] = {}


def robot_seed(catalog_name: str) -> int:
    """The farm seed of ``catalog_name``'s damage run: fixed by the robot's name, whichever file of the
    suite runs it (``BODYHEALTH_TEST_SEED`` pins or redraws it, as every test's seed)."""
    return node_seed(f"{SEED_ID}[{catalog_name}]") % 1000


def share(i: int) -> list[str]:
    """The catalog robots of the ``i``-th of the ``SHARES`` files the damage suite is split over, so
    that the suite's workers run them side by side."""
    return sorted(CATALOG)[i::SHARES]


def check(runs: RobotRuns) -> None:
    print(f"{runs.robot}: baseline after {runs.baseline_cycle} cycles, {runs.cpu_seconds:.1f} CPU s")
    for kind, first in matrix(runs).items():
        print(f"  {kind:14s} -> {first}")
    assert runs.baseline_cycle == 3  # K equal topologies from the first full window on
    assert runs.nominal_alerts == [], runs.nominal_findings
    assert all(f == [] for f in runs.nominal_findings[runs.baseline_cycle :]), runs.nominal_findings
    missed = {k for k in runs.damages if (runs.robot, k) in KNOWN_MISSES}
    for kind in missed:  # still unseen: no alert and no finding of any kind, never a wrong one
        assert runs.damages[kind].alerts == [], (kind, runs.damages[kind].alerts)
        assert all(f == [] for f in runs.damages[kind].findings), runs.damages[kind].findings
    damages = {k: r for k, r in runs.damages.items() if k not in missed}
    firsts = {k: (r.first[0], r.first[1]) if r.first else None for k, r in damages.items()}
    assert firsts == {k: (k, r.part) for k, r in damages.items()}, {k: r.findings for k, r in damages.items()}
    for kind, run in damages.items():
        assert run.first is not None and run.first[2] <= POST_CYCLES
        assert run.first_finding is not None
        if kind == "imu_moved":  # raised where the IMU went
            assert run.first_finding["to"] == run.truth["to"], run.first_finding
        # one finding only: nothing else was raised in the cycle the damage's alert came
        assert [a for a in run.alerts if a[2] == run.first[2]] == [run.first]
