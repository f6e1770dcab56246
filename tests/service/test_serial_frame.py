"""The serial frame codec: round trip, and a fuzz run against garbage, forged headers and bit flips."""

from __future__ import annotations

import binascii
import struct

import numpy as np
import pytest

from service.ingest.device import DeviceConfig
from service.ingest.serial import SerialSource
from service.ingest.serial_frame import (
    ACC_LSB,
    GYRO_LSB,
    HEADER,
    Q_LSB,
    SYNC,
    FrameDecoder,
    FrameEncoder,
    decode_payloads,
    frame_size,
    payload_dtype,
    quantize,
)

N_J, N_I = 6, 4


def test_round_trip_values_and_quantization(rng):
    enc = FrameEncoder(N_J, N_I)
    q = rng.uniform(-3, 3, (5, N_J))
    acc = rng.uniform(-60, 60, (5, N_I, 3))
    gyro = rng.uniform(-20, 20, (5, N_I, 3))
    wire = b"".join(enc.encode(100 + i, q[i], acc[i], gyro[i]) for i in range(5))
    assert len(wire) == 5 * frame_size(N_J, N_I)
    dec = FrameDecoder(N_J, N_I)
    frames = dec.feed(wire)
    assert [f.counter for f in frames] == [100, 101, 102, 103, 104]
    assert [f.seq for f in frames] == [0, 1, 2, 3, 4]
    q2, acc2, gyro2 = decode_payloads([f.payload for f in frames], N_J, N_I)
    np.testing.assert_allclose(q2, q, atol=Q_LSB / 2 + 1e-12)
    np.testing.assert_allclose(acc2, acc, atol=ACC_LSB / 2 + 1e-12)
    np.testing.assert_allclose(gyro2, gyro, atol=GYRO_LSB / 2 + 1e-12)
    assert dec.bytes_discarded == 0 and dec.crc_errors == 0 and dec.bad_headers == 0


def test_saturation_is_counted():
    enc = FrameEncoder(1, 1)
    enc.encode(0, [0.0], [[1e6, 0, 0]], [[0, -1e6, 0]])
    assert enc.clipped == 2
    counts, clipped = quantize(np.array([40000 * 0.005]), 0.005, "<i2")
    assert clipped == 1 and counts[0] == 32767


def test_wrong_device_shape_is_a_bad_header():
    wire = FrameEncoder(2, 1).encode(0, [0, 0], [[0, 0, 0]], [[0, 0, 0]])
    dec = FrameDecoder(1, 1)
    assert dec.feed(wire + b"\x00" * 64) == []
    assert dec.bad_headers == 1 and dec.crc_errors == 0
    assert dec.bytes_discarded == len(wire) + 64


def _reference_rejections(stream: bytes, accepted_spans: list[tuple[int, int]], flen: int) -> tuple[int, int]:
    """Brute force: every sync word outside an accepted frame is a candidate; classify it."""
    arr = np.frombuffer(stream, dtype=np.uint8)
    cand = np.flatnonzero((arr[:-1] == SYNC[0]) & (arr[1:] == SYNC[1]))
    starts = np.array([s for s, _ in accepted_spans])
    inside = np.zeros(len(arr), dtype=bool)
    for s, e in accepted_spans:
        inside[s:e] = True
    crc_err = bad = 0
    plen = payload_dtype(N_J, N_I).itemsize
    start_set = set(starts.tolist())
    for p in cand.tolist():
        if inside[p] or p in start_set:
            continue
        _, length, _, _, nj, ni = HEADER.unpack_from(stream, p)
        if length != plen or nj != N_J or ni != N_I:
            bad += 1
            continue
        body = stream[p + 2 : p + flen - 4]
        (crc,) = struct.unpack_from("<I", stream, p + flen - 4)
        assert binascii.crc32(body) != crc, "a forged frame with a valid CRC: the test data is unlucky"
        crc_err += 1
    return crc_err, bad


