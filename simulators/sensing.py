"""How a real robot senses and stamps its motion: encoders, IMU low-pass, two clocks.

Our physics hands out perfect joint velocities at the same instants as the IMU readings; a real robot
does not. :func:`apply_sensing` turns a recording simulated at a high inner rate (the physics clock, e.g.
1 kHz: fast enough to hold what the IMU sees) into what a robot would log:

* **IMU on-chip low-pass** (MPU-6050 ``DLPF_CFG``, register map RM-MPU-6000A rev 4.2, docs/design.md,
  'Facts the error models use'):
  each setting is a bandwidth and a delay. The datasheet gives nothing else, so the filter is modelled
  as the least-assuming filter with exactly those two numbers: a zero-phase windowed-sinc low-pass with
  its cut-off at the bandwidth followed by a pure delay of the stated length.
* **IMU sampling** at its own rate on its own clock: the clock runs ``drift_ppm`` fast against the encoders'
  and its stamps are ``skew`` seconds late (stamped on receipt after a USB-serial link: FTDI's default latency
  timer alone is 16 ms, docs/design.md, 'Facts the error models use'). The reading stamped ``s`` holds the
  filtered motion of encoder-clock time ``s / (1 + drift) - skew - delay``.
* **Encoders** report position only by default (``encoder_velocity=False``), quantized to ``2**encoder_bits``
  counts per turn (12 bits: Dynamixel X-series, 14 bits: AS5047P, docs/design.md, 'Facts the error models
  use') plus white noise, sampled at their own rate on the reference clock.
* **Stamps** of both streams carry Gaussian ``jitter`` (s) and a fraction ``drop`` of the samples of each
  stream is lost (serial frames with bad checksums).

Two presets: ``ideal`` returns the input unchanged (today's simulator output: synced true velocities),
``robot`` is a realistic hobby/research arm:

==================  ==========  =======================================================================
setting             ``robot``   where the figure comes from
==================  ==========  =======================================================================
encoder             14 bit,     AS5047P magnetic encoder, 16384 counts per turn (docs/design.md,
                    250 Hz,     'Facts the error models use'); a bus polled at a few hundred Hz;
                    pos. only   position only, as Dynamixel and AS5047P report it
IMU                 100 Hz,     MPU-6050 with ``SMPLRT_DIV`` = 9 (1 kHz / 10), DLPF_CFG 3: gyro 42 Hz,
                    DLPF 42 Hz  4.8 ms (register map RM-MPU-6000A rev 4.2)
skew                8 ms        "a few ms to tens of ms unless the hardware synchronizes them"
                                (docs/design.md, 'Facts the error models use'); less than one
                                16 ms FTDI latency period
drift               30 ppm      two uncalibrated crystal oscillators (±20-50 ppm parts)
jitter              0.2 ms      stamps taken by a host OS on receipt
drop                0.5 %       a few bad frames per thousand on a serial bus
==================  ==========  =======================================================================

:class:`SensingStream` applies the same model chunk by chunk to a simulation that keeps running (the
farm): the filter, the clocks and the stamps carry on across chunks instead of starting over.

Example
-------
>>> import numpy as np
>>> from simulators.kinematic_tree import random_robot_recording
>>> fine = random_robot_recording(np.random.default_rng(0), n_joints=3, seconds=2.0, rate=1000.0)
>>> rec = apply_sensing(fine, "robot", np.random.default_rng(1))
>>> rec.t_q is not None, rec.qd is None, round(rec.sample_rate), round(rec.encoder_rate)
(True, True, 100, 250)
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.interpolate import CubicHermiteSpline, CubicSpline
from scipy.signal import fftconvolve, firwin

from bodyschema.recording import Recording
from bodyschema.timing import DLPF_ACC, DLPF_GYRO

__all__ = [
    "DLPF_ACC",
    "DLPF_GYRO",
    "PRESETS",
    "SensingOptions",
    "SensingStream",
    "apply_sensing",
    "dlpf_filter",
    "resolve_sensing",
]


@dataclass(frozen=True)
class SensingOptions:
    """Sensing and timing of one robot (see the module docstring for the model and the presets).

    ``None`` rates mean "the simulation's rate"; ``dlpf_cfg`` None means no on-chip filter. Times in
    seconds. ``inner_rate`` is the physics rate used when the options are not ideal.
    """

    name: str = "ideal"
    inner_rate: float = 1000.0
    imu_rate: float | None = None
    encoder_rate: float | None = None
    encoder_velocity: bool = True
    encoder_bits: int | None = None
    encoder_noise: float = 0.0
    skew: float = 0.0
    drift_ppm: float = 0.0
    jitter: float = 0.0
    drop: float = 0.0
    dlpf_cfg: int | None = None

    def __post_init__(self) -> None:
        if self.imu_rate is not None and not 50.0 <= self.imu_rate <= 1000.0:
            raise ValueError(f"imu_rate must be 50..1000 Hz, got {self.imu_rate}")
        if self.encoder_rate is not None and not 100.0 <= self.encoder_rate <= 1000.0:
            raise ValueError(f"encoder_rate must be 100..1000 Hz, got {self.encoder_rate}")
        if not self.inner_rate >= max(self.imu_rate or 0.0, self.encoder_rate or 0.0, 200.0):
            raise ValueError("inner_rate must be at least 200 Hz and at least every stream's rate")
        if self.encoder_bits is not None and not 4 <= self.encoder_bits <= 32:
            raise ValueError(f"encoder_bits must be 4..32, got {self.encoder_bits}")
        if self.dlpf_cfg is not None and self.dlpf_cfg not in range(7):
            raise ValueError(f"dlpf_cfg must be 0..6 (MPU-6050 CONFIG register), got {self.dlpf_cfg}")
        if not 0.0 <= self.drop < 0.5:
            raise ValueError(f"drop must be a fraction in [0, 0.5), got {self.drop}")
        for name in ("encoder_noise", "jitter"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")
        if abs(self.skew) > 1.0 or abs(self.drift_ppm) > 1e4:
            raise ValueError("skew must be within ±1 s and drift within ±10000 ppm")

    @property
    def is_ideal(self) -> bool:
        """True when the options change nothing: the input recording is returned as it is."""
        return (
            self.imu_rate is None
            and self.encoder_rate is None
            and self.encoder_velocity
            and self.encoder_bits is None
            and self.encoder_noise == 0.0
            and self.skew == 0.0
            and self.drift_ppm == 0.0
            and self.jitter == 0.0
            and self.drop == 0.0
            and self.dlpf_cfg is None
        )

    @property
    def gyro_delay(self) -> float:
        """Group delay of the gyro's on-chip filter, s (0 without one)."""
        return 0.0 if self.dlpf_cfg is None else DLPF_GYRO[self.dlpf_cfg][1]

    @property
    def gyro_bandwidth(self) -> float | None:
        """Bandwidth of the gyro's on-chip filter, Hz (None without one)."""
        return None if self.dlpf_cfg is None else DLPF_GYRO[self.dlpf_cfg][0]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SensingOptions:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown sensing settings {sorted(unknown)}")
        return cls(**data)


