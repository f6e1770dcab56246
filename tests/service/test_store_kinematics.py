"""Geometry baselines in the store (SQLite and PostgreSQL): kept per topology baseline, read back
exactly as the kinematics JSON they were, the first one kept standing for its baseline."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.kinematics import ImuKinematics, JointKinematics, Kinematics
from bodyschema.topology import Topology
from service.frames import FrameBatch
from service.store import Store, UnknownRobot

TOPO = Topology({"j1": None}, {"imu0": "j1"})


def _kin(axis: list[float]) -> Kinematics:
    imu = ImuKinematics(
        "imu0",
        "j1",
        axis=np.array(axis),
        lever_arm=np.array([0.1, 0.0, 0.0]),
        axis_std_deg=0.05,
        lever_arm_std_m=0.002,
        gain=1.01,
        converged=True,
        gyro_axis=np.array(axis),
        gyro_axis_std_deg=0.01,
    )
    return Kinematics(
        {"imu0": imu}, {"j1": JointKinematics("j1", None, ("imu0",), "imu0")}, (), 10.0, 1.5, 600, TOPO
    )


def _robot(store: Store) -> None:
    store.write(
        FrameBatch(
            "r1",
            np.arange(3.0),
            ("j1",),
            np.zeros((3, 1)),
            ("imu0",),
            np.ones((3, 1, 3)),
            np.zeros((3, 1, 3)),
        )
    )


def test_kept_per_baseline_and_read_back_as_written(store: Store) -> None:
    _robot(store)
    first, later = _kin([0.0, 0.0, 1.0]), _kin([0.0, 1.0, 0.0])
    store.save_kinematics("r1", 3, first.to_json(), wall_time=10.0, window_end_t=30.0)
    store.save_kinematics("r1", 3, later.to_json(), wall_time=20.0, window_end_t=60.0)
    store.save_kinematics("r1", 4, later.to_json(), wall_time=30.0)
    kept = store.kinematics_baseline("r1", 3)
    assert kept is not None and (kept.baseline_id, kept.wall_time, kept.window_end_t) == (3, 10.0, 30.0)
    back = Kinematics.from_json(kept.data, TOPO)
    assert back.to_json() == first.to_json()
    assert back.imus["imu0"].axis.tolist() == [0.0, 0.0, 1.0] and back.imus["imu0"].converged
    other = store.kinematics_baseline("r1", 4)
    assert other is not None and other.window_end_t is None
    assert other.data["imus"]["imu0"]["axis"] == [0.0, 1.0, 0.0]
    assert store.kinematics_baseline("r1", 5) is None


def test_latest_replaces_the_one_before_it_never_the_baseline(store: Store) -> None:
    _robot(store)
    assert store.kinematics_latest("r1") is None
    base = store.save_kinematics("r1", 3, _kin([0.0, 0.0, 1.0]).to_json(), wall_time=10.0, latest=True)
    # the first row under a baseline is its geometry baseline, even when saved as the latest
    assert store.kinematics_baseline("r1", 3).id == base == store.kinematics_latest("r1", 3).id
    ids = [
        store.save_kinematics("r1", 3, _kin(axis).to_json(), wall_time=w, window_end_t=w, latest=True)
        for w, axis in ((20.0, [0.0, 1.0, 0.0]), (30.0, [1.0, 0.0, 0.0]))
    ]
    assert store.kinematics_baseline("r1", 3).id == base
    newest = store.kinematics_latest("r1", 3)
    assert newest is not None and newest.id == ids[1] and newest.wall_time == 30.0
    assert newest.data["imus"]["imu0"]["axis"] == [1.0, 0.0, 0.0]
    with store._session() as s:  # the 20 s estimate is gone: two rows per baseline, not one per cycle
        from sqlalchemy import func, select

        from service.db.models import KinematicsRow

        assert s.scalar(select(func.count()).select_from(KinematicsRow)) == 2
    store.save_kinematics("r1", 4, _kin([0.0, 0.0, 1.0]).to_json(), wall_time=40.0)
    assert store.kinematics_latest("r1").baseline_id == 4 and store.kinematics_latest("r1", 3).id == ids[1]


def test_update_replaces_a_kept_rows_json_only(store: Store) -> None:
    """The geometry baseline's pool grows in place: its id, baseline and times stay."""
    _robot(store)
    base = store.save_kinematics("r1", 3, _kin([0.0, 0.0, 1.0]).to_json(), wall_time=10.0, window_end_t=30.0)
    later = store.save_kinematics("r1", 3, _kin([0.0, 1.0, 0.0]).to_json(), wall_time=20.0, latest=True)
    grown = {**_kin([0.0, 0.0, 1.0]).to_json(), "lever_arm_pool": [{"imu0": [0.1, 0.0, 0.0]}] * 2}
    store.update_kinematics(base, grown)
    kept = store.kinematics_baseline("r1", 3)
    assert kept is not None and (kept.id, kept.wall_time, kept.window_end_t) == (base, 10.0, 30.0)
    assert kept.data == grown
    newest = store.kinematics_latest("r1", 3)
    assert newest is not None and newest.id == later and "lever_arm_pool" not in newest.data


def test_unknown_robot(store: Store) -> None:
    with pytest.raises(UnknownRobot):
        store.save_kinematics("nobody", 1, {}, wall_time=0.0)
    with pytest.raises(UnknownRobot):
        store.kinematics_baseline("nobody", 1)
    with pytest.raises(UnknownRobot):
        store.kinematics_latest("nobody")