@pytest.mark.slow
def test_fuzz_garbage_bit_flips_random_reads(seed):
    rng = np.random.default_rng(seed)
    n_frames = 100_000
    flen = frame_size(N_J, N_I)
    plen = payload_dtype(N_J, N_I).itemsize
    dt = payload_dtype(N_J, N_I)
    rec = np.zeros(n_frames, dtype=dt)
    rec["q"], _ = quantize(rng.uniform(-3, 3, (n_frames, N_J)), Q_LSB, "<i4")
    rec["acc"], _ = quantize(rng.normal(0, 20, (n_frames, N_I, 3)), ACC_LSB, "<i2")
    rec["gyro"], _ = quantize(rng.normal(0, 3, (n_frames, N_I, 3)), GYRO_LSB, "<i2")
    raw = rec.tobytes()

    # --- build the stream: frames, with garbage bursts between some of them
    parts: list[bytes] = []
    spans: list[tuple[int, int]] = []  # byte span of each true frame
    pos = 0
    n_absurd = n_forged = 0
    burst_before = rng.random(n_frames) < 0.02
    for i in range(n_frames):
        if burst_before[i]:
            kind = rng.integers(3)
            g = rng.integers(0, 256, rng.integers(1, 80), dtype=np.uint8).tobytes()
            if kind == 1:  # fake sync followed by an absurd length
                g += SYNC + struct.pack("<H", int(rng.integers(plen + 1, 65536))) + g[:6]
                n_absurd += 1
            elif kind == 2:  # a forged header that fits the device exactly: only the CRC can tell
                g += HEADER.pack(SYNC, plen, int(rng.integers(65536)), int(rng.integers(2**32)), N_J, N_I)
                n_forged += 1
            parts.append(g)
            pos += len(g)
        body = HEADER.pack(SYNC, plen, i & 0xFFFF, i, N_J, N_I) + raw[i * plen : (i + 1) * plen]
        frame = body + struct.pack("<I", binascii.crc32(body[2:]))
        parts.append(frame)
        spans.append((pos, pos + flen))
        pos += flen
    stream = bytearray(b"".join(parts))
    # --- bit flips, 1e-4 per bit over everything but the last frame
    n_bits = (len(stream) - flen) * 8
    flips = rng.choice(n_bits, size=rng.binomial(n_bits, 1e-4), replace=False)
    for b in flips.tolist():
        stream[b >> 3] ^= 1 << (b & 7)
    stream = bytes(stream) + b"\x00" * flen  # a quiet line after the last frame
    starts = np.array([s for s, _ in spans])
    fb = flips >> 3
    owner = np.searchsorted(starts, fb, side="right") - 1
    inside = (owner >= 0) & (fb < starts[np.clip(owner, 0, None)] + flen)
    corrupted = set(owner[inside].tolist())
    intact = set(range(n_frames)) - corrupted

    # --- decode with random read sizes
    cfg = DeviceConfig("fuzz", 0.01, [f"j{i}" for i in range(N_J)], [f"imu{i}" for i in range(N_I)])
    src = SerialSource("loop://", cfg)
    got_t, got_q, got_acc = [], [], []
    off = 0
    while off < len(stream):
        size = int(np.exp(rng.uniform(0, np.log(8192))))
        for batch in src.decode(stream[off : off + size]):
            got_t.append(batch.t)
            got_q.append(batch.q)
            got_acc.append(batch.acc)
        off += size
    src.close()
    t = np.concatenate(got_t)
    idx = np.rint(t / 0.01).astype(int)
    q, acc = np.concatenate(got_q), np.concatenate(got_acc)

    # nothing corrupt accepted: every accepted frame is a true frame, bit for bit
    assert len(set(idx.tolist())) == len(idx)
    assert set(idx.tolist()) <= set(range(n_frames))
    np.testing.assert_array_equal(np.rint(q / Q_LSB).astype(np.int64), rec["q"][idx])
    np.testing.assert_array_equal(np.rint(acc / ACC_LSB).astype(np.int64), rec["acc"][idx])
    assert not (set(idx.tolist()) & corrupted)
    # intact frames recovered
    recovered = len(set(idx.tolist()) & intact) / len(intact)
    assert recovered >= 0.999, recovered
    assert set(idx.tolist()) == intact
    # counters equal what was injected
    c = src.counters.as_dict()
    first, last = min(intact), max(intact)
    assert c.get("sequence_gaps", 0) == sum(1 for i in corrupted if first < i < last)
    accepted_bytes = len(idx) * flen
    assert c["bytes_discarded"] == len(stream) - accepted_bytes - src._decoder.pending
    crc_ref, bad_ref = _reference_rejections(stream, [spans[i] for i in sorted(intact)], flen)
    assert c.get("crc_errors", 0) == crc_ref
    assert c.get("bad_headers", 0) == bad_ref
    assert crc_ref >= n_forged and bad_ref >= n_absurd
    print(f"corrupted={len(corrupted)} forged={n_forged} absurd={n_absurd} counters={c}")
    assert len(corrupted) > 1000  # the run did inject faults
