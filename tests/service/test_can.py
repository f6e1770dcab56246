"""CAN ingest on python-can's virtual bus: DBC layout, faults, regrouping policy, bus failures."""

from __future__ import annotations

import json
import time
from importlib import resources

import can
import numpy as np
import pytest

from service.ingest.can import CAN_ERR_BUSOFF, CanSource, open_from_spec
from service.ingest.can_layout import (
    FD_IMU_BASE,
    IMU_ACC_BASE,
    JOINT_BASE,
    encode_samples,
    encode_samples_fd,
    frame_ids,
    load_project_database,
    project_database,
)
from service.ingest.can_mapping import SignalMap
from service.ingest.can_regroup import SampleAssembler
from service.ingest.device import DeviceConfig, DeviceConfigError
from service.ingest.serial_frame import ACC_LSB, GYRO_LSB, Q_LSB

N_J, N_I = 5, 4
CFG = DeviceConfig("r1", 0.01, [f"j{i}" for i in range(N_J)], [f"imu{i}" for i in range(N_I)])


def _data(rng, T):
    q = rng.uniform(-3, 3, (T, N_J))
    acc = rng.normal(0, 10, (T, N_I, 3))
    gyro = rng.normal(0, 2, (T, N_I, 3))
    return q, acc, gyro


def _collect(src, until, timeout=10.0):
    out = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        out += src.read(0.2)
        if until(out):
            break
    return out


def test_shipped_dbc_is_the_generated_one():
    shipped = resources.files("service.ingest").joinpath("bodyhealth.dbc").read_text(encoding="utf-8")
    assert shipped == project_database().as_dbc_string().replace("\r\n", "\n")
    db = load_project_database()
    assert len(db.messages) == 2 + 32 + 2 * 128 + 4 + 128  # stamp frames, classic, FD
    assert db.get_message_by_name("IMU_FD_3").is_fd and db.get_message_by_name("JOINTS_FD_0").length == 64
    m = db.get_message_by_frame_id(JOINT_BASE + 3)
    assert m.name == "JOINTS_3" and m.get_signal_by_name("q1").scale == Q_LSB


def test_encoder_agrees_with_cantools(rng):
    q, acc, gyro = _data(rng, 20)
    counter = np.arange(65530, 65550)  # wraps
    ids, data = encode_samples(counter, q, acc, gyro)
    assert ids.tolist() == frame_ids(N_J, N_I).tolist()
    db = load_project_database()
    for t in range(20):
        for f, fid in enumerate(ids.tolist()):
            v = db.decode_message(fid, data[t, f].tobytes())
            assert v["counter"] == counter[t] % 65536
            if fid < IMU_ACC_BASE:
                m = fid - JOINT_BASE
                for s in range(2):
                    j = 2 * m + s
                    if j < N_J:
                        assert abs(v[f"q{s}"] - q[t, j]) <= Q_LSB / 2 + 1e-12
            else:
                gy = fid >= 0x180
                k, arr, lsb = (fid - 0x180, gyro, GYRO_LSB) if gy else (fid - IMU_ACC_BASE, acc, ACC_LSB)
                for a, ax in enumerate("xyz"):
                    assert abs(v[ax] - arr[t, k, a]) <= lsb / 2 + 1e-12


