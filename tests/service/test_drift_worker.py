"""Geometry drift through the worker's real cycle: a turned IMU, a bent axis and a dead band raise
their alerts.

A UR5e runs in the simulated farm on the ``robot`` sensing preset with MPU-6050 IMUs (their errors
drawn once and kept, as a real IMU keeps its misalignment), its frames go into a real store, and a
worker with the production settings learns the topology baseline, then the geometry on it (joint
axes and lever arms, every ``kinematics_interval_cycles`` = 6 cycles of 5 s: each estimate on a 30 s
window of its own). Then one drift damage is injected (the simulators' catalog: a 2° turn, a 2° bend,
a 1° dead band) and cycles run until the first alert. Asserted: the nominal run raises no alert and
no finding at all, ever; each damage's first alert is of its kind, on its part.

A turned IMU is seen through the axis it reports, so the turn is about a direction perpendicular to
the joint's axis in the IMU's frame (a turn about the axis itself leaves the axis where it was and
moves only the lever arm's direction, by 3.5 mm at 10 cm for 2°: below what a lever arm repeats to).

The API then serves, from the same stores, the geometry kept under the baseline, the newest estimate,
their drift (the turned IMU's store names it; the nominal one names nothing) and a URDF of each that
loads in yourdfpy and MuJoCo with the robot's joints.

Time to the alert: the window must first pass the change (6 cycles), then M = 2 geometry estimates in
a row must show it (6 cycles apart), and the estimates are staggered per robot (up to 5 more):
``POST_CYCLES`` = 24.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import yourdfpy
from fastapi.testclient import TestClient

from bodyschema.lever_pool import POOL_KEY
from service.api import create_app
from service.settings import Settings
from service.store import Store, open_store
from service.worker import FRAME_KEY, Worker
from simulators.farm import Farm
from simulators.kinematics_truth import kinematics_truth
from simulators.robot import Robot
from tests.service.test_damage_worker import ROBOT, RobotRuns, _cycle, _feed, run_robot

pytestmark = pytest.mark.slow

POST_CYCLES = 24
#: Healthy cycles on the topology baseline before the damage: one geometry estimate (kept as the
#: geometry baseline) and one compared with it, whatever the stagger.
HEALTHY_CYCLES = 13


def _turn_about(axis: np.ndarray) -> list[float]:
    """A unit direction perpendicular to ``axis``."""
    e = np.eye(3)[int(np.argmin(np.abs(axis)))]
    v = np.cross(axis, e)
    return (v / np.linalg.norm(v)).tolist()


@pytest.fixture(scope="module")
def drift_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("drift")


@pytest.fixture(scope="module")
def runs(drift_dir: Path) -> RobotRuns:
    u = kinematics_truth(Robot.from_catalog("ur5e"))["imu7"].axis
    assert u is not None
    kwargs = {
        "imu_rotated": {"imu": "imu7", "angle_deg": 2.0, "about": _turn_about(u)},
        "axis_changed": {"joint": "wrist_1", "angle_deg": 2.0},
        "backlash": {"joint": "wrist_1", "deg": 1.0},
    }
    return run_robot(
        "ur5e",
        7,
        drift_dir,
        kinds=tuple(kwargs),
        damage_kwargs=kwargs,
        post_cycles=POST_CYCLES,
        nominal_cycles=POST_CYCLES,
        healthy_cycles=HEALTHY_CYCLES,
    )


def test_nominal_run_raises_nothing(runs: RobotRuns) -> None:
    assert runs.nominal_alerts == []
    assert all(f == [] for f in runs.nominal_findings[runs.baseline_cycle :]), runs.nominal_findings


@pytest.mark.parametrize(
    ("kind", "part"),
    [("imu_rotated", "imu:imu7"), ("axis_changed", "joint:wrist_1"), ("backlash", "joint:wrist_1")],
)
def test_drift_alerts_first_with_its_kind(runs: RobotRuns, kind: str, part: str) -> None:
    run = runs.damages[kind]
    print(kind, run.first, run.first_finding, run.findings)
    assert run.first is not None, run.findings
    assert run.first[:2] == (kind, part), run.findings
    assert run.first[2] <= POST_CYCLES
    assert run.first_finding is not None and "limit" in run.first_finding["detail"]


@pytest.mark.parametrize("damage", [None, "imu_rotated"])
def test_api_serves_geometry_drift_and_urdf(runs: RobotRuns, drift_dir: Path, damage: str | None) -> None:
    db = drift_dir / ("ur5e-robot.db" if damage is None else f"ur5e-robot-{damage}.db")
    # what the worker found in its last cycle on this store: none in the nominal run
    seen = [] if damage is None else runs.damages[damage].findings[-1]
    url = f"sqlite:///{db}"
    with open_store(url) as store, TestClient(create_app(store, settings=Settings(database_url=url))) as c:
        body = c.get(f"/api/v1/robots/{ROBOT}/kinematics").json()
        info, base = store.robot(ROBOT), store.baseline(ROBOT)
        assert info is not None and base is not None
        first, newest = body["baseline"], body["latest"]
        assert first is not None and newest is not None and newest["id"] > first["id"]
        assert first["baseline_id"] == newest["baseline_id"] == base.id
        assert newest["window_end_t"] > first["window_end_t"]
        assert set(newest["kinematics"]["imus"]) == set(info.imus)
        drift = [
            (f["kind"], f"imu:{f['imu']}" if f.get("imu") else f"joint:{f['joint']}") for f in body["drift"]
        ]
        assert drift == seen, (drift, seen)
        if damage is not None:
            assert ("imu_rotated", "imu:imu7") in drift
        for which in ("baseline", "latest"):
            r = c.get(f"/api/v1/robots/{ROBOT}/kinematics/urdf", params={"which": which})
            assert r.status_code == 200 and r.headers["content-type"].startswith("application/xml")
            path = drift_dir / f"{db.stem}-{which}.urdf"
            path.write_text(r.text)
            assert sorted(yourdfpy.URDF.load(str(path)).actuated_joint_names) == sorted(info.joints)
            assert mujoco.MjModel.from_xml_string(r.text).njnt == len(info.joints)


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
            _feed(farm, store, interval)
            _cycle(worker, history, alerts)

    worker = Seen(store, settings)
    _feed(farm, store, settings.window_seconds - interval)
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
