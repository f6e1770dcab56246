"""ROS bags: a simulated robot written with rosbags' own writers (ROS 2 MCAP and sqlite3, ROS 1) reads
back to the same recording, stamp for stamp, and the fast estimator finds the robot's exact tree in it;
bad bags are refused saying what they hold; a bag replays as a source; the import and export commands."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from bodyschema.estimate import estimate_topology
from bodyschema.recording import Recording
from cli.main import main
from emulators.rosbag import MessageFactory, RosbagWriteOptions, stamps_ns, write_rosbag
from service.ingest.replay import ReplaySource
from service.ingest.rosbag import RosbagError, RosbagOptions, bag_topics, import_rosbag, read_rosbag
from service.ingest.spec import SpecError, open_source
from simulators.recording_io import load_recording, save_recording
from simulators.simulation import simulate

FORMATS = ("mcap", "sqlite3", "ros1")
#: A fixed simulated robot: 20 s of the UR5e (6 joints, 12 IMUs) on the realistic ``robot`` preset.
SIM_SEED = 7


def bag_path(root: Path, fmt: str, name: str = "run") -> Path:
    return root / (f"{name}.bag" if fmt == "ros1" else f"{name}_{fmt}")


@pytest.fixture(scope="module")
def robot_rec() -> Recording:
    rec = simulate("ur5e", seconds=20.0, seed=SIM_SEED, sensing="robot")
    assert rec.is_multirate and rec.qd is None  # position-only encoders on their own clock
    return rec


@pytest.fixture(scope="module")
def robot_bags(robot_rec: Recording, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bags")
    out = {}
    for fmt in FORMATS:
        out[fmt] = bag_path(root, fmt)
        write_rosbag(robot_rec, out[fmt], RosbagWriteOptions(format=fmt))
    return out


def small_rec(n: int = 50, rate: float = 100.0, t0: float = 0.5) -> Recording:
    rng = np.random.default_rng(3)
    return Recording(
        t=t0 + np.arange(n) / rate,
        joint_names=("shoulder", "elbow"),
        q=rng.normal(size=(n, 2)),
        qd=rng.normal(size=(n, 2)),
        imu_names=("c1", "c2"),
        acc=rng.normal(size=(n, 2, 3)),
        gyro=rng.normal(size=(n, 2, 3)),
    )


# ------------------------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("fmt", FORMATS)
def test_simulated_robot_round_trips_and_gives_its_exact_tree(
    fmt: str, robot_rec: Recording, robot_bags: dict[str, Path]
) -> None:
    rec, summary = read_rosbag(robot_bags[fmt])
    assert summary.messages == robot_rec.n_samples * robot_rec.n_imus + robot_rec.t_q.shape[0]
    assert summary.dropped == {} and list(summary.joint_topics) == ["/joint_states"]
    assert len(summary.imu_topics) == 12
    assert rec.imu_names == robot_rec.imu_names and rec.joint_names == robot_rec.joint_names
    # bag stamps cannot be negative: when the simulator's encoder clock starts just before 0 the export
    # moves both streams on by 1 s; either way the stamps are the same to the nanosecond
    shift = 10**9 if min(robot_rec.t[0], robot_rec.t_q[0]) < 0 else 0
    origin = int(rec.extra["stamp_origin_ns"])
    assert origin == 0
    np.testing.assert_array_equal(stamps_ns(rec.t, origin), stamps_ns(robot_rec.t, shift))
    np.testing.assert_array_equal(stamps_ns(rec.t_q, origin), stamps_ns(robot_rec.t_q, shift))
    np.testing.assert_array_equal(rec.q, robot_rec.q)
    np.testing.assert_array_equal(rec.acc, robot_rec.acc)
    np.testing.assert_array_equal(rec.gyro, robot_rec.gyro)
    assert rec.is_multirate and rec.qd is None
    topo = estimate_topology(rec, method="fast")
    assert topo.unique
    assert topo.joint_parent == robot_rec.truth_parent_map
    assert topo.imu_joint == robot_rec.truth_imu_map


def test_single_clock_recording_with_velocity_round_trips_exactly(tmp_path: Path) -> None:
    src = small_rec()
    write_rosbag(src, tmp_path / "b", RosbagWriteOptions(format="mcap"))
    rec, summary = read_rosbag(tmp_path / "b")
    assert not rec.is_multirate  # one stamp series for both streams: a single-clock recording
    np.testing.assert_array_equal(stamps_ns(rec.t), stamps_ns(src.t))
    np.testing.assert_array_equal(rec.q, src.q)
    np.testing.assert_array_equal(rec.qd, src.qd)
    np.testing.assert_array_equal(rec.acc, src.acc)
    assert summary.messages == 50 * 3
    # written again from what was read, the bag has the same stamps and the same data
    write_rosbag(rec, tmp_path / "again", RosbagWriteOptions(format="sqlite3"))
    again, _ = read_rosbag(tmp_path / "again")
    np.testing.assert_array_equal(again.t, rec.t)
    np.testing.assert_array_equal(again.gyro, rec.gyro)


def test_wall_clock_stamps_count_from_a_whole_second_and_keep_nanoseconds(tmp_path: Path) -> None:
    src = small_rec(t0=0.123456789)
    origin = 1_700_000_000 * 10**9
    write_rosbag(src, tmp_path / "b.bag", RosbagWriteOptions(format="ros1", origin_ns=origin))
    rec, _ = read_rosbag(tmp_path / "b.bag")
    assert int(rec.extra["stamp_origin_ns"]) == origin
    assert rec.t[0] == 0.123456789
    np.testing.assert_array_equal(stamps_ns(rec.t, origin), stamps_ns(src.t, origin))
    # and the origin travels: exported again, the stamps are the same epoch stamps
    write_rosbag(rec, tmp_path / "c", RosbagWriteOptions(format="mcap"))
    again, _ = read_rosbag(tmp_path / "c")
    assert int(again.extra["stamp_origin_ns"]) == origin
    np.testing.assert_array_equal(again.t, rec.t)


def test_topics_are_picked_by_name(robot_bags: dict[str, Path], robot_rec: Recording) -> None:
    opts = RosbagOptions(imu_topics=("/imu/imu3", "/imu/imu0"), joint_topics=("/joint_states",))
    rec, summary = read_rosbag(robot_bags["mcap"], opts)
    assert rec.imu_names == ("imu0", "imu3")  # in the bag's topic order
    assert list(summary.imu_topics) == ["/imu/imu0", "/imu/imu3"]
    np.testing.assert_array_equal(rec.gyro, robot_rec.gyro[:, [0, 3]])


def test_imus_on_different_stamps_are_resampled_onto_the_longest(tmp_path: Path) -> None:
    """Two IMU drivers stamping on their own: the values of a linear signal land exactly on the
    common stamps (those of the IMU with more samples, within the span both cover)."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msgs = MessageFactory(ts, ts.serialize_cdr)
    ta = np.arange(0, 101) * 10_000_000  # 0..1 s at 100 Hz
    tb = 5_000_000 + np.arange(0, 50) * 20_000_000  # 5 ms late, 50 Hz
    with Writer2(tmp_path / "b", version=9) as w:
        ca = w.add_connection("/a/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cb = w.add_connection("/b/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for s in ta:
            w.write(ca, int(s), msgs.imu("/a/imu", int(s), "a_link", np.zeros(3), np.full(3, s / 1e9)))
            w.write(cj, int(s), msgs.joints("/joint_states", int(s), ["j1"], np.array([s / 1e9]), None))
        for s in tb:
            w.write(cb, int(s), msgs.imu("/b/imu", int(s), "", np.zeros(3), np.full(3, 2 * s / 1e9)))
    rec, _ = read_rosbag(tmp_path / "b")
    assert rec.imu_names == ("a_link", "b_imu")  # the frame id, else the topic
    assert rec.t[0] == pytest.approx(0.01) and rec.t[-1] == pytest.approx(0.98)  # within b's span
    np.testing.assert_allclose(rec.gyro[:, 0, 0], rec.t, atol=1e-12)
    np.testing.assert_allclose(rec.gyro[:, 1, 0], 2 * rec.t, atol=1e-12)
    # the encoders keep their own stamps (all 101): the IMU stamps were cut to the common span
    assert rec.is_multirate and rec.t_q.shape == (101,)
    np.testing.assert_allclose(rec.q[:, 0], rec.t_q, atol=1e-12)


def _hand_bag(path: Path, imu_stamps: list[int], joint_stamps: list[int], positions: bool = True) -> None:
    """A ROS 2 bag with one IMU and one joint-state topic at the given stamps (ns), written in that order."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msgs = MessageFactory(ts, ts.serialize_cdr)
    with Writer2(path, version=9) as w:
        ci = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for k, s in enumerate(imu_stamps):
            w.write(ci, k, msgs.imu("/imu", s, "imu_link", np.zeros(3), np.full(3, float(k))))
        for k, s in enumerate(joint_stamps):
            q = np.array([float(k)]) if positions or k % 2 else np.zeros(0)
            w.write(cj, k, msgs.joints("/joint_states", s, ["arm/j1"], q, None))


def test_duplicate_stamps_are_dropped_and_counted_and_position_less_states_too(tmp_path: Path) -> None:
    ms = 1_000_000
    _hand_bag(tmp_path / "b", [0, 10 * ms, 10 * ms, 20 * ms, 30 * ms], [k * 4 * ms for k in range(10)], False)
    rec, summary = read_rosbag(tmp_path / "b")
    assert summary.dropped == {"duplicate_stamps": 1, "joint_states_without_positions": 5}
    np.testing.assert_array_equal(rec.gyro[:, 0, 0], [0.0, 1.0, 3.0, 4.0])  # the first of a repeat is kept
    np.testing.assert_array_equal(rec.q[:, 0], [1.0, 3.0, 5.0, 7.0, 9.0])
    assert rec.joint_names == ("arm_j1",) and rec.imu_names == ("imu_link",)  # valid part names


def test_stamps_that_go_backwards_are_refused_naming_the_topic(tmp_path: Path) -> None:
    ms = 1_000_000
    _hand_bag(tmp_path / "b", [0, 10 * ms, 20 * ms], [0, 8 * ms, 4 * ms, 12 * ms])
    with pytest.raises(RosbagError, match=r"topic /joint_states: header.stamp goes backwards at index 2"):
        read_rosbag(tmp_path / "b")


# ------------------------------------------------------------------------------- import in bounded memory
def _same_file_as_read(bag: Path, out: Path, rows: int) -> Recording:
    """``import_rosbag`` with blocks of ``rows`` writes exactly what ``read_rosbag`` gives, saved, and
    leaves nothing beside the file."""
    rec, _ = read_rosbag(bag)
    save_recording(rec, out.parent / "expected.npz")
    before = set(out.parent.iterdir())
    layout, summary = import_rosbag(bag, out, RosbagOptions(chunk_rows=rows))
    assert set(out.parent.iterdir()) == before | {out}  # the spool files are gone
    with np.load(out) as got, np.load(out.parent / "expected.npz") as want:
        assert sorted(got.files) == sorted(want.files)
        for k in want.files:
            np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    assert (layout.n_samples, layout.imu_names, layout.joint_names) == (
        rec.n_samples,
        rec.imu_names,
        rec.joint_names,
    )
    assert (layout.qd is None) == (rec.qd is None) and summary.messages > 0
    return load_recording(out)


@pytest.mark.parametrize("fmt", FORMATS)
def test_import_writes_the_recording_block_by_block(
    fmt: str, robot_bags: dict[str, Path], robot_rec: Recording, tmp_path: Path
) -> None:
    back = _same_file_as_read(robot_bags[fmt], tmp_path / "rec.npz", rows=97)  # blocks cut mid-stream
    np.testing.assert_array_equal(back.acc, robot_rec.acc)
    np.testing.assert_array_equal(back.q, robot_rec.q)


def test_import_of_resampled_and_repeated_stamps_matches_the_read(tmp_path: Path) -> None:
    """Interpolated IMUs and dropped duplicates come out the same whatever the block size."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msgs = MessageFactory(ts, ts.serialize_cdr)
    ta = np.arange(0, 101) * 10_000_000
    tb = 5_000_000 + np.arange(0, 50) * 20_000_000
    rng = np.random.default_rng(5)
    with Writer2(tmp_path / "b", version=9) as w:
        ca = w.add_connection("/a/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cb = w.add_connection("/b/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for k, s in enumerate(ta):
            w.write(ca, k, msgs.imu("/a/imu", int(s), "a", rng.normal(size=3), rng.normal(size=3)))
            for _ in range(1 + (k % 7 == 3)):  # every 7th joint state sent twice
                w.write(cj, k, msgs.joints("/joint_states", int(s), ["j1", "j2"], rng.normal(size=2), None))
        for k, s in enumerate(tb):
            w.write(cb, k, msgs.imu("/b/imu", int(s), "b", rng.normal(size=3), rng.normal(size=3)))
    for rows in (1, 4, 33):
        out = tmp_path / f"r{rows}" / "rec.npz"
        out.parent.mkdir()
        back = _same_file_as_read(tmp_path / "b", out, rows)
        assert back.n_samples == 98 and back.t_q.shape == (101,)


def test_failed_import_leaves_no_file(robot_bags: dict[str, Path], tmp_path: Path) -> None:
    dst = storage = tmp_path / "bad.bag"
    shutil.copy(robot_bags["ros1"], dst)
    with storage.open("r+b") as f:
        f.seek(storage.stat().st_size // 3)
        f.write(b"\xff" * 20_000)
    out = tmp_path / "out" / "rec.npz"
    with pytest.raises(RosbagError, match="truncated or corrupt after"):
        import_rosbag(dst, out)
    assert list(out.parent.iterdir()) == []


# ------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("fmt", FORMATS)
def test_truncated_bag_is_refused_naming_what_it_holds(
    fmt: str, robot_bags: dict[str, Path], robot_rec: Recording, tmp_path: Path
) -> None:
    src = robot_bags[fmt]
    if fmt == "ros1":
        dst = tmp_path / "cut.bag"
        shutil.copy(src, dst)
        storage = dst
    else:
        dst = tmp_path / "cut"
        shutil.copytree(src, dst)
        (storage,) = [p for p in dst.iterdir() if p.suffix in (".mcap", ".db3")]
    with storage.open("r+b") as f:
        f.truncate(storage.stat().st_size // 2)
    with pytest.raises(RosbagError, match="truncated, corrupt or not a ROS bag") as err:
        read_rosbag(dst)
    if fmt != "ros1":  # a ROS 2 bag's metadata.yaml still says what the bag held
        assert f"/imu/imu0 (sensor_msgs/msg/Imu, {robot_rec.n_samples} messages)" in str(err.value)
        assert "/joint_states (sensor_msgs/msg/JointState" in str(err.value)


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_bag_damaged_in_the_middle_is_refused_after_what_was_read(
    fmt: str, robot_bags: dict[str, Path], tmp_path: Path
) -> None:
    """Its index is whole, so it opens; the messages stop decoding where the bytes are overwritten."""
    src = robot_bags[fmt]
    if fmt == "ros1":
        dst = storage = tmp_path / "bad.bag"
        shutil.copy(src, dst)
    else:
        dst = tmp_path / "bad"
        shutil.copytree(src, dst)
        (storage,) = [p for p in dst.iterdir() if p.suffix == ".mcap"]
    size = storage.stat().st_size
    with storage.open("r+b") as f:
        f.seek(size // 3)
        f.write(b"\xff" * 20_000)
    with pytest.raises(RosbagError, match=r"the bag is truncated or corrupt after \d+ message\(s\)") as err:
        read_rosbag(dst)
    assert "topics in the bag: /imu/imu0 (sensor_msgs/msg/Imu)" in str(err.value)


def test_missing_topic_is_refused_listing_the_topics(robot_bags: dict[str, Path]) -> None:
    with pytest.raises(RosbagError) as err:
        read_rosbag(robot_bags["ros1"], RosbagOptions(imu_topics=("/imu/data",)))
    text = str(err.value)
    assert text.startswith(
        "topic(s) /imu/data not in the bag; topics in the bag: /imu/imu0 (sensor_msgs/msg/Imu)"
    )
    assert "/joint_states (sensor_msgs/msg/JointState)" in text


def test_topic_of_another_type_is_refused(robot_bags: dict[str, Path]) -> None:
    with pytest.raises(RosbagError, match="/joint_states is sensor_msgs/msg/JointState") as err:
        read_rosbag(robot_bags["sqlite3"], RosbagOptions(imu_topics=("/joint_states",)))
    assert "need sensor_msgs/msg/Imu topics" in str(err.value)


def test_bag_of_unknown_message_types_is_refused_listing_them(tmp_path: Path) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(tmp_path / "b", version=9) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(c, 1, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    assert bag_topics(tmp_path / "b") == {"/chatter": "std_msgs/msg/String"}
    with pytest.raises(RosbagError) as err:
        read_rosbag(tmp_path / "b")
    assert str(err.value) == (
        "no sensor_msgs/msg/Imu topic for the IMUs; topics in the bag: /chatter (std_msgs/msg/String)"
    )


def test_no_such_bag(tmp_path: Path) -> None:
    with pytest.raises(RosbagError, match="no such bag"):
        read_rosbag(tmp_path / "nope.bag")


def test_writer_refuses_to_overwrite_and_a_ros1_name_without_bag(tmp_path: Path) -> None:
    (tmp_path / "b").mkdir()
    with pytest.raises(FileExistsError):
        write_rosbag(small_rec(), tmp_path / "b")
    with pytest.raises(ValueError, match=r"\.bag file"):
        write_rosbag(small_rec(), tmp_path / "c", RosbagWriteOptions(format="ros1"))
    with pytest.raises(ValueError, match="bag format must be one of"):
        RosbagWriteOptions(format="zip")  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------ replay as a source
def test_bag_replays_as_a_source(tmp_path: Path) -> None:
    src = small_rec()
    write_rosbag(src, tmp_path / "my run.bag", RosbagWriteOptions(format="ros1"))
    source = open_source(f"rosbag:{tmp_path / 'my run.bag'}@max?chunk=0.2")
    assert isinstance(source, ReplaySource)
    assert (source.robot, source.name, source.speed) == ("my_run", "rosbag:my_run", math.inf)
    batches = []
    while not source.exhausted:
        batches.extend(source.read(0.1))
    assert [b.n_samples for b in batches] == [20, 20, 10]
    np.testing.assert_array_equal(np.concatenate([b.gyro for b in batches]), src.gyro)
    named = open_source(f"rosbag:{tmp_path / 'my run.bag'}?robot=arm&imu_topics=/imu/c2")
    assert named.robot == "arm" and named.recording.imu_names == ("c2",)
    with pytest.raises(SpecError, match="unknown rosbag option"):
        open_source(f"rosbag:{tmp_path / 'my run.bag'}?speed=2")


# ------------------------------------------------------------------------------------------ commands
def test_export_and_import_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = small_rec()
    save_recording(src, tmp_path / "rec.npz")
    assert (
        main(["export", "rosbag", str(tmp_path / "rec.npz"), str(tmp_path / "out.bag"), "--format", "ros1"])
        == 0
    )
    assert "out.bag: 150 messages (ros1): 2 IMU topics under /imu/, 2 joints on /joint_states" in (
        capsys.readouterr().out
    )
    assert main(["import", "rosbag", str(tmp_path / "out.bag"), "-o", str(tmp_path / "back.npz")]) == 0
    out = capsys.readouterr().out
    assert "150 messages from 2 IMU and 1 joint-state topic(s): 2 IMUs at 100.0 Hz (50 samples)" in out
    assert "2 joints, encoders on the IMU stamps, velocity present; dropped: none" in out
    back = load_recording(tmp_path / "back.npz")
    np.testing.assert_array_equal(stamps_ns(back.t), stamps_ns(src.t))
    np.testing.assert_array_equal(back.q, src.q)
    code = main(["import", "rosbag", str(tmp_path / "out.bag"), "-o", "x.npz", "--joint-topic", "/js"])
    assert code == 1
    assert "topic(s) /js not in the bag; topics in the bag: /imu/c1" in capsys.readouterr().err
