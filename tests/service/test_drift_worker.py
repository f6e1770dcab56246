"""Geometry drift through the worker's real cycle: a turned IMU raises its alert.

A UR5e runs in the simulated farm on the ``robot`` sensing preset with MPU-6050 IMUs (their errors
drawn once and kept, as a real IMU keeps its misalignment), its frames go into a real store, and a
worker with the production settings learns the topology baseline, then the geometry on it (joint
axes and lever arms, every ``kinematics_interval_cycles`` = 6 cycles of 5 s: each estimate on a 30 s
window of its own). Then a drift damage is injected (the simulators' catalog: a 2° turn of an IMU)
and cycles run until the first alert. Asserted: the nominal run raises no alert and no finding at
all, ever; the damage's first alert is of its kind, on its part. The worker's alerts do not depend
on a finding's kind, so the wiring is checked with one damage; that a 2° bend and a 1° dead band
are found first on their part, on windows estimated as the worker estimates them, is
tests/bench/test_drift_bench.py's (the benchmark's catalog part), and the lever-arm pools are
tests/service/test_drift_worker_pools.py's.

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

from service.api import create_app
from service.settings import Settings
from service.store import open_store
from simulators.kinematics_truth import kinematics_truth
from simulators.robot import Robot
from tests.service.damage_runs import ROBOT, RobotRuns, run_robot

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
    kwargs = {"imu_rotated": {"imu": "imu7", "angle_deg": 2.0, "about": _turn_about(u)}}
    return run_robot(
        "ur5e",
        7,
        drift_dir,
        kinds=tuple(kwargs),
        damage_kwargs=kwargs,
        post_cycles=POST_CYCLES,
        nominal_cycles=POST_CYCLES,
        healthy_cycles=HEALTHY_CYCLES,
        geometry=True,
    )


def test_nominal_run_raises_nothing(runs: RobotRuns) -> None:
    assert runs.nominal_alerts == []
    assert all(f == [] for f in runs.nominal_findings[runs.baseline_cycle :]), runs.nominal_findings


def test_drift_alerts_first_with_its_kind(runs: RobotRuns) -> None:
    kind, part = "imu_rotated", "imu:imu7"
    assert list(runs.damages) == [kind]
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