def test_fd_layout_agrees_with_cantools_and_regroups(rng):
    T, n, k = 12, 17, 5
    q = rng.uniform(-3, 3, (T, n))
    acc = rng.normal(0, 10, (T, k, 3))
    gyro = rng.normal(0, 2, (T, k, 3))
    ids, lengths, data = encode_samples_fd(np.arange(T) + 65530, q, acc, gyro)
    assert ids.tolist() == frame_ids(n, k, "fd").tolist() and lengths.tolist() == [64, 64] + [16] * k
    db = load_project_database()
    for t in range(T):
        for f, fid in enumerate(ids.tolist()):
            v = db.decode_message(fid, data[t, f, : lengths[f]].tobytes())
            assert v["counter"] == (65530 + t) % 65536
            if fid >= FD_IMU_BASE:
                kk = fid - FD_IMU_BASE
                assert abs(v["acc_y"] - acc[t, kk, 1]) <= ACC_LSB / 2 + 1e-12
                assert abs(v["gyro_z"] - gyro[t, kk, 2]) <= GYRO_LSB / 2 + 1e-12
            else:
                j = 15 * (fid - 0x200) + 14
                if j < n:
                    assert abs(v["q14"] - q[t, j]) <= Q_LSB / 2 + 1e-12
    cfg = DeviceConfig(
        "fd", 0.01, [f"j{i}" for i in range(n)], [f"i{i}" for i in range(k)], {"can": {"layout": "fd"}}
    )
    asm = SampleAssembler(SignalMap.for_config(cfg))
    asm.add_many(
        [int(i) for t in range(T) for i in ids],
        [data[t, f, : lengths[f]].tobytes() for t in range(T) for f in range(len(ids))],
    )
    (batch,) = asm.take(flush=True)
    np.testing.assert_allclose(batch.t, (np.arange(T) + 65530) * 0.01)
    np.testing.assert_allclose(batch.q, q, atol=Q_LSB / 2 + 1e-12)
    np.testing.assert_allclose(batch.gyro, gyro, atol=GYRO_LSB / 2 + 1e-12)


def test_vectorised_decode_equals_cantools(tmp_path, rng):
    """Random payloads through both decoders: little/big endian, signed/unsigned, odd widths, DLC 6."""
    import cantools

    dbc = """VERSION ""
NS_ :
BS_:
BU_: DEV
BO_ 100 Mixed: 6 DEV
 SG_ a : 0|11@1- (0.5,-3) [0|0] "" Vector__XXX
 SG_ b : 11|13@1+ (1,0) [0|0] "" Vector__XXX
 SG_ c : 31|12@0- (0.25,1) [0|0] "" Vector__XXX
 SG_ counter : 47|8@0+ (1,0) [0|0] "" Vector__XXX
BO_ 101 Wide: 8 DEV
 SG_ w : 0|48@1- (1e-06,0) [0|0] "" Vector__XXX
 SG_ counter : 48|16@1+ (1,0) [0|0] "" Vector__XXX
"""
    db = cantools.database.load_string(dbc, "dbc")
    cfg = DeviceConfig(
        "mix",
        0.01,
        ["a", "b", "c", "w"],
        [],
        {
            "can": {
                "counter": {"signal": "counter", "bits": 8},
                "joints": {"a": "Mixed.a", "b": "Mixed.b", "c": "Mixed.c", "w": "Wide.w"},
            }
        },
    )
    asm = SampleAssembler(SignalMap(db, cfg, cfg.extra["can"]), horizon=1)
    T = 200
    mixed = [bytearray(rng.integers(0, 256, 6, dtype=np.uint8).tobytes()) for _ in range(T)]
    wide = [bytearray(rng.integers(0, 256, 8, dtype=np.uint8).tobytes()) for _ in range(T)]
    for t in range(T):  # the counter decides the sample: make it count up
        mixed[t][5] = t % 256
        wide[t][6] = t % 256  # the 16-bit counter of Wide, read with 8 bits, counts alike
        wide[t][7] = 0
    ids = [100, 101] * T
    datas = [d for pair in zip(mixed, wide, strict=True) for d in pair]
    asm.add_many(ids, datas)
    (batch,) = asm.take(flush=True)
    ref = np.array(
        [
            [db.decode_message(100, bytes(m))[s] for s in "abc"] + [db.decode_message(101, bytes(w))["w"]]
            for m, w in zip(mixed, wide, strict=True)
        ]
    )
    np.testing.assert_allclose(batch.q, ref, rtol=0, atol=1e-9)


def test_mapping_errors_name_the_problem(tmp_path):
    bad = DeviceConfig("r1", 0.01, ["j1"], [], {"can": {"joints": {"j1": "NOPE.q0"}}})
    with pytest.raises(DeviceConfigError, match="NOPE"):
        SignalMap.for_config(bad)
    bad = DeviceConfig("r1", 0.01, ["j1"], [], {"can": {"joints": {"j1": "JOINTS_0.qq"}}})
    with pytest.raises(DeviceConfigError, match="qq"):
        SignalMap.for_config(bad)
    bad = DeviceConfig("r1", 0.01, ["j1", "j2"], [], {"can": {"joints": {"j1": "JOINTS_0.q0"}}})
    with pytest.raises(DeviceConfigError, match="j2"):
        SignalMap.for_config(bad)


