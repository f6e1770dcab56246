"""The serial wire frame: one sample of encoders and IMUs per frame, CRC-32 protected.

Layout (all integers little-endian; full tables and a worked example in ``docs/wire-formats.md``)::

    offset size  field
    0      2     sync 0xA5 0x5A
    2      2     length    payload bytes = 4·N + 12·K
    4      2     seq       frame sequence number, +1 per frame (mod 2^16): gaps = lost frames
    6      4     counter   device sample counter, +1 per sample (mod 2^32): t = counter × period
    10     1     N         number of joints
    11     1     K         number of IMUs
    12     4·N   q         int32, joint position, LSB = 1e-6 rad (or m)
    ..     6·K   acc       int16 x,y,z per IMU, LSB = 0.005 m/s² (specific force, sensor frame)
    ..     6·K   gyro      int16 x,y,z per IMU, LSB = 0.001 rad/s (sensor frame)
    end-4  4     crc       CRC-32 (ISO-HDLC, as zlib.crc32) over bytes 2 .. end-4

Why CRC-32 and an exact-length check rather than CRC-16: a burst of line garbage can contain a byte
pair equal to the sync word followed by plausible header bytes. The decoder accepts a candidate only if
its length and counts equal the configured device *and* the CRC matches, so a forged header passes with
probability about 2^-32 per occurrence (CRC-16 alone would let one in every 65,536 through).
``binascii.crc32`` is the C implementation from the standard library.

Multi-rate devices (a ``"streams"`` section in the device description) send *stream frames* instead:
the same header and CRC behind the sync word ``0xA5 0x5B``, with the two count bytes read as a stream
tag and that stream's count, and the counter read as the stream's own time stamp::

    0      2     sync 0xA5 0x5B
    2      2     length    4·N (encoder frame) or 12·K (IMU frame)
    4      2     seq       +1 per frame of this stream (mod 2^16): gaps = this stream's lost frames
    6      4     stamp     the stream's time stamp, +period/tick per sample (mod 2^32): t = stamp × tick
    10     1     stream    1 = encoders, 2 = IMUs
    11     1     count     N (encoders) or K (IMUs)
    12     ..    payload   encoders: q as above; IMUs: acc then gyro as above
    end-4  4     crc       as above

A host set up for one kind never accepts the other: the sync words differ, so single-stream decoders
(and old hosts) skip stream frames as line noise and vice versa.

Resynchronisation: after a rejected candidate the decoder restarts the search one byte after its sync
word, so a false sync inside garbage never swallows the real frame behind it.

Example
-------
>>> import numpy as np
>>> enc = FrameEncoder(n_joints=1, n_imus=1)
>>> wire = enc.encode(counter=7, q=[0.5], acc=[[0, 0, 9.81]], gyro=[[0.1, 0, 0]])
>>> wire.hex()
'a55a1000000007000000010120a1070000000000aa076400000000005eea9768'
>>> dec = FrameDecoder(n_joints=1, n_imus=1)
>>> frames = dec.feed(b"\\x00garbage" + wire)
>>> [(f.seq, f.counter) for f in frames], dec.bytes_discarded
([(0, 7)], 8)
>>> q, acc, gyro = decode_payloads([f.payload for f in frames], 1, 1)
>>> float(q[0, 0]), float(acc[0, 0, 2]), float(gyro[0, 0, 0])
(0.5, 9.81, 0.1)

Stream frames of a multi-rate device (``docs/wire-formats.md`` has the bytes of both):

>>> senc = StreamFrameEncoder(n_joints=1, n_imus=1)
>>> wire = senc.encode_encoders(stamp=4000, q=[0.5]) + senc.encode_imus(stamp=8000, acc=[[0, 0, 9.81]],
...                                                                        gyro=[[0.1, 0, 0]])
>>> sdec = FrameDecoder(n_joints=1, n_imus=1, streams=True)
>>> [(f.stream, f.seq, f.counter, len(f.payload)) for f in sdec.feed(wire)]
[(1, 0, 4000, 4), (2, 0, 8000, 12)]
"""

