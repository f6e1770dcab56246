"""The windowed store on real SQLite and PostgreSQL: frames, windows, retention, silent IMUs, bad input."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from bodyschema.topology import Topology
from service.frames import FrameBatch, FrameError
from service.store import Store, UnknownAlert, UnknownRobot, build_chunks, open_store
from tests.service.builders import RATE, make_batch, stream


def concat(batches: list[FrameBatch]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([getattr(b, k) for b in batches]) for k in ("t", "q", "acc", "gyro")}


# ------------------------------------------------------------------------------------------ frames
def test_round_trip_is_bit_exact(store: Store, rng: np.random.Generator) -> None:
    batches = stream(rng, 3.0, batch=7)
    assert store.write_many(batches) == 300
    rec = store.read_between("r1", -math.inf, math.inf)
    ref = concat(batches)
    assert rec.n_samples == 300
    assert rec.joint_names == ("j1", "j2") and rec.imu_names == ("imu0", "imu1", "imu2")
    for k in ("t", "q", "acc", "gyro"):
        np.testing.assert_array_equal(getattr(rec, k), ref[k])
    assert store.sample_count("r1") == 300
    assert store.robot("r1").last_frame_t == pytest.approx(2.99)


@pytest.mark.parametrize("chunk", [1, 7, 10, 1000])
def test_windows_are_exact_at_chunk_boundaries(db_url: str, rng: np.random.Generator, chunk: int) -> None:
    batches = stream(rng, 2.0, batch=10)
    ref = concat(batches)
    with open_store(db_url, chunk_max_samples=chunk) as store:
        for i in range(0, len(batches), 3):  # several transactions, each with several batches
            store.write_many(batches[i : i + 3])
        assert store.sample_count("r1") == 200
        # Windows ending inside, at the start and at the end of chunks.
        for end_i, n in [(199, 50), (199, 200), (69, 7), (70, 10), (9, 1), (13, 14), (150, 1)]:
            rec = store.read_window("r1", seconds=n / RATE, end=float(ref["t"][end_i]))
            lo = max(end_i - n + 1, 0)
            np.testing.assert_array_equal(rec.t, ref["t"][lo : end_i + 1])
            np.testing.assert_array_equal(rec.acc, ref["acc"][lo : end_i + 1])
            np.testing.assert_array_equal(rec.q, ref["q"][lo : end_i + 1])
        # The default end is the last frame; a longer window than the data gives all of it.
        assert store.read_window("r1", 0.5).n_samples == 50
        assert store.read_window("r1", 100.0).n_samples == 200
        assert store.read_window("r1", 1.0, end=-5.0) is None


def test_chunking_coalesces_and_splits(rng: np.random.Generator) -> None:
    a = stream(rng, 1.0, batch=10)  # 10 batches of 10 samples
    chunks = build_chunks(a, max_samples=25)
    assert [c.n for c in chunks] == [20, 20, 20, 20, 20]
    long = make_batch(rng, n=95)
    assert [c.n for c in build_chunks([long], max_samples=40)] == [40, 40, 15]
    # A change of IMU set starts a new chunk; two robots never share one.
    mixed = [
        make_batch(rng, t0=0.0),
        make_batch(rng, robot="r2", t0=0.0),
        make_batch(rng, t0=0.1, imus=("imu0",)),
    ]
    assert [(c.robot, c.n, c.imu_names) for c in build_chunks(mixed, 100)] == [
        ("r1", 10, ("imu0", "imu1", "imu2")),
        ("r1", 10, ("imu0",)),
        ("r2", 10, ("imu0", "imu1", "imu2")),
    ]


def test_registration_and_several_robots(store: Store, rng: np.random.Generator) -> None:
    store.write_many([make_batch(rng, "b", 0.0), make_batch(rng, "a", 5.0, joints=("x",), imus=("i9", "i1"))])
    assert [r.name for r in store.robots()] == ["a", "b"]
    a = store.robot("a")
    assert a.joints == ["x"] and a.imus == ["i9", "i1"] and a.silent_imus == []
    assert a.last_frame_t == pytest.approx(5.09) and not a.simulated and a.catalog is None
    # A joint and an IMU that appear later register after the first ones, in first-seen order.
    store.write(make_batch(rng, "a", 5.1, joints=("x", "y"), imus=("i1", "i9", "i0")))
    a = store.robot("a")
    assert a.joints == ["x", "y"] and a.imus == ["i9", "i1", "i0"]
    assert store.robot("nobody") is None
    store.mark_simulated("a", "ur5e")
    store.set_excitation("a", {"x": 0.5, "y": 0.01})
    a = store.robot("a")
    assert a.simulated and a.catalog == "ur5e" and a.excitation == {"x": 0.5, "y": 0.01}
    store.mark_simulated("new-sim", "quadruped")  # registers a robot before its first frame
    assert store.robot("new-sim").last_frame_t is None and store.read_window("new-sim", 1.0) is None


def test_a_robot_is_looked_up_once_per_store(store: Store, rng: np.random.Generator) -> None:
    from sqlalchemy import event

    store.write(make_batch(rng, "a"))
    statements: list[str] = []

    def seen(_conn: object, _cursor: object, sql: str, *_args: object) -> None:
        statements.append(sql)

    event.listen(store.engine, "before_cursor_execute", seen)
    try:
        looked_up = []
        for _ in range(3):  # the reads a status makes: each used to look the robot up by name
            statements.clear()
            assert store.latest_topology("a") is None and store.alerts("a", active=True) == []
            looked_up.append(sum("FROM robots" in q and "robots.name" in q for q in statements))
        assert looked_up[1:] == [0, 0], statements
        with pytest.raises(UnknownRobot):  # an unknown name is asked every time, never remembered
            store.latest_topology("b")
        store.write(make_batch(rng, "b"))
        assert store.latest_topology("b") is None
    finally:
        event.remove(store.engine, "before_cursor_execute", seen)


def _fleet(rng: np.random.Generator, n: int, t0: float) -> list[FrameBatch]:
    """One batch per robot ``f00..``; every third robot has other parts, every fourth an IMU less."""
    return [
        make_batch(
            rng,
            f"f{i:02d}",
            t0,
            joints=("j1", "j2") if i % 3 else ("k",),
            imus=("imu0", "imu1", "imu2") if i % 4 else ("imu2", "imu0"),
        )
        for i in range(n)
    ]


def test_a_fleet_is_written_and_listed_in_statements_independent_of_its_size(db_url: str) -> None:
    """The ingest writer commits every robot's frames each second and the API lists every robot after
    each commit: both must cost a fixed number of statements, not a few per robot (at a hundred robots
    those statements were most of the served process's time)."""
    from sqlalchemy import event

    counts = {}
    for n in (3, 12):
        rng = np.random.default_rng(n)
        store = open_store(db_url)
        statements: list[str] = []

        def seen(_conn: object, _cursor: object, sql: str, *_args: object, into: list = statements) -> None:
            into.append(sql)

        try:
            store.write_many(_fleet(rng, n, 0.0))  # registers robots and parts
            event.listen(store.engine, "before_cursor_execute", seen)
            store.write_many(_fleet(rng, n, 1.0))
            written = len(statements)
            statements.clear()
            infos = store.robots()
            listed = len(statements)
            event.remove(store.engine, "before_cursor_execute", seen)
            counts[n] = (written, listed)
            assert [r.name for r in infos] == [f"f{i:02d}" for i in range(n)]
            for r in infos:  # the fleet's read gives what each robot's own read gives
                assert r == store.robot(r.name)
                assert r.last_frame_t == pytest.approx(1.09)
            assert infos[0].joints == ["k"] and infos[0].imus == ["imu2", "imu0"]
            assert infos[1].joints == ["j1", "j2"] and infos[1].imus == ["imu0", "imu1", "imu2"]
        finally:
            store.close()
    assert counts[12] == counts[3], counts


def test_one_write_moves_each_robots_clock_on_its_own(store: Store, rng: np.random.Generator) -> None:
    """Robots written in one transaction: one restarts (a new epoch), the others go on in theirs."""
    store.write_many([make_batch(rng, "a", 100.0), make_batch(rng, "b", 100.0)])
    store.write_many([make_batch(rng, "a", 0.0), make_batch(rng, "b", 101.0), make_batch(rng, "c", 7.0)])
    a, b, c = (store.robot(x) for x in "abc")
    assert (a.epoch, a.epoch_start_t, a.last_frame_t) == (1, 0.0, pytest.approx(0.09))
    assert (b.epoch, b.epoch_start_t, b.last_frame_t) == (0, None, pytest.approx(101.09))
    assert (c.epoch, c.last_frame_t) == (0, pytest.approx(7.09))
    assert store.read_window("a", 1.0).n_samples == 10 and store.read_window("b", 2.0).n_samples == 20


def test_robot_without_encoders(store: Store, rng: np.random.Generator) -> None:
    store.write(make_batch(rng, joints=()))
    rec = store.read_window("r1", 1.0)
    assert rec.q.shape == (10, 0) and rec.joint_names == ()


def test_silent_and_returning_imus(store: Store, rng: np.random.Generator) -> None:
    full = ("imu0", "imu1", "imu2")
    store.write_many(stream(rng, 2.0, imus=full))  # t in [0, 2)
    later = [make_batch(rng, t0=2.0 + i / RATE, imus=("imu0", "imu2")) for i in range(0, 200, 10)]  # [2, 4)
    store.write_many(later)
    info = store.robot("r1")
    assert info.imus == list(full) and info.silent_imus == ["imu1"]
    # A window after it fell silent leaves it out; one across the change leaves it out by default...
    assert store.read_window("r1", 1.0).imu_names == ("imu0", "imu2")
    across = store.read_window("r1", 3.0)
    assert across.imu_names == ("imu0", "imu2") and across.n_samples == 300
    # ...or keeps it with NaN where it was silent.
    nan = store.read_window("r1", 3.0, partial_imus="nan")
    assert nan.imu_names == full
    k = nan.imu_names.index("imu1")
    assert np.all(np.isfinite(nan.acc[nan.t < 2.0 - 1e-9, k])) and np.all(
        np.isnan(nan.acc[nan.t >= 2.0 - 1e-9, k])
    )
    np.testing.assert_array_equal(across.acc[-200:], concat(later)["acc"])
    # It comes back: no longer silent.
    store.write(make_batch(rng, t0=4.0, imus=full))
    assert store.robot("r1").silent_imus == []


def test_overlapping_batches_merge_in_time_order(store: Store, rng: np.random.Generator) -> None:
    a = make_batch(rng, t0=0.0, n=20)
    b = make_batch(rng, t0=0.1, n=20)  # overlaps a's last 10 samples, written later: wins there
    store.write(a)
    store.write(b)
    rec = store.read_between("r1", -math.inf, math.inf)
    assert rec.n_samples == 30 and np.all(np.diff(rec.t) > 0)
    np.testing.assert_array_equal(rec.acc[:10], a.acc[:10])
    np.testing.assert_array_equal(rec.acc[10:], b.acc)


def test_split_sources_merge_into_full_frames(store: Store, rng: np.random.Generator) -> None:
    """Encoders and IMUs arriving in separate batches with the same time stamps make whole frames."""
    enc = make_batch(rng, imus=())
    imu = make_batch(rng, joints=())
    store.write_many([enc, imu])
    rec = store.read_window("r1", 1.0)
    assert (
        rec.n_samples == 10
        and rec.joint_names == ("j1", "j2")
        and rec.imu_names == enc.imu_names + imu.imu_names
    )
    np.testing.assert_array_equal(rec.q, enc.q)
    np.testing.assert_array_equal(rec.gyro, imu.gyro)


def test_retention_prunes_by_device_time(db_url: str, rng: np.random.Generator) -> None:
    with open_store(db_url, retention_seconds=0.995, chunk_max_samples=10) as store:
        store.write_many(stream(rng, 3.0))
        store.write_many([make_batch(rng, "other", 100.0)])
        dropped = store.prune()
        # r1 ends at 2.99: chunks ending before 1.995 go (t in [0, 2)); "other" keeps its only chunk.
        assert dropped == 200
        assert store.sample_count("r1") == 100 and store.sample_count("other") == 10
        rec = store.read_between("r1", -math.inf, math.inf)
        assert rec.t[0] == pytest.approx(2.0)
        assert store.prune() == 0
        assert store.prune(now_t=200.0) == 110  # an explicit device clock past everything
        assert store.sample_count() == 0 and store.robot("r1").imus  # registrations stay


def test_retention_drops_in_batches_letting_other_writers_in(
    db_url: str, rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A prune of many chunks commits them a batch at a time, and the store's write lock is free
    between batches: a writer never waits for a whole epoch's drop."""
    from service.store import retention

    monkeypatch.setattr(retention, "PRUNE_BATCH", 7)
    with open_store(db_url, retention_seconds=0.995, chunk_max_samples=10) as store:
        store.write_many(stream(rng, 3.0))  # 30 chunks of r1
        before, takes = store.generation, []
        lock = store.write_lock
        enter = type(lock).__enter__

        def counted(self: object) -> object:
            takes.append(self._depth)  # type: ignore[attr-defined]
            return enter(self)  # type: ignore[arg-type]

        monkeypatch.setattr(type(lock), "__enter__", counted)
        assert store.prune(now_t=200.0) == 300
        assert store.sample_count() == 0
        # 30 chunks at 7 a batch: 5 transactions (the last finds 2), each taking the lock afresh
        assert store.generation - before == 5 and takes == [0] * 5


def test_malformed_batches_rejected_without_losing_data(store: Store, rng: np.random.Generator) -> None:
    good = make_batch(rng)
    store.write(good)
    bad_nan = make_batch(rng, t0=1.0)
    bad_nan.acc[3, 1, 2] = np.nan
    t = np.arange(3) / RATE
    bads = [
        bad_nan,
        FrameBatch("r1", t, ("j1",), np.zeros((3, 2)), ("imu0",), np.zeros((3, 1, 3)), np.zeros((3, 1, 3))),
        FrameBatch(
            "r1", t[::-1].copy(), (), np.zeros((3, 0)), ("i",), np.zeros((3, 1, 3)), np.zeros((3, 1, 3))
        ),
        FrameBatch("r1", t, (), np.zeros((3, 0)), ("i", "i"), np.zeros((3, 2, 3)), np.zeros((3, 2, 3))),
        FrameBatch("", t, (), np.zeros((3, 0)), ("i",), np.zeros((3, 1, 3)), np.zeros((3, 1, 3))),
        FrameBatch(
            "r1", t.astype(object), (), np.zeros((3, 0)), ("i",), np.zeros((3, 1, 3)), np.zeros((3, 1, 3))
        ),
        "not a batch",
    ]
    for bad in bads:
        with pytest.raises(FrameError, match="batch 1"):
            store.write_many([make_batch(rng, t0=2.0), bad])  # type: ignore[list-item]
    assert store.sample_count() == 10 and [r.name for r in store.robots()] == ["r1"]
    np.testing.assert_array_equal(store.read_window("r1", 1.0).acc, good.acc)
    assert store.write_many([]) == 0


def test_unknown_robot_and_bad_arguments(store: Store, rng: np.random.Generator) -> None:
    topo = Topology(joint_parent={"j1": None}, imu_joint={"imu0": "j1"})
    for call in (
        lambda: store.read_window("ghost", 1.0),
        lambda: store.save_topology("ghost", topo, 0.0, 0.0),
        lambda: store.baseline("ghost"),
        lambda: store.alerts("ghost"),
        lambda: store.set_excitation("ghost", {}),
        lambda: store.sample_count("ghost"),
    ):
        with pytest.raises(UnknownRobot):
            call()
    assert issubclass(UnknownRobot, KeyError)
    store.write(make_batch(rng))
    with pytest.raises(ValueError, match="seconds must be positive"):
        store.read_window("r1", 0.0)
    with pytest.raises(ValueError, match="partial_imus"):
        store.read_window("r1", 1.0, partial_imus="zero")
    with pytest.raises(ValueError, match="finite"):
        store.set_excitation("r1", {"j1": float("nan")})


def test_two_store_objects_share_one_database(db_url: str, rng: np.random.Generator) -> None:
    """Like two processes: both register the same robot and parts without clashing."""
    with open_store(db_url) as a, open_store(db_url) as b:
        a.write(make_batch(rng, t0=0.0))
        b.write(make_batch(rng, t0=0.1, imus=("imu0", "imu1", "imu2", "imu3")))
        a.write(make_batch(rng, t0=0.2, imus=("imu3",)))
        assert a.robot("r1").imus == ["imu0", "imu1", "imu2", "imu3"]
        assert b.sample_count("r1") == 30


# -------------------------------------------------------------------------------- topologies
def _topo(method: str, imu_joint: str = "j1") -> Topology:
    return Topology(
        joint_parent={"j1": None, "j2": "j1"},
        imu_joint={"imu0": imu_joint, "imu1": None},
        method=method,
        confidence={"imu:imu0": 0.9},
    )


def test_topologies_history_and_baseline(store: Store, rng: np.random.Generator) -> None:
    store.write(make_batch(rng))
    assert store.latest_topology("r1") is None and store.baseline("r1") is None
    ids = [
        store.save_topology("r1", _topo(m, j), wall_time=w, window_end_t=w / 10)
        for m, j, w in [("fast", "j1", 100.0), ("network", "j2", 200.0), ("fast", "j2", 300.0)]
    ]
    assert len(set(ids)) == 3
    latest = store.latest_topology("r1")
    assert latest.id == ids[2] and latest.robot == "r1" and latest.wall_time == 300.0
    assert latest.window_end_t == 30.0 and latest.method == "fast"
    assert latest.topology.same_structure(_topo("fast", "j2")) and latest.topology.confidence == {
        "imu:imu0": 0.9
    }
    assert store.latest_topology("r1", method="network").id == ids[1]
    assert store.latest_topology("r1", method="mlp") is None
    assert [r.id for r in store.topology_history("r1")] == ids[::-1]
    assert [r.id for r in store.topology_history("r1", limit=2)] == ids[:0:-1]

    store.set_baseline("r1", _topo("fast"), "auto", wall_time=50.0, window_end_t=5.0)
    b = store.baseline("r1")
    assert b.source == "auto" and b.wall_time == 50.0 and b.topology.imu_joint["imu0"] == "j1"
    store.set_baseline("r1", _topo("fast", "j2"), "operator")
    b2 = store.baseline("r1")
    assert b2.source == "operator" and b2.topology.imu_joint["imu0"] == "j2" and b2.id != b.id
    with pytest.raises(ValueError, match="baseline source"):
        store.set_baseline("r1", _topo("fast"), "someone")


# ------------------------------------------------------------------------------------ alerts
def test_alert_life_cycle(store: Store, rng: np.random.Generator) -> None:
    store.write_many([make_batch(rng, "r1"), make_batch(rng, "r2")])
    f = {"kind": "imu_moved", "imu": "imu0", "from": "j1", "to": "j2", "confidence": 0.9}
    a = store.upsert_alert("r1", "imu_moved", "imu:imu0", f, "pending", 10.0)
    assert (a.state, a.imu, a.joint, a.raised_at, a.acked, a.resolved_at) == (
        "pending",
        "imu0",
        None,
        10.0,
        False,
        None,
    )
    b = store.upsert_alert("r1", "imu_moved", "imu:imu0", {**f, "confidence": 0.95}, "active", 15.0)
    assert b.id == a.id and b.state == "active" and b.raised_at == 10.0 and b.updated_at == 15.0
    assert b.finding["confidence"] == 0.95
    other = store.upsert_alert("r2", "joint_locked", "joint:j2", {"kind": "joint_locked"}, "active", 16.0)
    assert other.joint == "j2" and other.imu is None and other.id != a.id

    assert {x.id for x in store.alerts()} == {a.id, other.id}
    assert [x.id for x in store.alerts("r1", active=True)] == [a.id]
    assert store.alerts("r2", active=False) == []
    assert store.ack_alert(a.id).acked is True
    assert store.ack_alert(999_999) is None

    closed = store.upsert_alert("r1", "imu_moved", "imu:imu0", f, "resolved", 20.0)
    assert closed.id == a.id and closed.state == "resolved" and closed.resolved_at == 20.0 and closed.acked
    assert store.alerts("r1", active=True) == [] and [x.id for x in store.alerts("r1", state="resolved")] == [
        a.id
    ]
    # Resolving again changes nothing; the same damage later is a new alert.
    assert store.upsert_alert("r1", "imu_moved", "imu:imu0", f, "resolved", 25.0).resolved_at == 20.0
    again = store.upsert_alert("r1", "imu_moved", "imu:imu0", f, "pending", 30.0)
    assert again.id != a.id and again.raised_at == 30.0 and not again.acked

    upd = store.update_alert(other.id, state="resolved", updated_at=40.0)
    assert upd.resolved_at == 40.0 and upd.robot == "r2"
    with pytest.raises(UnknownAlert):
        store.update_alert(999_999, acked=True)
    with pytest.raises(ValueError, match="unknown alert fields"):
        store.update_alert(other.id, colour="red")
    with pytest.raises(ValueError, match="alert part"):
        store.upsert_alert("r1", "imu_moved", "imu0", f, "active", 1.0)
    with pytest.raises(ValueError, match="alert state"):
        store.upsert_alert("r1", "imu_moved", "imu:imu0", f, "burning", 1.0)


def test_heartbeat_and_ping(store: Store) -> None:
    assert store.ping() and store.last_heartbeat("worker") is None
    store.heartbeat("worker", 123.5)
    store.heartbeat("worker", 124.5)
    store.heartbeat("ingest", 1.0)
    assert store.last_heartbeat("worker") == 124.5 and store.last_heartbeat("ingest") == 1.0


def test_ping_false_when_database_unreachable(tmp_path) -> None:
    store = open_store(f"sqlite:///{tmp_path / 'x.db'}")
    assert store.ping() is True  # the same path answers while it is a database
    store.close()
    (tmp_path / "x.db").unlink()
    (tmp_path / "x.db").mkdir()  # the path is now a folder: no database can open there
    broken = Store(f"sqlite:///{tmp_path / 'x.db'}")  # ping needs no schema
    assert broken.ping() is False


def test_random_batching_and_windows_match_a_plain_slice(rng: np.random.Generator) -> None:
    """Any batching, chunk size and window gives the same samples as slicing the whole stream."""
    for _case in range(15):
        n = int(rng.integers(1, 400))
        cuts = np.unique(np.concatenate([[0, n], rng.integers(0, n, size=int(rng.integers(0, 30)))]))
        whole = make_batch(rng, n=n)
        with open_store("sqlite://", chunk_max_samples=int(rng.integers(1, 60))) as store:
            parts = [
                FrameBatch(
                    "r1",
                    whole.t[a:b],
                    whole.joint_names,
                    whole.q[a:b],
                    whole.imu_names,
                    whole.acc[a:b],
                    whole.gyro[a:b],
                )
                for a, b in itertools.pairwise(cuts)
            ]
            k = 0
            while k < len(parts):  # transactions of random size
                step = int(rng.integers(1, 5))
                store.write_many(parts[k : k + step])
                k += step
            for _w in range(5):
                end_i = int(rng.integers(0, n))
                width = int(rng.integers(1, n + 1))
                rec = store.read_window("r1", width / RATE, end=float(whole.t[end_i]))
                lo = max(end_i - width + 1, 0)
                np.testing.assert_array_equal(rec.t, whole.t[lo : end_i + 1])
                np.testing.assert_array_equal(rec.gyro, whole.gyro[lo : end_i + 1])
                np.testing.assert_array_equal(rec.q, whole.q[lo : end_i + 1])