def test_user_dbc_with_units_and_8_bit_counter(tmp_path, rng):
    """An integrator's DBC: degrees and g, big-endian signals, an 8-bit counter, own names."""
    dbc = """VERSION ""
NS_ :
BS_:
BU_: DEV
BO_ 1280 EncHip: 8 DEV
 SG_ Angle : 7|32@0- (0.001,0) [-1000000|1000000] "deg" Vector__XXX
 SG_ SeqCnt : 63|8@0+ (1,0) [0|255] "" Vector__XXX
BO_ 1281 ImuAll: 8 DEV
 SG_ AccZ : 0|16@1- (0.001,0) [-32|32] "g" Vector__XXX
 SG_ RateX : 16|16@1- (0.1,0) [-3000|3000] "deg/s" Vector__XXX
 SG_ Zero : 32|16@1- (1,0) [-3|3] "" Vector__XXX
 SG_ SeqCnt : 56|8@1+ (1,0) [0|255] "" Vector__XXX
"""
    (tmp_path / "dev.dbc").write_text(dbc)
    cfg = {
        "robot": "rover",
        "period_s": 0.005,
        "joints": ["hip"],
        "imus": ["thigh"],
        "can": {
            "dbc": "dev.dbc",
            "counter": {"signal": "SeqCnt", "bits": 8},
            "joints": {"hip": "EncHip.Angle"},
            "imus": {
                "thigh": {
                    "acc": ["ImuAll.Zero", "ImuAll.Zero", "ImuAll.AccZ"],
                    "gyro": ["ImuAll.RateX", "ImuAll.Zero", "ImuAll.Zero"],
                }
            },
            "units": {"q": np.pi / 180, "acc": 9.80665, "gyro": np.pi / 180},
        },
    }
    (tmp_path / "rover.json").write_text(json.dumps(cfg))
    src = open_from_spec(f"virtual:user-dbc?config={tmp_path / 'rover.json'}")
    tx = can.Bus(interface="virtual", channel="user-dbc")
    import cantools

    db = cantools.database.load_file(str(tmp_path / "dev.dbc"))
    hip = rng.uniform(-170, 170, 300)
    for i in range(300):  # counter wraps at 256
        tx.send(
            can.Message(
                arbitration_id=1280,
                is_extended_id=False,
                data=db.encode_message(1280, {"Angle": hip[i], "SeqCnt": i % 256}),
            )
        )
        tx.send(
            can.Message(
                arbitration_id=1281,
                is_extended_id=False,
                data=db.encode_message(1281, {"AccZ": 1.0, "RateX": 90.0, "Zero": 0, "SeqCnt": i % 256}),
            )
        )
    batches = _collect(src, lambda out: sum(b.n_samples for b in out) >= 300)
    src.close()
    tx.shutdown()
    t = np.concatenate([b.t for b in batches])
    np.testing.assert_allclose(t, np.arange(300) * 0.005)
    q = np.concatenate([b.q for b in batches])[:, 0]
    np.testing.assert_allclose(q, np.deg2rad(np.round(hip, 3)), atol=1e-9)
    acc = np.concatenate([b.acc for b in batches])
    np.testing.assert_allclose(acc[:, 0], [[0, 0, 9.80665]] * 300)
    gyro = np.concatenate([b.gyro for b in batches])
    np.testing.assert_allclose(gyro[:, 0, 0], np.pi / 2)
    assert batches[0].robot == "rover"