from __future__ import annotations

import binascii
import struct
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

__all__ = [
    "ACC_LSB",
    "GYRO_LSB",
    "HEADER",
    "MAX_IMUS",
    "MAX_JOINTS",
    "Q_LSB",
    "STREAM_ENCODERS",
    "STREAM_IMUS",
    "SYNC",
    "SYNC_STREAM",
    "DecodedFrame",
    "FrameDecoder",
    "FrameEncoder",
    "StreamFrameEncoder",
    "decode_payloads",
    "frame_size",
    "payload_dtype",
    "quantize",
]

SYNC = b"\xa5\x5a"
#: Sync word of a multi-rate device's stream frames.
SYNC_STREAM = b"\xa5\x5b"
#: Stream tags (byte 10 of a stream frame).
STREAM_ENCODERS = 1
STREAM_IMUS = 2
#: sync, length, seq, counter, N, K
HEADER = struct.Struct("<2sHHIBB")
CRC = struct.Struct("<I")
MAX_JOINTS = 255
MAX_IMUS = 255

#: Quantization shared by both wires (the project DBC uses the same scales).
Q_LSB = 1e-6
ACC_LSB = 0.005
GYRO_LSB = 0.001


class DecodedFrame(NamedTuple):
    """One intact frame. ``counter`` is the sample counter, or a stream frame's time stamp; ``stream`` is
    0 for a single-stream frame, else :data:`STREAM_ENCODERS` or :data:`STREAM_IMUS`."""

    seq: int
    counter: int
    payload: bytes
    stream: int = 0


def payload_dtype(n_joints: int, n_imus: int) -> np.dtype:
    """The numpy record type of one payload (packed, little-endian)."""
    return np.dtype([("q", "<i4", (n_joints,)), ("acc", "<i2", (n_imus, 3)), ("gyro", "<i2", (n_imus, 3))])


def frame_size(n_joints: int, n_imus: int) -> int:
    """Bytes of one frame on the wire."""
    return HEADER.size + 4 * n_joints + 12 * n_imus + CRC.size


def quantize(values: np.ndarray, lsb: float, dtype: str) -> tuple[np.ndarray, int]:
    """Round to integer counts of ``lsb``, saturating at the type's range; returns (counts, n_clipped)."""
    info = np.iinfo(dtype)
    counts = np.rint(np.asarray(values, dtype=np.float64) / lsb)
    clipped = int(np.count_nonzero((counts < info.min) | (counts > info.max)))
    return np.clip(counts, info.min, info.max).astype(dtype), clipped


def _check_counts(n_joints: int, n_imus: int) -> None:
    if not (0 <= n_joints <= MAX_JOINTS and 0 <= n_imus <= MAX_IMUS and n_joints + n_imus > 0):
        raise ValueError(f"need 0..{MAX_JOINTS} joints and 0..{MAX_IMUS} IMUs, at least one in all")


class FrameEncoder:
    """Device side: build frames, numbering them. ``clipped`` counts values saturated to the range."""

    def __init__(self, n_joints: int, n_imus: int, seq: int = 0) -> None:
        _check_counts(n_joints, n_imus)
        self.n_joints, self.n_imus = n_joints, n_imus
        self.seq = seq & 0xFFFF
        self.clipped = 0
        self._dtype = payload_dtype(n_joints, n_imus)

    def encode(
        self,
        counter: int,
        q: Sequence[float] | np.ndarray,
        acc: np.ndarray | Sequence,
        gyro: np.ndarray | Sequence,
    ) -> bytes:
        rec = np.zeros((), dtype=self._dtype)
        rec["q"], c1 = quantize(np.reshape(q, (self.n_joints,)), Q_LSB, "<i4")
        rec["acc"], c2 = quantize(np.reshape(acc, (self.n_imus, 3)), ACC_LSB, "<i2")
        rec["gyro"], c3 = quantize(np.reshape(gyro, (self.n_imus, 3)), GYRO_LSB, "<i2")
        self.clipped += c1 + c2 + c3
        body = (
            HEADER.pack(
                SYNC, self._dtype.itemsize, self.seq, int(counter) & 0xFFFFFFFF, self.n_joints, self.n_imus
            )
            + rec.tobytes()
        )
        self.seq = (self.seq + 1) & 0xFFFF
        return body + CRC.pack(binascii.crc32(body[2:]))