PRESETS: dict[str, SensingOptions] = {
    "ideal": SensingOptions(),
    "robot": SensingOptions(
        name="robot",
        imu_rate=100.0,
        encoder_rate=250.0,
        encoder_velocity=False,
        encoder_bits=14,
        encoder_noise=0.0,
        skew=8e-3,
        drift_ppm=30.0,
        jitter=0.2e-3,
        drop=0.005,
        dlpf_cfg=3,
    ),
}


def resolve_sensing(spec: str | SensingOptions | None) -> SensingOptions:
    """A preset name (``ideal``, ``robot``), a JSON object string, or options: the options."""
    if spec is None:
        return PRESETS["ideal"]
    if isinstance(spec, SensingOptions):
        return spec
    if spec in PRESETS:
        return PRESETS[spec]
    if spec.lstrip().startswith("{"):
        return SensingOptions.from_json(json.loads(spec))
    raise ValueError(f"unknown sensing {spec!r}: not a preset ({', '.join(PRESETS)}) nor a JSON object")


@functools.lru_cache(maxsize=32)
def _taps(n: int, bandwidth: float, rate: float) -> np.ndarray:
    """The filter's taps, designed once per setting: a stream filters every chunk with the same ones,
    and their design cost as much as the filtering (read-only, as the cache hands out one array)."""
    h = firwin(n, bandwidth, fs=rate)
    h.setflags(write=False)
    return h


