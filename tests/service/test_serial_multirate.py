"""Multi-rate devices on the serial wire: stream frames (sync ``A5 5B``), one stream for the encoders and
one for the IMUs, each with its own sequence number and time stamps.

Tolerances come from the wire format: stamps are integer microseconds (error at most half a tick), and
values are rounded to their LSB (error at most half an LSB), plus float rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.recording import Recording
from emulators.devices import STAMP_TICK_S, SerialEmulator, stream_counters
from service.frames import FrameBatch
from service.ingest.device import DeviceConfig, DeviceConfigError, StreamSpec
from service.ingest.serial import SerialSource
from service.ingest.serial_frame import ACC_LSB, GYRO_LSB, Q_LSB, FrameEncoder, StreamFrameEncoder
from simulators import simulate
from tests.service.multirate_wire import assert_whole_streams_but_the_unpaired_end, read_until_drained

EPS = 1e-9


def _cfg(n: int = 2, k: int = 1, enc: float = 0.004, imu: float = 0.01) -> DeviceConfig:
    return DeviceConfig(
        "r1", imu, tuple(f"j{i}" for i in range(n)), tuple(f"imu{i}" for i in range(k))
    ).with_streams(StreamSpec(enc), StreamSpec(imu))


def _collect(src: SerialSource, data: bytes) -> list[FrameBatch]:
    out = src.decode(data)
    assert all(b.is_multirate for b in out)
    for b in out:
        b.validate()
    return out


def _cat(batches: list[FrameBatch], name: str) -> np.ndarray:
    return np.concatenate([getattr(b, name) for b in batches])


def test_worked_examples_of_the_wire_format_doc():
    """The bytes docs/wire-formats.md shows for an encoder frame and an IMU frame."""
    enc = StreamFrameEncoder(2, 1)
    a = enc.encode_encoders(12000, [0.25, -1.0])
    b = enc.encode_imus(18000, [[0, 0, 9.81]], [[0.1, 0, 0]])
    assert a.hex() == "a55b08000000e02e0000010290d00300c0bdf0ff184dea77"
    assert b.hex() == "a55b0c00000050460000020100000000aa07640000000000ca6f2072"
    src = SerialSource("loop://", _cfg(2, 1))
    (batch,) = _collect(src, a + b)
    assert batch.t_q.tolist() == [0.012] and batch.t.tolist() == [0.018]
    assert batch.q.tolist() == [[0.25, -1.0]]
    assert batch.acc.tolist() == [[[0.0, 0.0, 9.81]]] and batch.gyro.tolist() == [[[0.1, 0.0, 0.0]]]
    src.close()


def test_streams_section_is_checked():
    with pytest.raises(DeviceConfigError, match="exactly the keys"):
        DeviceConfig("r", 0.01, ("j",), ("i",), {"streams": {"encoders": {"period_s": 0.004}}})
    with pytest.raises(DeviceConfigError, match="tick_s must not exceed"):
        DeviceConfig(
            "r",
            0.01,
            ("j",),
            ("i",),
            {"streams": {"encoders": {"period_s": 0.004, "tick_s": 0.01}, "imus": {"period_s": 0.01}}},
        )
    with pytest.raises(DeviceConfigError, match="at least one joint and one IMU"):
        DeviceConfig(
            "r", 0.01, ("j",), (), {"streams": {"encoders": {"period_s": 0.004}, "imus": {"period_s": 0.01}}}
        )
    cfg = DeviceConfig.from_dict(_cfg().to_dict())  # survives the JSON round trip
    assert cfg.streams == {"encoders": StreamSpec(0.004, 1e-6), "imus": StreamSpec(0.01, 1e-6)}


@pytest.mark.slow
def test_multirate_recording_round_trip_over_a_pty():
    """simulate(sensing="robot") -> SerialEmulator on a pty -> SerialSource: both streams' stamps and
    values arrive to the wire's resolution, and the samples the sensing model dropped are counted as
    lost frames of their stream."""
    rec = simulate("ur5e", seconds=4.0, seed=3, sensing="robot")
    assert rec.is_multirate and rec.q is not None
    em = SerialEmulator(rec, robot="ur5e")
    cfg = em.device_config()
    assert cfg.streams is not None and cfg.streams["encoders"].period_s == pytest.approx(0.004, rel=2e-3)
    src = SerialSource(em.port.name, cfg)
    em.start()

    def complete(got: list[FrameBatch]) -> bool:
        return (
            bool(got)
            and got[-1].t[-1] >= rec.t[-1] + em.time_offset_s - 1e-3
            and sum(len(b.t_q) for b in got) >= len(rec.t_q)
        )

    got = read_until_drained(src.read, lambda: em.wait_done(0), complete)
    src.close()
    em.stop()
    assert got and all(b.is_multirate for b in got)
    t, t_q = _cat(got, "t") - em.time_offset_s, _cat(got, "t_q") - em.time_offset_s
    assert_whole_streams_but_the_unpaired_end(t, t_q, rec)
    n, m = len(t), len(t_q)  # compare what arrived
    rec_t, rec_acc, rec_gyro, rec_tq, rec_q = rec.t[:n], rec.acc[:n], rec.gyro[:n], rec.t_q[:m], rec.q[:m]
    np.testing.assert_allclose(t, rec_t, rtol=0, atol=STAMP_TICK_S / 2 + EPS)
    np.testing.assert_allclose(t_q, rec_tq, rtol=0, atol=STAMP_TICK_S / 2 + EPS)
    np.testing.assert_allclose(_cat(got, "q"), rec_q, rtol=0, atol=Q_LSB / 2 + EPS)
    np.testing.assert_allclose(_cat(got, "acc"), rec_acc, rtol=0, atol=ACC_LSB / 2 + EPS)
    np.testing.assert_allclose(_cat(got, "gyro"), rec_gyro, rtol=0, atol=GYRO_LSB / 2 + EPS)
    lost = sum(
        int((np.diff(stream_counters(s, 1 / r)) - 1).sum())
        for s, r in ((rec.t_q, rec.encoder_rate), (rec.t, rec.sample_rate))
    )
    c = src.counters.as_dict()
    assert lost > 0 and c["sequence_gaps"] == lost  # the 0.5 % drops of the robot preset
    for bad in ("crc_errors", "bad_headers", "stale_frames", "clock_jumps", "counter_resets", "malformed"):
        assert c.get(bad, 0) == 0, c


def test_single_stream_device_still_works_and_the_two_kinds_never_mix(rng):
    """An old device (sample-counter frames) keeps its single-clock batches; a host set up for one kind
    skips the other kind's frames as line noise."""
    T = 20
    rec = Recording(
        t=np.arange(T) * 0.01,
        joint_names=["j0", "j1"],
        q=rng.uniform(-3, 3, (T, 2)),
        imu_names=["imu0"],
        acc=rng.normal(0, 10, (T, 1, 3)),
        gyro=rng.normal(0, 2, (T, 1, 3)),
    )
    old = b"".join(FrameEncoder(2, 1).encode(i, rec.q[i], rec.acc[i], rec.gyro[i]) for i in range(T))
    plain = SerialSource("loop://", DeviceConfig("r1", 0.01, ("j0", "j1"), ("imu0",)))
    (b,) = plain.decode(old)
    assert not b.is_multirate and b.t.tolist() == pytest.approx(rec.t.tolist(), abs=1e-12)
    np.testing.assert_allclose(b.q, rec.q, atol=Q_LSB / 2 + EPS)

    senc = StreamFrameEncoder(2, 1)
    new = b"".join(
        senc.encode_encoders(4000 * i, rec.q[i]) + senc.encode_imus(10000 * i, rec.acc[i], rec.gyro[i])
        for i in range(T)
    )
    assert plain.decode(new) == [] and plain.counters.extra["bytes_discarded"] == len(new)
    streams = SerialSource("loop://", _cfg(2, 1))
    assert streams.decode(old) == [] and streams.counters.extra["bytes_discarded"] == len(old)
    got = _collect(streams, new)
    np.testing.assert_allclose(_cat(got, "t_q"), np.arange(T) * 0.004, atol=1e-12)
    np.testing.assert_allclose(_cat(got, "t"), np.arange(T) * 0.01, atol=1e-12)
    plain.close()
    streams.close()


