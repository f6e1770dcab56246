"""How :mod:`bench.generator` senses its robots: MPU-6050 errors at the datasheet's limits, its low-pass,
encoder quantization and IMU-to-encoder skew (docs/design.md, 'Facts the error models use'). Written apart
from :mod:`simulators.sensing` on purpose: the generator checks the product against assumptions it did not
make.

Per IMU, fixed for a recording: a sensitivity matrix ``S = I + diag(scale) + cross`` (scale within
±3 %, cross-axis terms within ±2 %), drawn separately for gyro and accelerometer; a gyro zero-rate
offset within ±20 °/s and an accelerometer offset within ±0.4 m/s² per axis. White noise at the
datasheet's densities (gyro 0.005 °/s/√Hz, accelerometer 400 µg/√Hz) is added at the simulation rate,
whose Nyquist band it fills, before the optional low-pass, as the chip adds it before its filter.

The low-pass (``DLPF_CFG`` 3: gyro 42 Hz, 4.8 ms; accelerometer 44 Hz, 4.9 ms) is two equal one-pole
stages whose low-frequency delay is the register map's: a critically damped pair has its -3 dB band at
``0.64 / (π × delay)``, 42.7 Hz for 4.8 ms, within a hertz of the stated band.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter, lfilter_zi

__all__ = ["ImuErrors", "SensedImus", "SensingSpec", "draw_errors", "sample_at", "sense_imus"]

DEG = np.pi / 180.0
G0 = 9.80665

#: MPU-6050 (PS-MPU-6000A-00 rev 3.4) and its register map's DLPF_CFG 3 (docs/design.md, 'Facts the error
#: models use').
GYRO_NOISE_DENSITY = 0.005 * DEG  # rad/s/√Hz
ACC_NOISE_DENSITY = 400e-6 * G0  # m/s²/√Hz
GYRO_OFFSET = 20.0 * DEG  # rad/s, zero-rate offset bound
ACC_OFFSET = 0.4  # m/s², offset bound used here
SCALE = 0.03
CROSS = 0.02
DLPF_GYRO_DELAY = 4.8e-3
DLPF_ACC_DELAY = 4.9e-3


@dataclass(frozen=True)
class SensingSpec:
    """Which sensing errors a generated recording carries."""

    imu_errors: bool = True
    dlpf: bool = False
    encoder_bits: int | None = None
    skew: float = 0.0  # s, IMU samples older than their stamps relative to the encoders

    def __post_init__(self) -> None:
        if self.encoder_bits is not None and not 4 <= self.encoder_bits <= 24:
            raise ValueError(f"encoder_bits must be within 4..24, got {self.encoder_bits}")
        if not 0.0 <= self.skew <= 0.05:
            raise ValueError(f"skew must be within 0..0.05 s, got {self.skew}")

    def quantize(self, q: np.ndarray) -> np.ndarray:
        """Encoder positions as counts of ``2π / 2**bits`` (unchanged without a bit count)."""
        if self.encoder_bits is None:
            return q.copy()
        step = 2 * np.pi / 2**self.encoder_bits
        return np.round(q / step) * step

    def truth_lag(self) -> float:
        """The gyro's total lag behind the encoders, s: skew plus the filter's delay."""
        return self.skew + (DLPF_GYRO_DELAY if self.dlpf else 0.0)

    def to_json(self) -> dict:
        """What a logger would state about its sensors (``dlpf_cfg`` as docs/recording-format.md)."""
        return {
            "source": "bench.generator",
            "dlpf_cfg": 3 if self.dlpf else None,
            "encoder_bits": self.encoder_bits,
            "imu_errors": self.imu_errors,
        }


@dataclass(frozen=True)
class ImuErrors:
    """The drawn errors per IMU: reading = S @ truth + bias + noise."""

    gyro_S: np.ndarray  # (K, 3, 3)
    gyro_bias: np.ndarray  # (K, 3) rad/s
    acc_S: np.ndarray
    acc_bias: np.ndarray  # (K, 3) m/s²
    gyro_noise_std: float  # rad/s per sample at the simulation rate, before any filter
    acc_noise_std: float

    def reorder(self, index: np.ndarray) -> ImuErrors:
        return replace(
            self,
            gyro_S=self.gyro_S[index],
            gyro_bias=self.gyro_bias[index],
            acc_S=self.acc_S[index],
            acc_bias=self.acc_bias[index],
        )


@dataclass(frozen=True)
class SensedImus:
    acc: np.ndarray  # (T, K, 3)
    gyro: np.ndarray  # (T, K, 3)
    errors: ImuErrors


def _sensitivity(rng: np.random.Generator, k: int, on: bool) -> np.ndarray:
    S = np.tile(np.eye(3), (k, 1, 1))
    if on:
        S += rng.uniform(-CROSS, CROSS, (k, 3, 3)) * (1 - np.eye(3))
        S += np.einsum("ki,ij->kij", rng.uniform(-SCALE, SCALE, (k, 3)), np.eye(3))
    return S


def draw_errors(rng: np.random.Generator, k: int, spec: SensingSpec, sim_rate: float) -> ImuErrors:
    """Errors of ``k`` IMUs, uniform within the datasheet's bounds (zero when ``imu_errors`` is off)."""
    on = spec.imu_errors
    band = np.sqrt(sim_rate / 2)
    return ImuErrors(
        gyro_S=_sensitivity(rng, k, on),
        gyro_bias=rng.uniform(-GYRO_OFFSET, GYRO_OFFSET, (k, 3)) * on,
        acc_S=_sensitivity(rng, k, on),
        acc_bias=rng.uniform(-ACC_OFFSET, ACC_OFFSET, (k, 3)) * on,
        gyro_noise_std=GYRO_NOISE_DENSITY * band * on,
        acc_noise_std=ACC_NOISE_DENSITY * band * on,
    )