def dlpf_filter(x: np.ndarray, rate: float, bandwidth: float) -> np.ndarray:
    """Zero-phase low-pass of ``x`` (T, ...) sampled at ``rate`` with its cut-off at ``bandwidth`` Hz.

    A Hamming-windowed sinc four periods of the cut-off long; the ends are padded by reflection so
    the filter does not pull them towards zero. The delay of the chip is applied separately, as a
    shift of the sampling instants.
    """
    if bandwidth >= rate / 2:
        return x
    half = max(2, math.ceil(2.0 * rate / bandwidth))
    h = _taps(2 * half + 1, bandwidth, rate)
    T = x.shape[0]
    pad = min(half, T - 1)
    xp = np.concatenate([x[pad:0:-1], x, x[-2 : -pad - 2 : -1]], axis=0)
    shape = (-1,) + (1,) * (x.ndim - 1)
    y = fftconvolve(xp, h.reshape(shape), mode="same", axes=0)
    return y[pad : pad + T]


def _stamps(
    start: float, stop: float, rate: float, rng: np.random.Generator, opts: SensingOptions
) -> tuple[np.ndarray, np.ndarray]:
    """Nominal sample instants (own clock) within [start, stop] and their kept index after drops."""
    k0, k1 = math.ceil(start * rate - 1e-9), math.floor(stop * rate + 1e-9)
    nominal = np.arange(k0, k1 + 1) / rate
    keep = np.ones(len(nominal), dtype=bool)
    if opts.drop > 0:
        keep = rng.random(len(nominal)) >= opts.drop
        keep[[0, -1]] = True  # the streams' extent is part of the scenario, not of the drops
    return nominal, keep


def _jittered(stamps: np.ndarray, rate: float, jitter: float, rng: np.random.Generator) -> np.ndarray:
    if jitter <= 0:
        return stamps
    # bounded so that stamps never swap: jitter is a fraction of the period, not a reordering
    noise = np.clip(rng.normal(scale=jitter, size=stamps.shape), -0.4 / rate, 0.4 / rate)
    return stamps + noise


def _sensed(
    rec: Recording,
    opts: SensingOptions,
    delay_g: float,
    t: np.ndarray,
    t_q: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray | None,
    acc: np.ndarray,
    gyro: np.ndarray,
) -> Recording:
    """The sensed recording of the physics' ``rec``: the two streams, the options in ``extra`` and the
    true skew the gyro's stamps carry (the clock skew plus the gyro filter's delay); the physics'
    per-sample extras, which belong to its own instants, are left out."""
    extra = {k: v for k, v in rec.extra.items() if np.ndim(v) == 0 or np.shape(v)[0] != rec.n_samples}
    extra["sensing"] = np.array(json.dumps(opts.to_json()))
    extra["truth_skew"] = np.array(opts.skew + delay_g)
    return replace(
        rec, t=t, t_q=t_q, q=q, qd=qd, qdd=None, acc=acc, gyro=gyro, ref_quat=None, ref_pos=None, extra=extra
    )