@pytest.mark.parametrize("policy", ["partial", "drop"])
def test_faults_are_counted_and_never_stored(rng, policy):
    channel = f"faults-{policy}"
    T = 600
    q, acc, gyro = _data(rng, T)
    ids, data = encode_samples(np.arange(T) + 1000, q, acc, gyro)
    F = len(ids)
    src = CanSource(
        CFG, lambda: can.Bus(interface="virtual", channel=channel), idle_flush_s=0.2, incomplete=policy
    )
    tx = can.Bus(interface="virtual", channel=channel)
    lost = rng.random((T, F)) < 0.01  # 1 % of frames never arrive
    short = (rng.random((T, F)) < 0.003) & ~lost  # these arrive with a short DLC instead
    n_err = n_remote = n_unknown = 0
    for t in range(T):
        for f in range(F):
            r = rng.random()
            if r < 0.01:
                tx.send(can.Message(is_error_frame=True, arbitration_id=0x004, data=bytes(8)))
                n_err += 1
            elif r < 0.015:
                tx.send(
                    can.Message(arbitration_id=int(ids[f]), is_remote_frame=True, dlc=8, is_extended_id=False)
                )
                n_remote += 1
            elif r < 0.02:
                tx.send(can.Message(arbitration_id=0x555, data=data[t, f].tobytes(), is_extended_id=False))
                n_unknown += 1
            if lost[t, f]:
                continue
            payload = data[t, f].tobytes()[: int(rng.integers(1, 7))] if short[t, f] else data[t, f].tobytes()
            tx.send(can.Message(arbitration_id=int(ids[f]), data=payload, is_extended_id=False))
    missing = lost | short
    joint_cols = np.flatnonzero(ids < IMU_ACC_BASE)
    dropped = missing[:, joint_cols].any(axis=1) if policy == "partial" else missing.any(axis=1)
    imu_missing = np.stack(
        [
            missing[:, [np.flatnonzero(ids == IMU_ACC_BASE + k)[0], np.flatnonzero(ids == 0x180 + k)[0]]].any(
                axis=1
            )
            for k in range(N_I)
        ],
        axis=1,
    )
    incomplete = ~dropped & imu_missing.any(axis=1)
    want = int((~dropped).sum())
    batches = _collect(src, lambda out: sum(b.n_samples for b in out) >= want)
    time.sleep(0.3)
    batches += src.read(0.1)
    src.close()
    tx.shutdown()

    c = src.counters.as_dict()
    assert c["error_frames"] == n_err
    assert c["remote_frames"] == n_remote
    assert c["unknown_ids"] == n_unknown
    assert c["decode_errors"] == int(short.sum())
    assert c["frames_missing"] == int(missing.sum())
    assert c["samples_dropped"] == int(dropped.sum())
    assert c.get("samples_incomplete", 0) == int(incomplete.sum())
    assert (policy == "drop") == (c.get("samples_incomplete", 0) == 0)
    assert c.get("late_frames", 0) == 0 and c.get("bus_errors", 0) == 0
    assert c["frames"] == T * F - int(missing.sum())
    # what was stored is exactly the intact data, sample by sample, IMU by IMU
    seen = []
    for b in batches:
        for i, t in enumerate(b.t):
            s = round(float(t) / 0.01) - 1000
            seen.append(s)
            assert not dropped[s]
            np.testing.assert_allclose(b.q[i], q[s], atol=Q_LSB / 2 + 1e-9)
            names = [f"imu{k}" for k in range(N_I) if not imu_missing[s, k]]
            assert list(b.imu_names) == names
            keep = ~imu_missing[s]
            np.testing.assert_allclose(b.acc[i], acc[s][keep], atol=ACC_LSB / 2 + 1e-9)
            np.testing.assert_allclose(b.gyro[i], gyro[s][keep], atol=GYRO_LSB / 2 + 1e-9)
    assert seen == sorted(seen) and len(seen) == want
    assert c["received"] == want and c["malformed"] == 0


