"""Every robot's status read for the whole fleet at once is each robot's status as asked alone, on both
databases: the newest topology of the method (else of any), the baseline, the open alerts, the newest
network topology."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.topology import Topology
from service.api.schemas import StatusOut
from service.frames import FrameBatch
from service.status import robot_status, robot_statuses
from service.store import Store

TRUE = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"}, method="fast")
MOVED = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j1"}, method="fast")


def _frames(robot: str) -> FrameBatch:
    t, z = np.arange(5) / 100.0, np.zeros((5, 1, 3))
    return FrameBatch(robot, t, ("j1",), np.zeros((5, 1)), ("imu0",), z, z + 1.0)


def test_a_fleets_statuses_read_at_once_are_each_robots(store: Store) -> None:
    for robot in ("new", "healthy", "damaged", "net-only"):
        store.write(_frames(robot))
    store.save_topology("healthy", TRUE, 1.0, 1.0)
    store.set_baseline("healthy", TRUE, "auto")
    store.save_topology("healthy", TRUE, 2.0, 2.0)  # the newer of two
    store.save_topology("damaged", TRUE, 1.0, 1.0)
    store.set_baseline("damaged", TRUE, "operator")
    store.save_topology("damaged", MOVED, 3.0, 3.0)
    store.save_topology("damaged", Topology(TRUE.joint_parent, TRUE.imu_joint, method="network"), 4.0, 4.0)
    finding = {"kind": "imu_moved", "imu": "imu1"}
    store.upsert_alert("damaged", "imu_moved", "imu:imu1", finding, "active", 3.0)
    store.upsert_alert("damaged", "imu_moved", "imu:imu0", {**finding, "imu": "imu0"}, "pending", 3.5)
    store.save_topology("net-only", Topology(TRUE.joint_parent, TRUE.imu_joint, method="network"), 1.0, 1.0)
    store.upsert_alert("net-only", "imu_moved", "imu:imu1", finding, "pending", 1.0)
    names = [r.name for r in store.robots()]
    for method in (None, "fast", "network"):
        fleet = robot_statuses(store, names, method)
        alone = {r: robot_status(store, r, method) for r in names}
        assert {r: StatusOut.of(s).model_dump() for r, s in fleet.items()} == {
            r: StatusOut.of(s).model_dump() for r, s in alone.items()
        }, method
    # the cases differ, so the comparison says something
    got = {r: s.status for r, s in robot_statuses(store, names).items()}
    want = {"damaged": "damaged", "healthy": "healthy", "net-only": "undetermined", "new": "undetermined"}
    assert got == want
    assert robot_statuses(store, names)["damaged"].network is not None


@pytest.mark.parametrize("method", [None, "network"])
def test_latest_topologies_and_baselines_of_a_fleet(store: Store, method: str | None) -> None:
    for robot in ("a", "b"):
        store.write(_frames(robot))
    ids = [store.save_topology("a", TRUE, t, t) for t in (1.0, 2.0)]
    store.save_topology("a", Topology(TRUE.joint_parent, TRUE.imu_joint, method="network"), 1.5, 1.5)
    newest = store.latest_topologies(method)
    assert {r: rec.id for r, rec in newest.items()} == {
        "a": store.latest_topology("a", method).id  # type: ignore[union-attr]
    }
    assert method == "network" or newest["a"].id == ids[1]
    assert store.baselines() == {}
    store.set_baseline("a", TRUE, "auto")
    second = store.set_baseline("a", MOVED, "operator")
    assert {r: b.id for r, b in store.baselines().items()} == {"a": second}


def test_a_stored_topology_is_parsed_once_per_store(store: Store) -> None:
    from sqlalchemy import event

    for robot in ("a", "b"):
        store.write(_frames(robot))
        store.save_topology(robot, TRUE, 1.0, 1.0)
        store.set_baseline(robot, TRUE, "auto")
    reads: list[str] = []

    def seen(conn, cursor, statement, *args) -> None:  # type: ignore[no-untyped-def]
        reads.append(statement)

    event.listen(store.engine, "before_cursor_execute", seen)
    try:
        first, bases = store.latest_topologies("fast"), store.baselines()
        parses = len(reads)
        again, bases_again = store.latest_topologies("fast"), store.baselines()
        assert (parses, len(reads) - parses) == (4, 2)  # parsed rows: their topologies are not read again
        assert all(again[r] is first[r] for r in first) and all(bases_again[r] is bases[r] for r in bases)
        newer = store.save_topology("b", MOVED, 2.0, 2.0)
        now = store.latest_topologies("fast")
    finally:
        event.remove(store.engine, "before_cursor_execute", seen)
    assert now["a"] is first["a"]
    assert now["b"].id == newer and now["b"].topology.imu_joint == MOVED.imu_joint
    assert now["b"] == store.latest_topology("b", "fast")
    assert bases["a"].source == "auto" and bases["a"] == store.baseline("a")


def test_a_robot_is_judged_again_only_when_what_it_is_judged_from_changed(store: Store) -> None:
    for robot in ("a", "b"):
        store.write(_frames(robot))
        store.save_topology(robot, TRUE, 1.0, 1.0)
        store.set_baseline(robot, TRUE, "auto")
    judged: dict = {}
    first = robot_statuses(store, ["a", "b"], judged=judged)
    assert {r: s.status for r, s in first.items()} == {"a": "healthy", "b": "healthy"}
    assert all(robot_statuses(store, ["a", "b"], judged=judged)[r] is first[r] for r in first)
    store.save_topology("b", MOVED, 2.0, 2.0)
    second = robot_statuses(store, ["a", "b"], judged=judged)
    assert second["a"] is first["a"] and second["b"].status == "undetermined"
    store.upsert_alert("a", "imu_moved", "imu:imu1", {"kind": "imu_moved", "imu": "imu1"}, "active", 3.0)
    third = robot_statuses(store, ["a", "b"], judged=judged)
    assert third["a"].status == "damaged" and third["b"] is second["b"]
    alone = {r: StatusOut.of(robot_status(store, r)).model_dump() for r in ("a", "b")}
    assert {r: StatusOut.of(s).model_dump() for r, s in third.items()} == alone