def test_bad_stream_frames_are_refused_with_counters_and_lose_no_good_one():
    enc = StreamFrameEncoder(2, 1)
    good = [enc.encode_encoders(4000 * i, [0.001 * i, -0.5]) for i in range(6)]
    imu = [enc.encode_imus(10000 * i + 8000, [[0, 0, 9.81]], [[0.1 * i, 0, 0]]) for i in range(2)]
    flipped = bytearray(enc.encode_encoders(24000, [9.0, 9.0]))
    flipped[14] ^= 0x01  # one bit of q0: the CRC no longer matches
    wrong_count = StreamFrameEncoder(3, 1).encode_encoders(28000, [1, 2, 3])  # N = 3 on a 2-joint device
    wrong_tag = bytearray(imu[0])
    wrong_tag[10] = 3  # no stream 3
    line = (
        good[0]
        + imu[0]
        + bytes(flipped)
        + good[1]
        + wrong_count
        + b"\xa5\x5b\x00"
        + good[2]
        + bytes(wrong_tag)
    )
    line += good[3] + imu[1] + good[4] + good[5]
    src = SerialSource("loop://", _cfg(2, 1))
    got = _collect(src, line)
    c = src.counters.extra
    # bad headers: the wrong count, the cut-off sync word (read with the next frame's bytes), the wrong tag
    assert c["crc_errors"] == 1 and c["bad_headers"] == 3
    assert _cat(got, "t_q").tolist() == pytest.approx([0.0, 0.004, 0.008, 0.012, 0.016, 0.02], abs=1e-12)
    assert _cat(got, "t").tolist() == pytest.approx([0.008, 0.018], abs=1e-12)
    assert _cat(got, "q")[:, 0].tolist() == pytest.approx([0.0, 0.001, 0.002, 0.003, 0.004, 0.005], abs=1e-12)
    assert _cat(got, "gyro")[:, 0, 0].tolist() == pytest.approx([0.0, 0.1], abs=1e-12)
    # encoder samples without an IMU sample yet wait for one (nothing is lost)
    more = enc.encode_encoders(32000, [0.5, 0.5], seq=6) + enc.encode_encoders(36000, [0.6, 0.6], seq=7)
    assert src.decode(more) == []
    (late,) = _collect(src, enc.encode_imus(38000, [[0, 0, 9.81]], [[0.3, 0, 0]]))
    assert late.t_q.tolist() == pytest.approx([0.032, 0.036], abs=1e-12) and late.t.tolist() == [0.038]
    assert "sequence_gaps" not in c  # the refused frames were never part of the device's numbering
    src.close()


