"""Approving a baseline: the topology it picks, the alerts it ends, and that both happen or neither."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlalchemy.orm import Session

import service.store.topologies
from bodyschema.topology import Topology
from service.frames import FrameBatch
from service.store import Store, UnknownRobot, open_store


def _topo(method: str, imu_joint: str = "j1") -> Topology:
    return Topology(
        joint_parent={"j1": None, "j2": "j1"},
        imu_joint={"imu0": imu_joint, "imu1": None},
        method=method,
        confidence={"imu:imu0": 0.9},
    )


def _robot(store: Store, name: str = "r1") -> None:
    n = 10
    store.write(
        FrameBatch(
            name,
            np.arange(n) / 100.0,
            ("j1", "j2"),
            np.zeros((n, 2)),
            ("imu0", "imu1"),
            np.ones((n, 2, 3)),
            np.zeros((n, 2, 3)),
        )
    )


def _alerts(store: Store, robot: str = "r1") -> None:
    """One active, one pending and one already resolved alert."""
    f = {"kind": "imu_moved", "imu": "imu0"}
    store.upsert_alert(robot, "imu_moved", "imu:imu0", f, "active", 10.0)
    store.upsert_alert(robot, "imu_dead", "imu:imu1", {"kind": "imu_dead", "imu": "imu1"}, "pending", 11.0)
    store.upsert_alert(robot, "joint_locked", "joint:j2", {"kind": "joint_locked"}, "active", 5.0)
    store.upsert_alert(robot, "joint_locked", "joint:j2", {"kind": "joint_locked"}, "resolved", 6.0)


def test_approval_picks_the_newest_fast_topology_and_resolves_open_alerts(store: Store) -> None:
    _robot(store)
    _robot(store, "other")
    store.save_topology("r1", _topo("fast", "j1"), wall_time=100.0, window_end_t=1.0)
    store.save_topology("r1", _topo("fast", "j2"), wall_time=200.0, window_end_t=2.0)
    store.save_topology("r1", _topo("network", "j1"), wall_time=300.0, window_end_t=3.0)
    _alerts(store)
    store.upsert_alert("other", "imu_moved", "imu:imu0", {"kind": "imu_moved"}, "active", 10.0)

    base = store.approve_baseline("r1", wall_time=400.0)

    assert base == store.baseline("r1")
    assert (base.robot, base.source, base.wall_time, base.window_end_t, base.method) == (
        "r1",
        "operator",
        400.0,
        None,
        "fast",
    )
    assert base.topology.same_structure(_topo("fast", "j2"))
    by_part = {a.part: a for a in store.alerts("r1")}
    assert {a.state for a in by_part.values()} == {"resolved"}
    for part in ("imu:imu0", "imu:imu1"):
        assert by_part[part].resolved_at == by_part[part].updated_at == 400.0
    assert by_part["joint:j2"].resolved_at == 6.0  # resolved before: left as it was
    assert [a.state for a in store.alerts("other")] == ["active"]  # another robot's alerts stay


def test_approval_falls_back_to_any_method_takes_a_given_topology_and_checks_its_arguments(
    store: Store,
) -> None:
    _robot(store)
    with pytest.raises(LookupError, match="no topology learned for 'r1'"):
        store.approve_baseline("r1")
    assert store.baseline("r1") is None
    with pytest.raises(UnknownRobot):
        store.approve_baseline("nope")
    store.save_topology("r1", _topo("network", "j2"), wall_time=100.0, window_end_t=1.0)
    assert store.approve_baseline("r1").method == "network"
    given = store.approve_baseline("r1", _topo("mlp", "j1"), source="auto", wall_time=7.0)
    assert (given.source, given.wall_time, given.method) == ("auto", 7.0, "mlp")
    assert store.baseline("r1") == given
    with pytest.raises(ValueError, match="baseline source"):
        store.approve_baseline("r1", source="someone")


def test_approval_is_one_transaction(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A failure after the baseline row is in and the alerts are resolved leaves neither behind."""
    url = f"sqlite:///{tmp_path / 'approve.db'}"
    real = service.store.topologies.resolve_open_alerts
    calls: list[int] = []

    def resolve_then_fail(s: Session, rid: int, wall_time: float) -> int:
        calls.append(real(s, rid, wall_time))
        raise RuntimeError("connection lost")

    with open_store(url) as store:
        _robot(store)
        store.save_topology("r1", _topo("fast", "j2"), wall_time=100.0, window_end_t=1.0)
        store.set_baseline("r1", _topo("fast", "j1"), "auto", wall_time=50.0)
        _alerts(store)
        before = {a.id: a for a in store.alerts("r1")}
        old_base = store.baseline("r1")

        monkeypatch.setattr(service.store.topologies, "resolve_open_alerts", resolve_then_fail)
        with pytest.raises(RuntimeError, match="connection lost"):
            store.approve_baseline("r1", wall_time=400.0)
        assert calls == [2]  # both steps ran inside the transaction before it failed
        monkeypatch.undo()

    with Store(url) as fresh:  # another connection: nothing of the failed approval was committed
        assert fresh.baseline("r1") == old_base
        assert {a.id: a for a in fresh.alerts("r1")} == before
        assert fresh.approve_baseline("r1", wall_time=500.0).topology.same_structure(_topo("fast", "j2"))
        assert [a.state for a in fresh.alerts("r1")] == ["resolved"] * 3