def apply_sensing(rec: Recording, sensing: str | SensingOptions, rng: np.random.Generator) -> Recording:
    """What a robot with ``sensing`` would log of the motion in ``rec`` (a single-clock recording
    sampled at least as fast as every stream; see the module docstring for the model).

    Returns ``rec`` itself for ideal options. Otherwise a docs/recording-format.md multi-rate recording:
    ``t`` the IMU stamps, ``t_q`` the encoder stamps, ``q`` (and ``qd`` only with
    ``encoder_velocity``) on ``t_q``; ``extra["sensing"]`` holds the options as JSON and
    ``extra["truth_skew"]`` the IMU's total lag (skew plus filter delay at time 0), s.
    """
    opts = resolve_sensing(sensing)
    if opts.is_ideal:
        return rec
    if rec.q is None or rec.t_q is not None:
        raise ValueError("apply_sensing needs a single-clock recording with joint positions")
    t = rec.t
    inner = rec.sample_rate
    imu_rate = opts.imu_rate or inner
    enc_rate = opts.encoder_rate or inner
    if inner < max(imu_rate, enc_rate) * 0.999:
        raise ValueError(f"the input is sampled at {inner:g} Hz, slower than a sensor stream")
    acc, gyro = rec.acc, rec.gyro
    delay_g = delay_a = 0.0
    if opts.dlpf_cfg is not None:
        bw_a, delay_a = DLPF_ACC[opts.dlpf_cfg]
        bw_g, delay_g = DLPF_GYRO[opts.dlpf_cfg]
        acc = dlpf_filter(acc, inner, bw_a)
        gyro = dlpf_filter(gyro, inner, bw_g)
    t0, t1 = float(t[0]), float(t[-1])
    drift = opts.drift_ppm * 1e-6

    # ---- IMU: instants regular on the IMU clock; the stamp of the reading is late by ``skew``
    lag_max = max(delay_a, delay_g)
    s_start = (t0 + opts.skew + lag_max) * (1 + drift)
    s_stop = (t1 + opts.skew + min(delay_a, delay_g)) * (1 + drift)
    stamps, keep = _stamps(s_start, s_stop, imu_rate, rng, opts)
    phys = stamps / (1 + drift) - opts.skew  # encoder-clock instant each reading was taken
    K = rec.n_imus
    g_spline = CubicSpline(t, gyro.reshape(len(t), -1), axis=0)
    a_spline = CubicSpline(t, acc.reshape(len(t), -1), axis=0)
    gyro_s = g_spline(np.clip(phys - delay_g, t0, t1)).reshape(-1, K, 3)[keep]
    acc_s = a_spline(np.clip(phys - delay_a, t0, t1)).reshape(-1, K, 3)[keep]
    t_imu = _jittered(stamps, imu_rate, opts.jitter, rng)[keep]

    # ---- encoders: the reference clock; Hermite interpolation through the physics' own velocities
    e_stamps, e_keep = _stamps(t0, t1, enc_rate, rng, opts)
    qd_in = rec.qd if rec.qd is not None else np.gradient(rec.q, t, axis=0)
    q_spline = CubicHermiteSpline(t, rec.q, qd_in, axis=0)
    q = q_spline(e_stamps)
    qd = q_spline.derivative()(e_stamps) if opts.encoder_velocity else None
    if opts.encoder_noise > 0:
        q = q + rng.normal(scale=opts.encoder_noise, size=q.shape)
    if opts.encoder_bits is not None:
        lsb = 2 * np.pi / 2**opts.encoder_bits
        q = np.round(q / lsb) * lsb
    t_enc = _jittered(e_stamps, enc_rate, opts.jitter, rng)[e_keep]
    q = q[e_keep]
    qd = None if qd is None else qd[e_keep]

    return _sensed(rec, opts, delay_g, t_imu, t_enc, q, qd, acc_s, gyro_s)


#: Physics samples kept beyond the filter's half-width around every interpolated instant, so the
#: cubic spline through a buffer reads the interior the way one spline through the whole run would.
_SPLINE_MARGIN = 16