def test_late_and_duplicate_frames(rng):
    """Frames out of order within the horizon still regroup; beyond it they are late, repeats duplicates."""
    T = 40
    q, acc, gyro = _data(rng, T)
    ids, data = encode_samples(np.arange(T), q, acc, gyro)
    src = CanSource(CFG, lambda: can.Bus(interface="virtual", channel="late"), horizon=3, idle_flush_s=0.2)
    tx = can.Bus(interface="virtual", channel="late")

    def send(t, f):
        tx.send(can.Message(arbitration_id=int(ids[f]), data=data[t, f].tobytes(), is_extended_id=False))

    for t in range(T):
        for f in range(len(ids)):
            if (t, f) in ((10, 0), (20, 1)):
                continue
            send(t, f)
            if (t, f) == (11, 0):
                send(10, 0)  # 1 sample late: within the horizon
            if (t, f) == (30, 0):
                send(20, 1)  # 10 samples late: beyond it
            if t == 5 and f == 2:
                send(5, 2)  # a repeat
    batches = _collect(src, lambda out: sum(b.n_samples for b in out) >= T - 1)
    src.close()
    tx.shutdown()
    c = src.counters.as_dict()
    t = np.rint(np.concatenate([b.t for b in batches]) / 0.01).astype(int)
    assert 10 in t and 20 not in t  # sample 20 lost joint frame 1 for good
    assert c["late_frames"] == 1 and c["duplicate_frames"] == 1 and c["samples_dropped"] == 1


def test_bus_off_and_bus_error_reconnect(rng):
    T = 300
    q, acc, gyro = _data(rng, T)
    ids, data = encode_samples(np.arange(T), q, acc, gyro)
    buses: list[can.BusABC] = []

    def factory():
        buses.append(can.Bus(interface="virtual", channel="busoff"))
        return buses[-1]

    src = CanSource(CFG, factory, idle_flush_s=0.2, backoff=(0.01, 0.05))
    tx = can.Bus(interface="virtual", channel="busoff")

    def send(lo, hi):
        for t in range(lo, hi):
            for f in range(len(ids)):
                tx.send(
                    can.Message(arbitration_id=int(ids[f]), data=data[t, f].tobytes(), is_extended_id=False)
                )

    send(0, 100)
    got = _collect(src, lambda out: sum(b.n_samples for b in out) >= 100)
    tx.send(can.Message(is_error_frame=True, arbitration_id=CAN_ERR_BUSOFF, data=bytes(8)))
    got += _collect(src, lambda out: src.counters.extra.get("reconnects", 0) >= 1 and src.connected)
    assert src.counters.extra["bus_off"] == 1 and len(buses) == 2
    send(100, 200)
    got += _collect(src, lambda out: sum(b.n_samples for b in got + out) >= 200)
    buses[-1].shutdown()  # the adapter goes away under the receive thread
    got += _collect(src, lambda out: src.counters.extra.get("reconnects", 0) >= 2 and src.connected)
    send(200, 300)
    got += _collect(src, lambda out: sum(b.n_samples for b in got + out) >= 300)
    src.close()
    tx.shutdown()
    c = src.counters.as_dict()
    assert c["reconnects"] == 2 and c["bus_errors"] >= 2 and len(buses) == 3
    t = np.rint(np.concatenate([b.t for b in got]) / 0.01).astype(int)
    assert t.tolist() == list(range(300))
    np.testing.assert_allclose(np.concatenate([b.q for b in got]), q, atol=Q_LSB)


def test_buffered_slcan_parses_every_line_kind_and_survives_garbage():
    from service.ingest.can import BufferedSlcanBus

    bus = BufferedSlcanBus("loop://", sleep_after_open=0)
    try:
        while bus.recv(0.05) is not None:  # the loop echoes the open commands back; drain them
            pass
        fd_data = bytes(range(16))
        bus.serialPortOrig.write(
            b"t1232AABB\r"
            + b"T1ABCDEF03112233\r"
            + b"r1230\r"
            + b"\a"
            + b"t12\r"
            + b"tZZZ8\r"
            + b"d123A"
            + fd_data.hex().upper().encode()
            + b"\r"
            + b"t7FF0\r"
        )
        got: list[can.Message] = []
        for _ in range(20):
            m = bus.recv(0.1)
            if m is not None:
                got.append(m)
            elif len(got) >= 5:
                break
        seen = [(m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_fd, bytes(m.data)) for m in got]
        assert seen == [
            (0x123, False, False, False, b"\xaa\xbb"),
            (0x1ABCDEF0, True, False, False, b"\x11\x22\x33"),
            (0x123, False, True, False, b""),
            (0x123, False, False, True, fd_data),
            (0x7FF, False, False, False, b""),
        ]
        assert bus.garbled_lines == 2
    finally:
        bus.shutdown()