def test_clock_faults_are_counted_and_time_never_goes_back():
    """A repeated stamp is dropped (stale), a stamp that leaps ahead with no frame lost is kept and
    counted as a clock jump, a stamp far behind is a restart: time carries on after the newest stamp."""
    enc = StreamFrameEncoder(1, 1)
    stamps = [1_000_000, 1_004_000, 1_004_000, 1_008_000, 6_008_000, 6_012_000, 200_000, 204_000]
    line = b"".join(enc.encode_encoders(s, [0.01 * i]) for i, s in enumerate(stamps))
    line += enc.encode_imus(1_010_000, [[0, 0, 9.81]], [[0, 0, 0]])
    src = SerialSource("loop://", _cfg(1, 1))
    (b,) = _collect(src, line)
    expect = [1.0, 1.004, 1.008, 6.008, 6.012, 6.012001, 6.016001]
    np.testing.assert_allclose(b.t_q, expect, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.q[:, 0], [0.0, 0.01, 0.03, 0.04, 0.05, 0.06, 0.07], atol=1e-12)
    c = src.counters.extra
    assert (c["stale_frames"], c["clock_jumps"], c["counter_resets"]) == (1, 1, 1)
    assert c.get("sequence_gaps", 0) == 0
    src.close()


def test_a_silent_stream_loses_only_what_it_cannot_pair():
    """Encoders without any IMU sample for longer than the hold time: the oldest are dropped and
    counted (``samples_unpaired``); the rest pair with the IMU sample that finally comes."""
    enc = StreamFrameEncoder(1, 1)
    src = SerialSource("loop://", _cfg(1, 1))
    n = 751  # 3 s of encoder samples at 250 Hz
    assert src.decode(b"".join(enc.encode_encoders(4000 * i, [0.0]) for i in range(n))) == []
    (b,) = _collect(src, enc.encode_imus(3_000_000, [[0, 0, 9.81]], [[0, 0, 0]]))
    kept = len(b.t_q)
    assert src.counters.extra["samples_unpaired"] == n - kept
    assert b.t_q[0] == pytest.approx(1.0, abs=1e-9) and b.t_q[-1] == pytest.approx(3.0, abs=1e-9)
    src.close()