class SensingStream:
    """:func:`apply_sensing` for a simulation delivered in consecutive chunks (a running robot).

    :meth:`push` takes the next single-clock chunk at the options' inner rate and returns what the
    robot logs of the motion so far: a multi-rate :class:`Recording` continuing the previous one, or
    None while too little is known yet. The IMU filter needs motion a few tens of ms ahead of each
    reading, so the output trails the physics by :attr:`latency` seconds; what is held back comes out
    with a later chunk, never twice and never restarted. Stamps, drift and the filter run on without a
    break: apart from the random draws (jitter, drops) and float rounding, the concatenated output is
    :func:`apply_sensing` of the concatenated input (up to :attr:`latency` before its end), and the
    same whichever way the motion is cut into chunks.

    >>> import numpy as np
    >>> from simulators.kinematic_tree import random_robot_recording
    >>> fine = random_robot_recording(np.random.default_rng(0), n_joints=2, seconds=1.0, rate=1000.0)
    >>> stream = SensingStream("robot", np.random.default_rng(1))
    >>> outs = [stream.push(fine.select(slice(i, i + 100))) for i in range(0, 1000, 100)]
    >>> [(o.n_samples, o.t_q.shape[0]) for o in outs[:3]], round(stream.latency, 4)
    ([(3, 12), (10, 25), (10, 25)], 0.0512)
    >>> bool(outs[1].t[0] > outs[0].t[-1] and outs[1].t_q[0] > outs[0].t_q[-1])
    True
    """

    def __init__(self, sensing: str | SensingOptions, rng: np.random.Generator) -> None:
        opts = resolve_sensing(sensing)
        if opts.is_ideal:
            raise ValueError("ideal sensing changes nothing: use the simulation's chunks as they are")
        self.opts = opts
        # one generator per stream and purpose, each drawn sample by sample: the draws, and so the
        # output, do not depend on how the motion was cut into chunks
        self._imu_keep, self._imu_jitter, self._enc_keep, self._enc_jitter, self._enc_noise = rng.spawn(5)
        self.inner = float(opts.inner_rate)
        self.imu_rate = float(opts.imu_rate or opts.inner_rate)
        self.enc_rate = float(opts.encoder_rate or opts.inner_rate)
        self.drift = opts.drift_ppm * 1e-6
        self.delay_a = self.delay_g = 0.0
        self.bw_a: float | None = None
        self.bw_g: float | None = None
        if opts.dlpf_cfg is not None:
            self.bw_a, self.delay_a = DLPF_ACC[opts.dlpf_cfg]
            self.bw_g, self.delay_g = DLPF_GYRO[opts.dlpf_cfg]
        half = [
            math.ceil(2.0 * self.inner / bw) for bw in (self.bw_a, self.bw_g) if bw and bw < self.inner / 2
        ]
        self._half = max([2, *half])  # filter half-width, physics samples
        self._buf: dict[str, np.ndarray] | None = None
        self._at_start = True  # the buffer still holds the first physics sample
        self._k_imu: int | None = None  # next nominal IMU index (own clock)
        self._k_enc: int | None = None
        self._pending_imu: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_enc: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._last: Recording | None = None

    @property
    def latency(self) -> float:
        """Seconds of physics the output trails by (filter half-width and spline margin less the IMU's
        own lag: a reading is stamped after the motion it holds)."""
        ahead = (self._half + _SPLINE_MARGIN) / self.inner - self.opts.skew - min(self.delay_a, self.delay_g)
        return max(0.0, ahead)

    def push(self, rec: Recording) -> Recording | None:
        """Take the next single-clock chunk (at the inner rate, continuing the previous one)."""
        if rec.q is None or rec.t_q is not None:
            raise ValueError("a sensing stream takes single-clock chunks with joint positions")
        if rec.n_samples > 1 and abs(rec.sample_rate - self.inner) > 1e-6 * self.inner:
            raise ValueError(f"chunks must be sampled at the inner rate {self.inner:g} Hz")
        qd = (
            rec.qd if rec.qd is not None else np.gradient(rec.q, rec.t, axis=0) if rec.n_samples > 1 else None
        )
        if qd is None:
            qd = np.zeros_like(rec.q)
        new = {"t": rec.t, "q": rec.q, "qd": qd, "acc": rec.acc, "gyro": rec.gyro}
        if self._buf is None:
            self._buf = {k: np.asarray(v, dtype=np.float64) for k, v in new.items()}
            t0 = float(rec.t[0])
            lag_max = max(self.delay_a, self.delay_g)
            self._k_imu = math.ceil((t0 + self.opts.skew + lag_max) * (1 + self.drift) * self.imu_rate - 1e-9)
            self._k_enc = math.ceil(t0 * self.enc_rate - 1e-9)
        else:
            if not float(rec.t[0]) > float(self._buf["t"][-1]):
                raise ValueError("chunks must continue in time")
            self._buf = {k: np.concatenate([self._buf[k], new[k]]) for k in new}
        self._last = rec
        self._sense()
        return self._emit()

    # ------------------------------------------------------------------------------------------
    def _sense(self) -> None:
        """Turn every reading whose inputs are all known into pending samples; trim the buffer."""
        assert self._buf is not None and self._k_imu is not None and self._k_enc is not None
        b = self._buf
        t = b["t"]
        n = t.shape[0]
        h, m = self._half, _SPLINE_MARGIN
        lo = 0 if self._at_start else h + m  # first index whose filtered value is trustworthy
        hi = n - 1 - h - m  # last one
        if hi <= lo + 3:
            return
        opts = self.opts
        # ---- IMU: readings whose physics instants (both filters) lie within [t[lo], t[hi]]
        t_hi = float(t[hi])
        s_hi = (t_hi + opts.skew + min(self.delay_a, self.delay_g)) * (1 + self.drift)
        k1 = math.floor(s_hi * self.imu_rate + 1e-9)
        if k1 >= self._k_imu:
            stamps = np.arange(self._k_imu, k1 + 1) / self.imu_rate
            keep = self._keep(stamps.shape[0], self._imu_keep)
            phys = stamps / (1 + self.drift) - opts.skew
            # filter and interpolate only around the instants needed (plus the spline's margin)
            first = 0 if self._at_start else h
            i0 = max(int(np.searchsorted(t, phys[0] - max(self.delay_a, self.delay_g))) - m, first)
            i1 = min(int(np.searchsorted(t, phys[-1])) + m, n - h)
            f0 = 0 if i0 == 0 else max(i0 - h, 0)
            part = slice(f0, min(i1 + h, n))
            acc, gyro = b["acc"][part], b["gyro"][part]
            if self.bw_a is not None:
                acc = dlpf_filter(acc, self.inner, self.bw_a)
            if self.bw_g is not None:
                gyro = dlpf_filter(gyro, self.inner, self.bw_g)
            K = acc.shape[1]
            sl = slice(i0 - f0, i1 - f0)
            ts = t[i0:i1]
            g = CubicSpline(ts, gyro[sl].reshape(len(ts), -1), axis=0)(
                np.clip(phys - self.delay_g, ts[0], ts[-1])
            )
            a = CubicSpline(ts, acc[sl].reshape(len(ts), -1), axis=0)(
                np.clip(phys - self.delay_a, ts[0], ts[-1])
            )
            t_imu = _jittered(stamps, self.imu_rate, opts.jitter, self._imu_jitter)[keep]
            self._pending_imu.append((t_imu, a.reshape(-1, K, 3)[keep], g.reshape(-1, K, 3)[keep]))
            self._k_imu = k1 + 1
        # ---- encoders: up to the same stamp as the IMU readings, on the reference clock
        e_hi = min(s_hi, float(t[-1]))
        j1 = math.floor(e_hi * self.enc_rate + 1e-9)
        if j1 >= self._k_enc:
            e_stamps = np.arange(self._k_enc, j1 + 1) / self.enc_rate
            e_keep = self._keep(e_stamps.shape[0], self._enc_keep)
            spline = CubicHermiteSpline(t, b["q"], b["qd"], axis=0)
            q = spline(e_stamps)
            qd = spline.derivative()(e_stamps) if opts.encoder_velocity else None
            if opts.encoder_noise > 0:
                q = q + self._enc_noise.normal(scale=opts.encoder_noise, size=q.shape)
            if opts.encoder_bits is not None:
                lsb = 2 * np.pi / 2**opts.encoder_bits
                q = np.round(q / lsb) * lsb
            t_enc = _jittered(e_stamps, self.enc_rate, opts.jitter, self._enc_jitter)[e_keep]
            self._pending_enc.append((t_enc, q[e_keep], None if qd is None else qd[e_keep]))
            self._k_enc = j1 + 1
        # ---- keep what the next readings need: the filter's and the spline's reach before them
        next_phys = min(
            self._k_imu / self.imu_rate / (1 + self.drift) - opts.skew - max(self.delay_a, self.delay_g),
            self._k_enc / self.enc_rate,
        )
        first = int(np.searchsorted(t, next_phys, side="right")) - 1 - (h + m) - 2
        if first > 0:
            self._buf = {k: v[first:] for k, v in b.items()}
            self._at_start = False

    def _keep(self, count: int, rng: np.random.Generator) -> np.ndarray:
        if self.opts.drop <= 0 or count == 0:
            return np.ones(count, dtype=bool)
        return rng.random(count) >= self.opts.drop

    def _emit(self) -> Recording | None:
        """The pending samples as one recording, once both streams have some and they overlap."""
        if not self._pending_imu or not self._pending_enc:
            return None
        t = np.concatenate([p[0] for p in self._pending_imu])
        t_q = np.concatenate([p[0] for p in self._pending_enc])
        if t.shape[0] == 0 or t_q.shape[0] == 0 or not min(t[-1], t_q[-1]) > max(t[0], t_q[0]):
            return None
        acc = np.concatenate([p[1] for p in self._pending_imu])
        gyro = np.concatenate([p[2] for p in self._pending_imu])
        q = np.concatenate([p[1] for p in self._pending_enc])
        qd = None if self._pending_enc[0][2] is None else np.concatenate([p[2] for p in self._pending_enc])
        self._pending_imu.clear()
        self._pending_enc.clear()
        rec = self._last
        assert rec is not None
        return _sensed(rec, self.opts, self.delay_g, t, t_q, q, qd, acc, gyro)
