"""Multi-rate devices on CAN: each stream regroups by its own counter and is timed by its stamp frame
(``ENCODER_STAMP``/``IMU_STAMP``, bodyhealth.dbc); slcan ptys carry them like any other frame.

Tolerances come from the wire format: stamps are integer microseconds (error at most half a tick),
values are rounded to their LSB (error at most half an LSB), plus float rounding.
"""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from emulators.devices import STAMP_TICK_S, SlcanEmulator, stream_counters
from service.frames import FrameBatch
from service.ingest.can import CanSource, open_bus
from service.ingest.can_layout import encode_samples, encode_stream, load_project_database
from service.ingest.can_mapping import SignalMap
from service.ingest.can_regroup import MultirateAssembler
from service.ingest.device import DeviceConfig, DeviceConfigError, StreamSpec
from service.ingest.serial_frame import ACC_LSB, GYRO_LSB, Q_LSB
from simulators import simulate
from tests.service.multirate_wire import assert_whole_streams_but_the_unpaired_end, read_until_drained

EPS = 1e-9


def _cfg(n: int = 2, k: int = 1, **can: object) -> DeviceConfig:
    extra = {"can": dict(can)} if can else {}
    base = DeviceConfig(
        "r1", 0.01, tuple(f"j{i}" for i in range(n)), tuple(f"imu{i}" for i in range(k)), extra
    )
    return base.with_streams(StreamSpec(0.004), StreamSpec(0.01))


def _frames(ids: np.ndarray, lengths: np.ndarray, data: np.ndarray) -> list[list[tuple[int, bytes]]]:
    """Per sample, its frames as (id, payload)."""
    return [
        [(int(i), data[s, f, : int(n)].tobytes()) for f, (i, n) in enumerate(zip(ids, lengths, strict=True))]
        for s in range(data.shape[0])
    ]


def test_stamp_frames_decode_with_cantools_as_documented():
    """The worked example of docs/wire-formats.md, decoded by cantools from the shipped DBC."""
    db = load_project_database()
    ids, lengths, data = encode_stream(
        "encoders", np.array([3]), np.array([12000]), q=np.array([[0.25, -1.0]])
    )
    assert [hex(i) for i in ids] == ["0x78", "0x80"] and lengths.tolist() == [8, 8]
    assert data[0, 0].tobytes().hex(" ").upper() == "E0 2E 00 00 00 00 03 00"
    assert db.decode_message(0x078, data[0, 0].tobytes()) == {"stamp": 12000, "counter": 3}
    assert db.decode_message(0x080, data[0, 1].tobytes()) == {"q0": 0.25, "q1": -1.0, "counter": 3}
    acc, gyro = np.array([[[0, 0, 9.81]]]), np.array([[[0.1, -0.2, 0]]])
    ids, lengths, data = encode_stream(
        "imus", np.array([1]), np.array([18000]), acc=acc, gyro=gyro, layout="fd"
    )
    assert [hex(i) for i in ids] == ["0x79", "0x300"] and lengths.tolist() == [8, 16]
    assert data[0, 1, :16].tobytes().hex().upper() == "00000000AA07640038FF000001000000"
    assert db.decode_message(0x079, data[0, 0, :8].tobytes()) == {"stamp": 18000, "counter": 1}
    assert db.get_message_by_name("IMU_STAMP").frame_id == 0x079


def test_stream_maps_are_checked():
    enc, imu = SignalMap.for_streams(_cfg(3, 2, layout="fd"))
    assert sorted(enc.by_id) == [0x078, 0x200] and sorted(imu.by_id) == [0x079, 0x300, 0x301]
    with pytest.raises(DeviceConfigError, match="not a multi-rate"):
        SignalMap.for_streams(DeviceConfig("r", 0.01, ("j",), ("i",)))
    both = {
        "joints": {"j0": "IMU_FD_0.acc_x"},
        "imus": {
            "imu0": {
                "acc": [f"IMU_FD_0.acc_{a}" for a in "xyz"],
                "gyro": [f"IMU_FD_0.gyro_{a}" for a in "xyz"],
            }
        },
        "stamps": {"encoders": "ENCODER_STAMP.stamp", "imus": "IMU_STAMP.stamp"},
    }
    with pytest.raises(DeviceConfigError, match="carry both encoder and IMU"):
        SignalMap.for_streams(_cfg(1, 1, **both))
    no_stamps = {k: v for k, v in both.items() if k != "stamps"}
    with pytest.raises(DeviceConfigError, match="needs 'stamps'"):
        SignalMap.for_streams(_cfg(1, 1, **no_stamps))