class StreamFrameEncoder:
    """Device side of a multi-rate device: encoder frames and IMU frames, each stream numbered on its
    own (``seq`` may be given to leave a gap: a frame the line lost). ``clipped`` counts saturations."""

    def __init__(self, n_joints: int, n_imus: int) -> None:
        if not (1 <= n_joints <= MAX_JOINTS and 1 <= n_imus <= MAX_IMUS):
            raise ValueError(f"a multi-rate device needs 1..{MAX_JOINTS} joints and 1..{MAX_IMUS} IMUs")
        self.n_joints, self.n_imus = n_joints, n_imus
        self.seq = {STREAM_ENCODERS: 0, STREAM_IMUS: 0}
        self.clipped = 0
        self._dtype = {STREAM_ENCODERS: payload_dtype(n_joints, 0), STREAM_IMUS: payload_dtype(0, n_imus)}

    def _frame(self, stream: int, count: int, stamp: int, payload: np.ndarray, seq: int | None) -> bytes:
        s = self.seq[stream] if seq is None else int(seq) & 0xFFFF
        body = HEADER.pack(SYNC_STREAM, payload.nbytes, s, int(stamp) & 0xFFFFFFFF, stream, count)
        body += payload.tobytes()
        self.seq[stream] = (s + 1) & 0xFFFF
        return body + CRC.pack(binascii.crc32(body[2:]))

    def encode_encoders(self, stamp: int, q: Sequence[float] | np.ndarray, seq: int | None = None) -> bytes:
        """One encoder sample stamped ``stamp`` ticks."""
        rec = np.zeros((), dtype=self._dtype[STREAM_ENCODERS])
        rec["q"], c = quantize(np.reshape(q, (self.n_joints,)), Q_LSB, "<i4")
        self.clipped += c
        return self._frame(STREAM_ENCODERS, self.n_joints, stamp, rec, seq)

    def encode_imus(
        self, stamp: int, acc: np.ndarray | Sequence, gyro: np.ndarray | Sequence, seq: int | None = None
    ) -> bytes:
        """One sample of every IMU stamped ``stamp`` ticks."""
        rec = np.zeros((), dtype=self._dtype[STREAM_IMUS])
        rec["acc"], c1 = quantize(np.reshape(acc, (self.n_imus, 3)), ACC_LSB, "<i2")
        rec["gyro"], c2 = quantize(np.reshape(gyro, (self.n_imus, 3)), GYRO_LSB, "<i2")
        self.clipped += c1 + c2
        return self._frame(STREAM_IMUS, self.n_imus, stamp, rec, seq)