def _lowpass(x: np.ndarray, delay: float, dt: float) -> np.ndarray:
    """Two one-pole stages, each delaying low frequencies by ``delay / 2``, started settled."""
    a = dt / (dt + delay / 2)
    b, den = [a], [1.0, -(1.0 - a)]
    zi = lfilter_zi(b, den)
    for _ in range(2):
        x, _ = lfilter(b, den, x, axis=0, zi=zi.reshape((1,) + (1,) * (x.ndim - 1)) * x[:1])
    return x


def sample_at(x: np.ndarray, ts: np.ndarray, when: np.ndarray) -> np.ndarray:
    """``x`` (on the uniform grid ``ts``) linearly interpolated at ``when``."""
    dt = ts[1] - ts[0]
    pos = np.clip((when - ts[0]) / dt, 0, len(ts) - 1.000001)
    i = pos.astype(int)
    f = (pos - i)[:, None]
    return x[i] * (1 - f) + x[i + 1] * f


def sense_imus(
    rng: np.random.Generator, sens: np.ndarray, ts: np.ndarray, t: np.ndarray, spec: SensingSpec
) -> SensedImus:
    """IMU readings at stamps ``t`` from MuJoCo's per-step sensor data ``sens`` (steps, 6K: gyro then
    accelerometer per IMU) on the simulation grid ``ts``.

    Sensitivity and offset are linear and the filter passes DC unchanged, so the true signal is
    filtered (when the low-pass is on), sampled at ``t - skew``, and only then scaled and offset. The
    noise is drawn at the samples with the variance the filter leaves of white noise at the
    simulation rate (its impulse response's energy); samples 10 ms apart are then about 3 % correlated
    through the filter, which this leaves out."""
    dt = float(ts[1] - ts[0])
    k = sens.shape[1] // 6
    err = draw_errors(rng, k, spec, 1.0 / dt)
    when = t - spec.skew
    out = np.empty((t.size, k, 2, 3))
    chunk = 8  # IMUs filtered at a time: bounds the full-rate float64 copy
    for j0 in range(0, k, chunk):
        x = sens[:, 6 * j0 : 6 * min(k, j0 + chunk)].astype(np.float64).reshape(len(ts), -1, 2, 3)
        if spec.dlpf:
            x[:, :, 0] = _lowpass(x[:, :, 0], DLPF_GYRO_DELAY, dt)
            x[:, :, 1] = _lowpass(x[:, :, 1], DLPF_ACC_DELAY, dt)
        out[:, j0 : j0 + x.shape[1]] = sample_at(x.reshape(len(ts), -1), ts, when).reshape(t.size, -1, 2, 3)
    gyro = np.einsum("kij,tkj->tki", err.gyro_S, out[:, :, 0]) + err.gyro_bias
    acc = np.einsum("kij,tkj->tki", err.acc_S, out[:, :, 1]) + err.acc_bias
    for x, std, delay in (
        (gyro, err.gyro_noise_std, DLPF_GYRO_DELAY),
        (acc, err.acc_noise_std, DLPF_ACC_DELAY),
    ):
        if std > 0:
            x += rng.normal(0.0, std * _noise_gain(spec.dlpf, delay, dt), x.shape)
    return SensedImus(acc=acc, gyro=gyro, errors=err)


def _noise_gain(dlpf: bool, delay: float, dt: float) -> float:
    """The std the low-pass leaves of unit white noise: the root of its impulse response's energy."""
    if not dlpf:
        return 1.0
    a = dt / (dt + delay / 2)
    one = a * (1.0 - a) ** np.arange(2000)  # one stage's impulse response
    h = np.convolve(one, one)[:2000]
    return float(np.sqrt(np.sum(h**2)))