def test_bad_frames_lost_samples_and_clock_faults_are_counted():
    """Short payloads, unknown ids, a sample without its stamp, a lost sample, a repeated stamp, a
    stamp that leaps ahead and one far behind: each counted, every good sample kept and timed."""
    asm = MultirateAssembler(*SignalMap.for_streams(_cfg(2, 1)), incomplete="partial")
    counters = np.array([0, 1, 2, 4, 5, 6, 7, 8, 9])  # sample 3 never sent
    stamps = np.array([1000, 5000, 9000, 17000, 17000, 3_021_000, 3_025_000, 100, 4100])
    q = np.column_stack([np.arange(9) * 0.01, -np.arange(9) * 0.01])
    enc = _frames(*encode_stream("encoders", counters, stamps, q=q))
    imu = _frames(
        *encode_stream(
            "imus",
            np.arange(3),
            np.array([2000, 12000, 22000]),
            acc=np.ones((3, 1, 3)),
            gyro=np.zeros((3, 1, 3)),
        )
    )
    enc[2] = enc[2][1:]  # sample 2 arrives without its stamp frame
    frames = [f for s in enc for f in s] + [f for s in imu for f in s]
    frames.insert(3, (0x080, b"\x00\x01"))  # short DLC
    frames.insert(5, (0x7F0, b"\x00" * 8))  # nobody's id
    asm.add_many([i for i, _ in frames], [d for _, d in frames])
    got = asm.take(flush=True)
    assert len(got) == 1 and got[0].is_multirate
    b = got[0]
    b.validate()
    # kept: 0, 1, 4, (5: stale), 6 (jump), 7, 8 (restart: carries on 1 µs after the newest), 9
    np.testing.assert_allclose(
        b.t_q, [0.001, 0.005, 0.017, 3.021, 3.025, 3.025001, 3.029001], rtol=0, atol=EPS
    )
    np.testing.assert_allclose(b.q[:, 0], [0.0, 0.01, 0.03, 0.05, 0.06, 0.07, 0.08], atol=Q_LSB / 2 + EPS)
    np.testing.assert_allclose(b.t, [0.002, 0.012, 0.022], rtol=0, atol=EPS)
    c = asm.counts
    assert c["decode_errors"] == 1 and c["unknown_ids"] == 1
    assert c["samples_dropped"] == 1 and c["frames_missing"] == 1  # sample 2: no stamp, cannot be timed
    assert c["samples_missing"] == 2  # sample 3 never came; sample 2 was dropped before timing
    assert (c["stale_stamps"], c["clock_jumps"], asm.resets) == (1, 1, 1)


@pytest.mark.slow
@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_multirate_recording_round_trip_over_slcan(fd):
    """simulate(sensing="robot") -> SlcanEmulator on a pty -> CanSource over slcan: both streams' stamps
    and values arrive to the wire's resolution; the sensing model's dropped samples are counted."""
    rec = simulate("ur5e", seconds=3.0, seed=5, sensing="robot")
    assert rec.is_multirate and rec.q is not None
    em = SlcanEmulator(rec, robot="ur5e", fd=fd)
    cfg = em.device_config()
    assert cfg.streams is not None and cfg.extra.get("can", {}).get("layout") == ("fd" if fd else None)
    src = CanSource(cfg, lambda: open_bus("slcan", em.port.name), idle_flush_s=0.3)
    em.start()

    def complete(got: list[FrameBatch]) -> bool:
        n_q = sum(len(b.t_q) for b in got)
        return em.wait_done(0) and n_q >= len(rec.t_q) and sum(len(b.t) for b in got) >= rec.n_samples

    got = read_until_drained(src.read, lambda: em.wait_done(0), complete)
    src.close()
    em.stop()
    assert got and all(b.is_multirate for b in got)
    t = np.concatenate([b.t for b in got]) - em.time_offset_s
    t_q = np.concatenate([b.t_q for b in got]) - em.time_offset_s
    assert_whole_streams_but_the_unpaired_end(t, t_q, rec)
    n, m = len(t), len(t_q)  # compare what arrived
    rec_t, rec_acc, rec_gyro, rec_tq, rec_q = rec.t[:n], rec.acc[:n], rec.gyro[:n], rec.t_q[:m], rec.q[:m]
    np.testing.assert_allclose(t, rec_t, rtol=0, atol=STAMP_TICK_S / 2 + EPS)
    np.testing.assert_allclose(t_q, rec_tq, rtol=0, atol=STAMP_TICK_S / 2 + EPS)
    np.testing.assert_allclose(np.concatenate([b.q for b in got]), rec_q, rtol=0, atol=Q_LSB / 2 + EPS)
    np.testing.assert_allclose(np.concatenate([b.acc for b in got]), rec_acc, rtol=0, atol=ACC_LSB / 2 + EPS)
    np.testing.assert_allclose(
        np.concatenate([b.gyro for b in got]), rec_gyro, rtol=0, atol=GYRO_LSB / 2 + EPS
    )
    lost = sum(
        int((np.diff(stream_counters(s, 1 / r)) - 1).sum())
        for s, r in ((rec.t_q, rec.encoder_rate), (rec.t, rec.sample_rate))
    )
    c = src.counters.as_dict()
    assert lost > 0 and c["samples_missing"] == lost
    for bad in (
        "decode_errors",
        "unknown_ids",
        "frames_missing",
        "samples_dropped",
        "stale_stamps",
        "clock_jumps",
    ):
        assert c.get(bad, 0) == 0, c


def test_single_stream_device_next_to_the_extension(rng):
    """A device config without ``streams`` keeps the single-clock layout and batches, and the stamp ids
    are nobody's frames for it."""
    cfg = DeviceConfig("r1", 0.01, ("j0",), ("imu0",))
    src = CanSource(cfg, lambda: open_bus("virtual", "mr-single"))
    tx = can.Bus(interface="virtual", channel="mr-single")
    q = rng.uniform(-1, 1, (5, 1))
    ids, data = encode_samples(np.arange(5), q, np.zeros((5, 1, 3)), np.zeros((5, 1, 3)))
    for s in range(5):
        tx.send(can.Message(arbitration_id=0x078, data=b"\x00" * 8, is_extended_id=False))
        for f, i in enumerate(ids):
            tx.send(can.Message(arbitration_id=int(i), data=data[s, f].tobytes(), is_extended_id=False))
    got: list[FrameBatch] = []
    t0 = time.monotonic()
    while sum(b.n_samples for b in got) < 5 and time.monotonic() - t0 < 5:
        got += src.read(0.2)
    src.close()
    tx.shutdown()
    assert not any(b.is_multirate for b in got)
    np.testing.assert_allclose(np.concatenate([b.t for b in got]), np.arange(5) * 0.01, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([b.q for b in got]), q, atol=Q_LSB / 2 + EPS)
    assert src.counters.extra["unknown_ids"] == 5