class FrameDecoder:
    """Host side: feed it bytes as they come (any chunking), get back the intact frames.

    Counters (every byte fed ends up either in an accepted frame or in ``bytes_discarded``):

    - ``crc_errors``: candidates whose header fitted but whose CRC did not match;
    - ``bad_headers``: a sync word followed by a length or counts that do not fit this device;
    - ``bytes_discarded``: bytes skipped while searching for a frame (garbage, rejected frames).

    ``streams=True`` decodes a multi-rate device's stream frames (sync ``A5 5B``) instead, of either
    stream; the header must name a known stream with this device's count for it.
    """

    def __init__(self, n_joints: int, n_imus: int, streams: bool = False) -> None:
        _check_counts(n_joints, n_imus)
        self.n_joints, self.n_imus = n_joints, n_imus
        self.streams = streams
        self.sync = SYNC_STREAM if streams else SYNC
        self.payload_len = payload_dtype(n_joints, n_imus).itemsize
        self.frame_len = HEADER.size + self.payload_len + CRC.size
        #: stream frames: (length, count) per stream tag
        self._stream_shape = {STREAM_ENCODERS: (4 * n_joints, n_joints), STREAM_IMUS: (12 * n_imus, n_imus)}
        self.crc_errors = 0
        self.bad_headers = 0
        self.bytes_discarded = 0
        self.bytes_accepted = 0
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held back as the possible start of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial frame (the port went away); its bytes count as discarded."""
        self.bytes_discarded += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[DecodedFrame]:
        """Append ``data``; return the frames completed by it, in order."""
        if self.streams:
            return self._scan(data, SYNC_STREAM, self._stream_frame)
        return self._scan(data, SYNC, self._single_frame)

    def _single_frame(self, header: tuple) -> tuple[int, int] | None:
        """(frame length, stream) of a single-stream header of this decoder's shape; else None."""
        _, length, _, _, nj, ni = header
        if length != self.payload_len or nj != self.n_joints or ni != self.n_imus:
            return None
        return self.frame_len, 0

    def _stream_frame(self, header: tuple) -> tuple[int, int] | None:
        """(frame length, stream) of a stream frame's header of a declared stream and shape; else None."""
        _, length, _, _, stream, count = header
        shape = self._stream_shape.get(stream)
        if shape is None or shape != (length, count) or count == 0:
            return None
        return HEADER.size + length + CRC.size, stream

    def _scan(
        self,
        data: bytes | bytearray | memoryview,
        sync: bytes,
        frame: Callable[[tuple], tuple[int, int] | None],
    ) -> list[DecodedFrame]:
        """The frames ``data`` completes: find ``sync``, check the header (``frame`` gives the frame's
        length and stream, or None) and the CRC; on a bad header or CRC step one byte past the sync and
        look again (counted), so a corrupt frame costs only itself. The rest waits for more bytes."""
        buf = self._buf
        buf += data
        n = len(buf)
        out: list[DecodedFrame] = []
        pos = 0
        hsize = HEADER.size
        while True:
            i = buf.find(sync, pos)
            if i < 0:
                keep = n - 1 if n > pos and buf[n - 1] == sync[0] else n
                self.bytes_discarded += keep - pos
                pos = keep
                break
            self.bytes_discarded += i - pos
            pos = i
            if n - i < hsize:
                break
            header = HEADER.unpack_from(buf, i)
            got = frame(header)
            if got is None:
                self.bad_headers += 1
                self.bytes_discarded += 1
                pos = i + 1
                continue
            flen, stream = got
            end = i + flen
            if n < end:
                break
            (crc,) = CRC.unpack_from(buf, end - 4)
            if binascii.crc32(buf[i + 2 : end - 4]) != crc:
                self.crc_errors += 1
                self.bytes_discarded += 1
                pos = i + 1
                continue
            # seq, then the sample counter (a stream frame's time stamp)
            out.append(DecodedFrame(header[2], header[3], bytes(buf[i + hsize : end - 4]), stream))
            self.bytes_accepted += flen
            pos = end
        del buf[:pos]
        return out


def decode_payloads(
    payloads: Sequence[bytes], n_joints: int, n_imus: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Payloads of T frames -> ``q`` (T,N) rad, ``acc`` (T,K,3) m/s², ``gyro`` (T,K,3) rad/s, at once."""
    dt = payload_dtype(n_joints, n_imus)
    rec = np.frombuffer(b"".join(payloads), dtype=dt)
    return (
        rec["q"].astype(np.float64) * Q_LSB,
        rec["acc"].astype(np.float64) * ACC_LSB,
        rec["gyro"].astype(np.float64) * GYRO_LSB,
    )
