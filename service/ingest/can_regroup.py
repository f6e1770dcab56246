"""Regroup decoded CAN frames into samples by the device sample counter.

Frames of one sampling instant share a counter value. A sample is released when all its frames have
arrived, or when the newest counter seen is ``horizon`` samples ahead of it (its missing frames are taken
as lost), always in counter order so time never goes backwards.

What happens to an incomplete sample is the ``incomplete`` policy:

- ``"drop"`` (default): the sample is dropped (``samples_dropped``). The store leaves an IMU out of a
  whole window when it is missing from part of it, so using a sample without one IMU would make that
  IMU vanish from the window; a missing sample costs nothing of the kind (time stamps keep the gap).
- ``"partial"``: with every joint frame present, the sample is **used** without the IMUs that miss an
  accelerometer or gyroscope frame (``samples_incomplete``); with a joint frame missing it is dropped
  (``samples_dropped``), since a joint position cannot be left out of a sample.

``frames_missing`` counts the frames that never came. A frame for a sample already released is
``late_frames``; a repeat of a frame already held is ``duplicate_frames``; a frame shorter than its DBC
message (short DLC) or one cantools cannot decode is ``decode_errors``; an id the mapping does not use is
``unknown_ids``.

A multi-rate device's streams (``"streams"`` in its config, docs/wire-formats.md) regroup on their own:
:class:`MultirateAssembler` holds one :class:`SampleAssembler` per stream, each regrouping by that
stream's counter, with the stream's stamp frame as one more frame of each sample (a sample without its
stamp cannot be timed and is dropped under either policy). Time is then the stamp (``stamp × tick_s``),
not ``counter × period``; the counter still orders the samples and tells lost ones
(``samples_missing``) from clock faults: ``clock_jumps`` (a stamp that leapt ahead, kept),
``stale_stamps`` (a stamp that did not advance, dropped), and the stamp clock's restarts in the source's
``counter_resets``. ``samples_unpaired`` counts samples dropped while the other stream stayed silent.

Frames are decoded in batches. The signal layout of each message (start bit, length, byte order,
sign, scale, offset) is read from the cantools database and applied to all frames of a batch at once
with numpy, which is what lets one core keep up with a humanoid's worth of frames; messages the
vectorised path does not cover (multiplexed, floating-point signals, CAN FD payloads over 8 bytes) are
decoded by cantools frame by frame. The tests check both paths against ``cantools`` on the same frames.

Example
-------
>>> import numpy as np
>>> from service.ingest.can_layout import encode_samples
>>> from service.ingest.can_mapping import SignalMap
>>> from service.ingest.device import DeviceConfig
>>> cfg = DeviceConfig("r1", 0.01, ("j1",), ("imu0",))
>>> asm = SampleAssembler(SignalMap.for_config(cfg), incomplete="partial")
>>> ids, data = encode_samples(np.array([5, 6]), np.array([[0.1], [0.2]]), np.ones((2, 1, 3)),
...                            np.zeros((2, 1, 3)))
>>> for t in range(2):
...     for f in range(3):
...         if (t, f) != (1, 2):  # the second sample loses its gyro frame
...             asm.add(int(ids[f]), data[t, f].tobytes())
>>> [(b.t.tolist(), b.imu_names) for b in asm.take(flush=True)]
[([0.05], ('imu0',)), ([0.06], ())]
>>> asm.counts["samples_incomplete"], asm.counts["frames_missing"]
(1, 1)
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence

import numpy as np
from cantools.database.can import Message

from service.frames import FrameBatch
from service.ingest.can_mapping import ACC, GYRO, STAMP, Q, SignalMap
from service.ingest.device import DeviceClock, StreamClock, StreamJoiner

__all__ = ["MultirateAssembler", "SampleAssembler", "compile_layout"]

log = logging.getLogger(__name__)

#: (64-bit word, shift within it, length, big-endian, signed, scale, offset) of one signal.
Spec = tuple[int, int, int, bool, bool, float, float]


def compile_layout(msg: Message, names: Sequence[str]) -> tuple[Spec, ...] | None:
    """Bit specs of ``names`` in ``msg`` for the vectorised decoder, or None when it cannot take them.

    A signal qualifies when it is an integer of at most 63 bits that does not straddle a 64-bit word of
    the payload (true of any byte-aligned layout); the message must not be multiplexed.
    """
    if msg.length > 64 or msg.is_multiplexed():
        return None
    specs = []
    for name in names:
        s = msg.get_signal_by_name(name)
        if s.is_float or s.length > 63 or s.is_multiplexer or s.multiplexer_ids:
            return None
        big = s.byte_order == "big_endian"
        if big:
            lin = (s.start // 8) * 8 + (7 - s.start % 8)  # MSB position counted from byte 0's MSB
            word, off = divmod(lin, 64)
            if off + s.length > 64:
                return None
            shift = 64 - off - s.length
        else:
            word, shift = divmod(int(s.start), 64)
            if shift + s.length > 64:
                return None
        specs.append((word, shift, int(s.length), big, bool(s.is_signed), float(s.scale), float(s.offset)))
    return tuple(specs)


def _extract(u_le: np.ndarray, u_be: np.ndarray | None, spec: Spec) -> np.ndarray:
    word, shift, length, big, signed, scale, offset = spec
    src = u_be if big else u_le
    assert src is not None
    raw = (src[:, word] >> np.uint64(shift)) & np.uint64((1 << length) - 1)
    v = raw.astype(np.int64)
    if signed:
        v = np.where(v >= (1 << (length - 1)), v - (1 << length), v)
    return v * scale + offset


class _Group:
    """Frame ids sharing one compiled layout: where each of their signals goes."""

    def __init__(self, specs: tuple[Spec, ...] | None, message: Message, names: tuple[str, ...]):
        self.specs, self.message, self.names = specs, message, names
        self.nbytes = 8 * -(-message.length // 8)
        self.big = specs is not None and any(sp[3] for sp in specs)
        self.dest: list[np.ndarray] = []
        self.factor: list[np.ndarray] = []


def _destinations(
    targets: Sequence[tuple[str, int, int, int, float]], N: int, K: int
) -> tuple[list[int], list[float]]:
    """Column in a sample row (joints, then accelerometers, gyroscopes, stamp) and scale factor of each
    signal of a frame: its counter first, which goes nowhere (-1)."""
    dest = [-1]  # the counter goes nowhere
    factor = [1.0]
    for _, kind, i, axis, f in targets:
        if kind == Q:
            dest.append(i)
        elif kind == ACC:
            dest.append(N + 3 * i + axis)
        elif kind == GYRO:
            dest.append(N + 3 * K + 3 * i + axis)
        else:
            assert kind == STAMP
            dest.append(N + 6 * K)
        factor.append(f)
    return dest, factor


class SampleAssembler:
    """Frames in (``add``/``add_many``), :class:`~service.frames.FrameBatch` out (``take``).

    Not thread-safe: one thread feeds and takes (the CAN source's reader thread)."""

    def __init__(
        self, signal_map: SignalMap, horizon: int = 4, reset_after: int = 256, incomplete: str = "drop"
    ) -> None:
        if horizon < 1:
            raise ValueError("horizon must be >= 1")
        if incomplete not in ("drop", "partial"):
            raise ValueError(f"incomplete must be 'drop' or 'partial', got {incomplete!r}")
        self.incomplete = incomplete
        self.map = signal_map
        self.horizon = horizon
        self.clock = DeviceClock(bits=signal_map.counter_bits, reset_after=reset_after)
        self.counts: Counter[str] = Counter()
        cfg = signal_map.config
        self._n, self._k = N, K = len(cfg.joints), len(cfg.imus)
        stamped = bool(signal_map.stamp_frames)
        self._d = N + 6 * K + int(stamped)
        #: multi-rate stream: its stamps become time (None: counter × period)
        self.stamp_clock: StreamClock | None = None
        if stamped:
            assert signal_map.stream is not None
            self.stamp_clock = StreamClock(signal_map.stream, bits=signal_map.stamp_bits)
        self._last_taken: int | None = None
        fids = sorted(signal_map.by_id)
        self._fids = np.array(fids, dtype=np.int64)
        self._nf = len(fids)
        self._msg_len = np.array([signal_map.by_id[f].message.length for f in fids], dtype=np.int64)
        self._build_groups(signal_map, fids, N, K)
        pos = {f: p for p, f in enumerate(fids)}
        self._joint_pos = np.array(sorted(pos[f] for f in signal_map.joint_frames), dtype=np.int64)
        self._imu_pos = [np.array(sorted(pos[f] for f in fr), dtype=np.int64) for fr in signal_map.imu_frames]
        self._stamp_pos = np.array(sorted(pos[f] for f in signal_map.stamp_frames), dtype=np.int64)
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._ready: list[tuple[int, np.ndarray, tuple[bool, ...]]] = []
        self._last_released: int | None = None
        self._newest: int | None = None
        self._all_imus = (True,) * K

    def _build_groups(self, signal_map: SignalMap, fids: list[int], N: int, K: int) -> None:
        """Sort the frame ids into groups that decode alike (one compiled layout and payload size, or
        cantools per frame id) and record where each frame's signals go in a sample row."""
        self._group_of = np.zeros(self._nf, dtype=np.int64)
        self._row_in_group = np.zeros(self._nf, dtype=np.int64)
        self._groups: list[_Group] = []
        keys: dict[object, int] = {}
        for p, fid in enumerate(fids):
            route = signal_map.by_id[fid]
            names = (signal_map.counter_signal, *[t[0] for t in route.targets])
            specs = compile_layout(route.message, names)
            key: object = (specs, -(-route.message.length // 8)) if specs is not None else ("cantools", fid)
            if key not in keys:
                keys[key] = len(self._groups)
                self._groups.append(_Group(specs, route.message, names))
            g = self._groups[keys[key]]
            dest, factor = _destinations(route.targets, N, K)
            self._group_of[p] = keys[key]
            self._row_in_group[p] = len(g.dest)
            g.dest.append(np.array(dest, dtype=np.int64))
            g.factor.append(np.array(factor))
        self._dest = [np.stack(g.dest) for g in self._groups]
        self._factor = [np.stack(g.factor) for g in self._groups]

    @property
    def ready(self) -> int:
        """Samples released and waiting to be taken."""
        return len(self._ready)

    @property
    def pending(self) -> int:
        return len(self._pending)

    @property
    def resets(self) -> int:
        """Device restarts seen by the counter and (multi-rate) by the stamp clock."""
        return self.clock.resets + (self.stamp_clock.resets if self.stamp_clock is not None else 0)

    def add(self, frame_id: int, data: bytes | bytearray) -> None:
        """Take one data frame; never raises for bad frames (they are counted)."""
        self.add_many([frame_id], [data])

    def add_many(self, frame_ids: Sequence[int], datas: Sequence[bytes | bytearray]) -> None:
        """Take frames in arrival order; never raises for bad frames (they are counted)."""
        m = len(frame_ids)
        if m == 0:
            return
        ids = np.fromiter(frame_ids, dtype=np.int64, count=m)
        pos = np.searchsorted(self._fids, ids)
        pos[pos >= self._nf] = 0
        known = self._fids[pos] == ids
        lens = np.fromiter(map(len, datas), dtype=np.int64, count=m)
        short = known & (lens < self._msg_len[pos])
        self.counts["unknown_ids"] += int(m - known.sum())
        self.counts["decode_errors"] += int(short.sum())
        ok = known & ~short
        if not ok.all():
            keep = np.flatnonzero(ok)
            ids, pos, lens = ids[keep], pos[keep], lens[keep]
            datas = [datas[i] for i in keep.tolist()]
            m = len(keep)
            if m == 0:
                return
        group = self._group_of[pos]
        counter = np.zeros(m, dtype=np.int64)
        good = np.ones(m, dtype=bool)
        values: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (frame rows, dest, value)
        for g_i in np.unique(group).tolist():
            g = self._groups[g_i]
            rows = np.flatnonzero(group == g_i)
            gr = self._row_in_group[pos[rows]]
            if g.specs is not None:
                nb = g.nbytes
                sub = [datas[r] for r in rows.tolist()]
                if (lens[rows] == nb).all():
                    buf = b"".join(sub)
                else:  # pad short payloads (DLC 4, FD 12...), cut excess bytes
                    buf = b"".join(bytes(d[:nb]).ljust(nb, b"\0") for d in sub)
                u_le = np.frombuffer(buf, dtype="<u8").reshape(len(rows), nb // 8)
                u_be = u_le.byteswap() if g.big else None
                vals = np.stack([_extract(u_le, u_be, sp) for sp in g.specs], axis=1)
            else:
                vals = np.zeros((len(rows), len(g.names)))
                for r, row in enumerate(rows.tolist()):
                    try:
                        dec = g.message.decode(bytes(datas[row]), decode_choices=False)
                        vals[r] = [float(dec[n]) for n in g.names]
                    except Exception as err:  # one undecodable frame must not stop the batch
                        good[row] = False
                        log.debug("frame 0x%x: cannot decode: %s", int(ids[row]), err)
            counter[rows] = np.rint(vals[:, 0]).astype(np.int64)
            values.append((rows, self._dest[g_i][gr], vals * self._factor[g_i][gr]))
        bad = int((~good).sum())
        self.counts["decode_errors"] += bad
        idx = self.clock.index_many(counter[good]) if bad else self.clock.index_many(counter)
        if bad:
            full = np.full(m, -(1 << 62), dtype=np.int64)
            full[good] = idx
            idx = full
        self._assemble(idx, pos, values, good)

    def _assemble(self, idx: np.ndarray, pos: np.ndarray, values: list, good: np.ndarray) -> None:
        # a frame is late when its sample was released before it arrived: either in an earlier batch, or
        # pushed out within this one by a frame ``horizon`` samples newer that came before it
        floor = -(1 << 62) if self._newest is None else self._newest
        newest_before = np.maximum.accumulate(np.concatenate([[floor], np.where(good, idx, floor)[:-1]]))
        late = good & (idx <= newest_before - self.horizon)
        if self._last_released is not None:
            late |= good & (idx <= self._last_released)
        n_late = int(late.sum())
        if n_late:
            self.counts["late_frames"] += n_late
        use = good & ~late
        if not use.any():
            return
        uniq, inv = np.unique(idx[use], return_inverse=True)
        nu, F, D = len(uniq), self._nf, self._d
        V = np.zeros((nu, D))
        S = np.zeros((nu, F), dtype=bool)
        for i, u in enumerate(uniq.tolist()):
            held = self._pending.get(u)
            if held is not None:
                V[i], S[i] = held
        use_rows = np.flatnonzero(use)
        frame_pos = pos[use_rows]
        key = inv * F + frame_pos
        first = np.zeros(len(key), dtype=bool)
        _, first_idx = np.unique(key, return_index=True)
        first[first_idx] = True
        fresh = first & ~S[inv, frame_pos]
        n_dup = int(len(key) - fresh.sum())
        if n_dup:
            self.counts["duplicate_frames"] += n_dup
        S[inv[fresh], frame_pos[fresh]] = True
        self.counts["frames"] += int(fresh.sum())
        sample_of = np.full(len(use), -1, dtype=np.int64)
        sample_of[use_rows[fresh]] = inv[fresh]
        for rows, dest, vals in values:
            srow = sample_of[rows]
            sel = srow >= 0
            if not sel.any():
                continue
            d, v = dest[sel], vals[sel]
            r = np.broadcast_to(srow[sel][:, None], d.shape)
            m = d >= 0
            V[r[m], d[m]] = v[m]
        for i, u in enumerate(uniq.tolist()):
            self._pending[u] = (V[i], S[i])
        top = int(uniq[-1])
        if self._newest is None or top > self._newest:
            self._newest = top
        self._release(force=False)

    def _release(self, force: bool) -> None:
        pend, newest = self._pending, self._newest
        if not pend:
            return
        for idx in sorted(pend):
            vals, seen = pend[idx]
            complete = bool(seen.all())
            if not (complete or force or newest - idx >= self.horizon):
                break
            del pend[idx]
            self._last_released = idx
            if complete:
                self._ready.append((idx, vals, self._all_imus))
                continue
            self.counts["frames_missing"] += int(self._nf - seen.sum())
            if (
                self.incomplete == "drop"
                or not seen[self._joint_pos].all()
                or not seen[self._stamp_pos].all()
            ):
                self.counts["samples_dropped"] += 1
                continue
            present = tuple(bool(seen[p].all()) for p in self._imu_pos)
            self.counts["samples_incomplete"] += 1
            self._ready.append((idx, vals, present))

    def take(self, flush: bool = False) -> list[FrameBatch]:
        """Released samples as batches (one per run of samples with the same IMUs present).

        ``flush`` releases every pending sample now (end of stream, or the bus went quiet)."""
        if flush:
            self._release(force=True)
        ready, self._ready = self._ready, []
        out: list[FrameBatch] = []
        cfg = self.map.config
        N, K = self._n, self._k
        times: np.ndarray | None = None
        if self.stamp_clock is not None and ready:
            ready, times = self._stamp_times(ready)
        i = 0
        while i < len(ready):
            mask = ready[i][2]
            j = i + 1
            while j < len(ready) and ready[j][2] == mask:
                j += 1
            run = ready[i:j]
            if times is None:
                t = np.array([r[0] for r in run], dtype=np.float64) * cfg.period_s
            else:
                t = times[i:j]
            V = np.stack([r[1] for r in run])[:, : N + 6 * K]
            sel = np.flatnonzero(mask)
            T = len(run)
            acc = V[:, N : N + 3 * K].reshape(T, K, 3)[:, sel]
            gyro = V[:, N + 3 * K :].reshape(T, K, 3)[:, sel]
            names = tuple(cfg.imus[s] for s in sel)
            out.append(FrameBatch(cfg.robot, t, cfg.joints, V[:, :N].copy(), names, acc, gyro))
            i = j
        return out

    def _stamp_times(self, ready: list) -> tuple[list, np.ndarray]:
        """The released samples of a stamped stream that keep their place in time, and their times."""
        clock = self.stamp_clock
        assert clock is not None
        m = self.map
        idx = np.array([r[0] for r in ready], dtype=np.int64)
        prev = np.concatenate([[idx[0] - 1 if self._last_taken is None else self._last_taken], idx[:-1]])
        steps = idx - prev
        self._last_taken = int(idx[-1])
        self.counts["samples_missing"] += int(np.maximum(steps - 1, 0).sum())
        col = self._n + 6 * self._k
        raw = np.rint((np.array([r[1][col] for r in ready]) - m.stamp_offset) / m.stamp_scale)
        t, keep = clock.times(raw.astype(np.int64), np.maximum(steps, 1))
        self.counts["clock_jumps"] = clock.jumps
        self.counts["stale_stamps"] = clock.stale
        if not keep.all():
            ready = [r for r, k in zip(ready, keep.tolist(), strict=True) if k]
        return ready, t


class MultirateAssembler:
    """The two streams of a multi-rate device: one :class:`SampleAssembler` each, joined into multi-rate
    batches (``t`` IMU stamps, ``t_q`` encoder stamps) by a :class:`~service.ingest.device.StreamJoiner`.

    Same interface as :class:`SampleAssembler` (``add_many``, ``take``, ``ready``, ``pending``,
    ``counts``, ``resets``). Frames go to the stream whose map holds their id; the IMU stream's
    assembler counts ids neither map holds.

    Example
    -------
    >>> from service.ingest.can_layout import encode_stream
    >>> from service.ingest.device import DeviceConfig, StreamSpec
    >>> cfg = DeviceConfig("r", 0.01, ("j",), ("i",)).with_streams(StreamSpec(0.004), StreamSpec(0.01))
    >>> asm = MultirateAssembler(*SignalMap.for_streams(cfg))
    >>> e_ids, _, e = encode_stream("encoders", np.arange(5), 4000 * np.arange(5) + 100, q=np.ones((5, 1)))
    >>> i_ids, _, m = encode_stream("imus", np.arange(2), np.array([8000, 18000]), acc=np.ones((2, 1, 3)),
    ...                             gyro=np.zeros((2, 1, 3)))
    >>> frames = [(int(f), d[k, n]) for ids, d in ((e_ids, e), (i_ids, m)) for k in range(len(d))
    ...           for n, f in enumerate(ids)]
    >>> asm.add_many([f for f, _ in frames], [d.tobytes() for _, d in frames])
    >>> [(b.t.tolist(), b.t_q.tolist()) for b in asm.take(flush=True)]
    [([0.008, 0.018], [0.0001, 0.0041, 0.0081, 0.0121, 0.0161])]
    """

    def __init__(
        self,
        encoder_map: SignalMap,
        imu_map: SignalMap,
        horizon: int = 4,
        reset_after: int = 256,
        incomplete: str = "drop",
    ) -> None:
        self.encoders = SampleAssembler(encoder_map, horizon, reset_after, incomplete)
        self.imus = SampleAssembler(imu_map, horizon, reset_after, incomplete)
        self._enc_ids = np.array(sorted(encoder_map.by_id), dtype=np.int64)
        self.joiner = StreamJoiner(encoder_map.config.robot, encoder_map.config.joints, imu_map.config.imus)

    @property
    def ready(self) -> int:
        """Nonzero when :meth:`take` would return a batch (both streams have samples)."""
        enc_wait, imu_wait = self.joiner.pending
        if not (self.encoders.ready or self.imus.ready):
            return 0
        return int(bool(self.encoders.ready or enc_wait) and bool(self.imus.ready or imu_wait))

    @property
    def pending(self) -> int:
        return self.encoders.pending + self.imus.pending

    @property
    def counts(self) -> Counter[str]:
        c = self.encoders.counts + self.imus.counts
        for k in ("clock_jumps", "stale_stamps", "samples_missing"):  # totals that may be zero
            c[k] = self.encoders.counts[k] + self.imus.counts[k]
        c["samples_unpaired"] = self.joiner.unpaired
        return c

    @property
    def resets(self) -> int:
        return self.encoders.resets + self.imus.resets

    def add(self, frame_id: int, data: bytes | bytearray) -> None:
        """Take one data frame; never raises for bad frames (they are counted)."""
        self.add_many([frame_id], [data])

    def add_many(self, frame_ids: Sequence[int], datas: Sequence[bytes | bytearray]) -> None:
        """Take frames in arrival order, each to its stream; never raises for bad frames."""
        if not len(frame_ids):
            return
        ids = np.fromiter(frame_ids, dtype=np.int64, count=len(frame_ids))
        enc = np.isin(ids, self._enc_ids)
        if enc.all():
            self.encoders.add_many(frame_ids, datas)
            return
        if not enc.any():
            self.imus.add_many(frame_ids, datas)
            return
        e, o = np.flatnonzero(enc).tolist(), np.flatnonzero(~enc).tolist()
        self.encoders.add_many([frame_ids[i] for i in e], [datas[i] for i in e])
        self.imus.add_many([frame_ids[i] for i in o], [datas[i] for i in o])

    def take(self, flush: bool = False) -> list[FrameBatch]:
        """Multi-rate batches of what both streams released (``flush``: release every pending sample)."""
        for b in self.encoders.take(flush):
            self.joiner.add_encoders(b.t, b.q)
        for b in self.imus.take(flush):
            self.joiner.add_imus(b.t, b.imu_names, b.acc, b.gyro)
        return self.joiner.take()
