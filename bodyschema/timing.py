"""Timing tools for comparing an IMU stream with an encoder stream on a different clock (pure).

Real robots log encoder positions on one clock and gyro rates on another, a few ms apart, at different rates,
with gaps; the gyro has been low-passed on chip (docs/design.md, 'Science notes' and 'Facts the error models
use'). The fast estimator's exact gyro models (:mod:`bodyschema.fast`) hold sample by sample, and they are
linear in their parameters, so **any linear time-invariant filter applied alike to the gyro and to every
regressor keeps them exact**. That is the principle here: nothing is compared until both sides have been taken
to one grid and through one band.

* :func:`resample` puts a stream on a uniform grid (cubic spline through its own stamps), marking grid
  points inside long gaps invalid.
* :func:`lowpass` is the common band: a zero-phase spectral low-pass, flat to 0.8 ``fc`` with a
  raised-cosine roll-off to 1.2 ``fc``. With ``derivative=True`` it is the *band-limited
  differentiator*: the same filter times ``i 2πf``, which is exact for every frequency it passes. It is
  used instead of Savitzky-Golay or a smoothing spline because its band is stated in Hz and is exactly
  the band the gyro side goes through, so the derived velocity and the gyro are compared through one
  transfer function; finite-difference and polynomial differentiators deviate from ``i 2πf`` inside
  the band by amounts that depend on the rate (a central difference is 6.5 % low at 10 Hz from 100 Hz
  samples, far above sensor noise).
* :func:`choose_band` sizes that band from the rates and the IMU filter: well below both Nyquist
  frequencies (interpolation and aliasing errors) and below the IMU's on-chip bandwidth (where its
  magnitude response is flat), capped at 10 Hz (robot motion lives below it; quantization noise of a
  derived velocity grows with the cube of the band, :func:`derivative_noise`; a joint that crosses
  fewer than one encoder count per sample has less of it, :func:`rate_noise`).
* :func:`estimate_lag` finds the IMU's lag behind the encoders (clock skew plus filter delay) as the
  shift that lets the encoder-derived velocities explain the most band-limited gyro variance;
  :func:`robust_lag` does it per IMU and takes a weighted median, so a few IMUs the encoders cannot
  explain (a link whose encoder failed, a sensor that came loose) do not drag the answer away.

Example
-------
>>> import numpy as np
>>> t = np.arange(2000) / 100.0
>>> x = np.sin(2 * np.pi * 0.5 * t)
>>> d = lowpass(x, 100.0, 5.0, derivative=True)
>>> bool(np.max(np.abs(d[200:-200] - np.pi * np.cos(np.pi * t[200:-200]))) < 1e-3)
True
>>> choose_band(100.0, 250.0, imu_bandwidth=42.0)
10.0
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from bodyschema.recording import Recording
from bodyschema.topology import Topology

__all__ = [
    "DLPF_ACC",
    "DLPF_GYRO",
    "LagHint",
    "aligned_recording",
    "choose_band",
    "derivative_noise",
    "edge_margin",
    "encoder_count",
    "encoders_moved",
    "estimate_lag",
    "gyro_band_noise",
    "lag_hinted",
    "lag_moved",
    "lag_search_centre",
    "lowpass",
    "measured_lag",
    "median_rate",
    "position_noise",
    "rate_noise",
    "resample",
    "robust_lag",
    "timed_view",
]

#: MPU-6050 DLPF_CFG 0..6 -> (bandwidth Hz, delay s), register map RM-MPU-6000A rev 4.2, CONFIG
#: (docs/design.md, 'Facts the error models use'). Facts used by the simulator's sensing model and by the
#: estimator's error model.
DLPF_ACC: tuple[tuple[float, float], ...] = (
    (260.0, 0.0),
    (184.0, 2.0e-3),
    (94.0, 3.0e-3),
    (44.0, 4.9e-3),
    (21.0, 8.5e-3),
    (10.0, 13.8e-3),
    (5.0, 19.0e-3),
)
DLPF_GYRO: tuple[tuple[float, float], ...] = (
    (256.0, 0.98e-3),
    (188.0, 1.9e-3),
    (98.0, 2.8e-3),
    (42.0, 4.8e-3),
    (20.0, 8.3e-3),
    (10.0, 13.4e-3),
    (5.0, 18.6e-3),
)


def median_rate(t: np.ndarray) -> float:
    """Median sample rate of stamps ``t``, Hz (robust to jitter and drops)."""
    return float(1.0 / np.median(np.diff(np.asarray(t, dtype=float))))


def choose_band(imu_rate: float, encoder_rate: float, imu_bandwidth: float | None = None) -> float:
    """The common comparison band, Hz: ``min(0.1 * min rate, imu_bandwidth / 4, 10)``.

    A tenth of the slower stream's rate keeps cubic interpolation of either stream exact to about
    1e-4 in band; a quarter of the on-chip bandwidth keeps a first-order roll-off within 3 % (the rest
    is in the error model); 10 Hz is above the motion of the arms we monitor.
    """
    fc = min(0.1 * min(imu_rate, encoder_rate), 10.0)
    if imu_bandwidth is not None:
        fc = min(fc, imu_bandwidth / 4.0)
    return float(fc)


def resample(
    t: np.ndarray, x: np.ndarray, grid: np.ndarray, max_gap: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (T, ...) on stamps ``t`` -> (values on ``grid``, valid mask).

    Cubic spline through the stamps; grid points inside a gap longer than ``max_gap`` median periods
    (docs/recording-format.md) are marked invalid rather than trusted.
    """
    t = np.asarray(t, dtype=float)
    y = CubicSpline(t, x, axis=0, extrapolate=False)(grid)
    valid = np.isfinite(y.reshape(len(grid), -1)).all(axis=1)
    d = np.diff(t)
    period = float(np.median(d))
    for i in np.flatnonzero(d > max_gap * period):
        valid &= ~((grid > t[i]) & (grid < t[i + 1]))
    y = np.where(np.isfinite(y), y, 0.0)
    return y, valid


@functools.lru_cache(maxsize=32)
def _response(n: int, rate: float, fc: float) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies and the raised-cosine band of an ``n``-point real FFT (cached: the fast estimator
    filters hundreds of signals of one length; the arrays are read-only)."""
    f = np.fft.rfftfreq(n, 1.0 / rate)
    lo, hi = 0.8 * fc, 1.2 * fc
    H = np.where(f <= lo, 1.0, np.where(f >= hi, 0.0, 0.5 * (1 + np.cos(np.pi * (f - lo) / (hi - lo)))))
    f.setflags(write=False)
    H.setflags(write=False)
    return f, H


def lowpass(
    x: np.ndarray, rate: float, fc: float, derivative: bool = False, axis: int = 0, step: int = 1
) -> np.ndarray:
    """Zero-phase band-limit of ``x`` along ``axis`` (and its exact in-band derivative).

    The line through the first and last sample is taken out before the FFT and put back after (its
    derivative is its slope), so the periodic extension has no jump; the first and last ``2 / fc``
    seconds still carry edge effects and are left out of fits by the callers.

    ``step`` > 1 returns every ``step``-th sample only, computed in the frequency domain by an inverse
    transform ``step`` times shorter (exact: nothing above ``1.2 fc`` survives the band, so nothing
    folds as long as ``rate / step >= 2.4 fc``). The fast estimator filters hundreds of regressors and
    keeps one sample in ``step``; this is most of its time saved.
    """
    from scipy import fft as sfft

    if step < 1 or (step > 1 and rate / step < 2.4 * fc):
        raise ValueError(f"step {step} folds the {fc:g} Hz band of data sampled at {rate:g} Hz")
    x = np.moveaxis(np.asarray(x, dtype=float), axis, -1)
    n = x.shape[-1]
    m = -(-n // step)  # output samples
    n_fft = step * sfft.next_fast_len(m, real=True)
    ramp = np.linspace(0.0, 1.0, n)
    a, b = x[..., :1], x[..., -1:]
    xd = x - a
    xd -= (b - a) * ramp
    n_out = n_fft // step
    nb = n_out // 2 + 1  # every step-th sample of the length-n_fft inverse: the first nb bins' inverse
    f, H = _response(n_fft, rate, fc)
    X = sfft.rfft(xd, n=n_fft, axis=-1)[..., :nb]
    X *= H[:nb] * (2j * np.pi * f[:nb]) if derivative else H[:nb]
    y = sfft.irfft(X, n=n_out, axis=-1)[..., :m] / step
    if derivative:
        y += (b - a) * rate / max(n - 1, 1)
    else:
        y += a + (b - a) * ramp[::step]
    return np.moveaxis(y, -1, axis)


def position_noise(q: np.ndarray) -> np.ndarray:
    """Per-joint white-noise std of encoder positions (quantization plus noise), rad, (N,).

    From the third difference (variance 20 σ² for white noise, nearly nothing for smooth motion at
    encoder rates); the top 1 % is trimmed for the instants where a torque step breaks smoothness. A
    mean of squares, not a median, because quantization error of a slow joint is mostly an exact zero.
    """
    q = np.asarray(q, dtype=float)
    if q.shape[0] < 8:
        return np.zeros(q.shape[1])
    d3 = np.diff(q, n=3, axis=0) ** 2
    cut = np.quantile(d3, 0.99, axis=0)
    d3 = np.where(d3 <= cut, d3, 0.0)
    return np.sqrt(d3.mean(axis=0) / 20.0)


def gyro_band_noise(
    gyro: np.ndarray, rate: float, fc: float, imu_bandwidth: float | None = None
) -> np.ndarray:
    """(K,) std per channel of the gyro noise of ``gyro`` (T, K, 3) sampled at ``rate`` inside 0..fc
    (0 where too few samples to tell).

    Model: white sensor noise of density ``N0`` through the IMU's stated low-pass (``imu_bandwidth``,
    Hz), so the band keeps ``N0 fc``. Without a filter below ``rate / 2`` the noise is white to Nyquist
    and :func:`bodyschema.fast_core.noise_level` (the third difference, which smooth motion hardly
    reaches) gives it. A filter below Nyquist empties the top of the spectrum the third difference
    reads: at 100 Hz a 20 Hz filter leaves it under 1 % of the noise, so ``N0`` is read instead from the
    spectrum between half the bandwidth and the bandwidth (above the comparison band, which
    :func:`choose_band` keeps under a quarter of it), divided by a first-order roll-off's power gain
    there. The filter's true shape is not stated: a sharper one passes up to twice a first-order one's
    power there (whose gain is ½ at the bandwidth, 0.8 at half of it), so the variance errs high by at
    most 2, the side on which more models fit. Welch's median average and the median over frequencies
    keep torque steps and motion lines out, as the median does for the third difference.

    >>> rng = np.random.default_rng(0)
    >>> x = rng.normal(scale=1e-3, size=(6000, 1, 3))  # white to 50 Hz: 1e-6 rad²/s² over 0..50 Hz
    >>> bool(abs(gyro_band_noise(x, 100.0, 5.0)[0] / (1e-3 * np.sqrt(5 / 50)) - 1) < 0.05)
    True
    """
    from scipy.signal import welch

    from bodyschema.fast_core import noise_level

    gyro = np.asarray(gyro, dtype=float)
    sigma = None
    if imu_bandwidth is not None and imu_bandwidth < rate / 2 and gyro.shape[0] >= 64:
        nper = int(min(gyro.shape[0] // 4, 2 ** np.ceil(np.log2(4 * rate))))
        f, psd = welch(gyro - np.median(gyro, axis=0), fs=rate, nperseg=nper, axis=0, average="median")
        sel = (f >= imu_bandwidth / 2) & (f <= imu_bandwidth)
        if sel.any():
            gain = 1.0 / (1.0 + (f[sel] / imu_bandwidth) ** 2)
            density = np.median(psd[sel] / gain[:, None, None], axis=0)  # (K, 3), one-sided, per Hz
            sigma = np.sqrt(np.mean(density, axis=-1) * fc)
    if sigma is None:
        sigma = noise_level(gyro) * np.sqrt(min(1.0, fc / (rate / 2)))
    return np.where(np.isfinite(sigma), sigma, 0.0)


def derivative_noise(sigma_q: np.ndarray, rate: float, fc: float) -> np.ndarray:
    """In-band std of the derivative of white position noise ``sigma_q`` sampled at ``rate``, rad/s.

    White noise of variance σ² spreads evenly over 0..rate/2; differentiating multiplies its spectrum
    by (2πf)², and the band keeps 0..fc: σ² (2 / rate) (2π)² fc³ / 3.
    """
    return np.sqrt(np.asarray(sigma_q) ** 2 * (2.0 / rate) * (2 * np.pi) ** 2 * fc**3 / 3.0)


def encoder_count(q: np.ndarray) -> np.ndarray:
    """Per joint, the count (rad) whose whole multiples its positions are, 0 where they are not (N,).

    A quantizing encoder reports ``k Δ``: every change of reading is a whole number of counts. The
    smallest change seen is one count or a few (a joint that never moved by exactly one); the largest
    divisor of it, up to 4, that divides every change within 1e-3 count is taken. Positions off any
    lattice (no quantization, or noise added after it) give 0.

    >>> q = np.round(np.sin(np.arange(500) / 50)[:, None] / 1e-3) * 1e-3
    >>> encoder_count(np.hstack([q, np.sin(np.arange(500) / 50)[:, None]])).round(6).tolist()
    [0.001, 0.0]
    """
    q = np.asarray(q, dtype=float)
    out = np.zeros(q.shape[1])
    for j in range(q.shape[1]):
        d = np.abs(np.diff(q[:, j]))
        d = d[d > 0]
        if d.size < 2:
            continue
        for m in (1, 2, 3, 4):
            step = float(d.min()) / m
            k = d / step
            if np.max(np.abs(k - np.round(k))) < 1e-3:
                out[j] = step
                break
    return out


def rate_noise(q: np.ndarray, rate: float, fc: float) -> np.ndarray:
    """In-band std of the rate derived from encoder positions ``q`` (T, N) sampled at ``rate``, rad/s, (N,).

    :func:`derivative_noise` of :func:`position_noise`, which takes the position error to be white:
    true of noise, and of quantization while a joint crosses at least one count per sample (the error
    then decorrelates from sample to sample). A joint on a lattice (:func:`encoder_count`) that crosses
    fewer counts changes its reading only at the crossings. The crossing is registered at the next
    sample; the band-limited reading puts the step half a sample before it, so each crossing is
    displaced by ``u`` uniform within ±T/2 (variance T²/12, T = 1/rate). The derived rate's error is
    then a train of impulses of weight Δ, one per crossing, each displaced by ``u``; in band
    (2π fc T < 1) an impulse displaced by ``u`` differs from the true one by ``-i ω Δ u``, so ``c``
    crossings per sample leave ``c rate Δ² (T²/12) (2π)² 2 fc³ / 3`` = ``c`` times the white figure
    for Δ²/12. Hence the white figure times ``c``, the mean over samples of ``min(1, |Δq| / Δ)`` (a
    sample that moved one count or more is in the white regime). Without a lattice ``c`` is 1.

    Measured against the unquantized positions of ``bench/generator.py`` robots (12-bit encoders,
    10 Hz band): joints crossing 0.26-0.34 counts per sample within 3 % of the true error, where the
    white figure is 1.8 times too high; moving joints within 10 %. Both figures assume the motion
    dithers the crossings (as a robot's dynamics do): a joint that dithers about one count with no
    motion of its own (jammed, chattering) changes its reading at random and is several times noisier
    than either, and so is a noiseless periodic motion, whose quantization error is periodic too. The
    estimator leaves such joints to its other excitation floors (gyro noise, model error).
    """
    q = np.asarray(q, dtype=float)
    white = derivative_noise(position_noise(q), rate, fc)
    count = encoder_count(q)
    moved = np.abs(np.diff(q, axis=0)) / np.where(count > 0, count, 1.0)
    c = np.where(count > 0, np.mean(np.minimum(moved, 1.0), axis=0) if len(moved) else 1.0, 1.0)
    return white * np.sqrt(c)


def estimate_lag(
    y: np.ndarray,
    x_at: Callable[[float], np.ndarray],
    max_lag: float = 0.1,
    step: float = 1e-3,
) -> tuple[float, np.ndarray, np.ndarray]:
    """The lag ``d`` (s) that maximises the variance of ``y`` (T, M) explained by ``x_at(d)`` (T, P).

    ``x_at(d)`` returns the band-limited encoder signals evaluated ``d`` seconds before the IMU grid.
    A coarse search over ±``max_lag`` in ``step`` s is refined by a parabola through the best point and
    its neighbours (the explained variance is smooth in ``d``: both sides are band-limited).
    Returns (lag, the lags tried, explained fraction at each).
    """
    yc = y - y.mean(axis=0)
    total = float(np.sum(yc * yc))
    lags = np.arange(-max_lag, max_lag + step / 2, step)
    s = np.array([float(np.sum(_explained(x_at(float(d)), yc))) for d in lags]) / max(total, 1e-300)
    return _parabola_peak(lags, s, int(np.argmax(s))), lags, s


def _explained(x: np.ndarray, yc: np.ndarray) -> np.ndarray:
    """Per column of the centred ``yc``, the variance a least-squares fit on the columns of ``x``
    (centred here, with a tiny ridge so a silent column cannot make it singular) explains."""
    X = x - x.mean(axis=0)
    G = X.T @ X
    G += (1e-9 * np.trace(G) / max(len(G), 1) + 1e-300) * np.eye(len(G))
    B = X.T @ yc
    return np.sum(B * np.linalg.solve(G, B), axis=0)


def _parabola_peak(lags: np.ndarray, s: np.ndarray, i: int) -> float:
    """The lag of the peak of the parabola through ``s`` at ``i`` and its neighbours (``lags[i]`` at an
    end of the range or where the three points do not curve down)."""
    if 0 < i < len(lags) - 1:
        s0, s1, s2 = s[i - 1], s[i], s[i + 1]
        den = s0 - 2 * s1 + s2
        off = 0.5 * (s0 - s2) / den if den < 0 else 0.0
        return float(lags[i] + np.clip(off, -1.0, 1.0) * (lags[1] - lags[0]))
    return float(lags[i])


def robust_lag(
    y: np.ndarray,
    x_at: Callable[[float], np.ndarray],
    width: int = 3,
    max_lag: float = 0.1,
    step: float = 1e-3,
) -> tuple[float, np.ndarray, np.ndarray]:
    """The lag of :func:`estimate_lag`, found per group of ``width`` columns of ``y`` (one IMU's three
    gyro axes) and combined by a weighted median.

    A pooled search weighs every IMU by its gyro variance. An IMU whose motion the encoders do not
    explain (its link's encoder froze, it came loose) still correlates with the other joints'
    velocities at *some* shift, often at the end of the search range, and when its link moves the most
    it decides the pooled lag: seen as 52 ms instead of 17 ms on a five-joint arm with one frozen
    encoder, after which no model fits and every part looks lost. Per IMU, each gives its own best
    shift; those whose best shift is an end of the range found no lag at all and are left out, and
    the rest are combined by the median weighted by the explained fraction at their best shift, so
    up to half the weight may be wrong. The pooled search is the answer when no IMU has an interior
    peak. The encoder signals ``x_at(d)`` are evaluated once per shift for all IMUs, so this costs
    what the pooled search costs. Returns (lag, each IMU's best shift, its explained fraction there).

    >>> t = np.arange(3000) / 100.0
    >>> x = lambda d: np.stack([np.sin(1.3 * (t - d)), np.cos(0.7 * (t - d))], axis=1)
    >>> good = x(0.02) @ np.array([[1.0, 0.5, 0.0], [0.2, 0.0, 1.0]])
    >>> loose = 5 * np.sin(0.9 * t)[:, None] * np.ones(3)  # follows no joint, four times the variance
    >>> round(robust_lag(np.hstack([good, good, good, loose]), x)[0], 4)
    0.02
    """
    T = y.shape[0]
    G = y.shape[1] // width
    yc = y - y.mean(axis=0)
    total = np.sum((yc * yc).reshape(T, G, width), axis=(0, 2))
    lags = np.arange(-max_lag, max_lag + step / 2, step)
    explained = np.array([_explained(x_at(float(d)), yc).reshape(G, width).sum(axis=1) for d in lags])
    s = explained / np.maximum(total, 1e-300)
    best_i = np.argmax(s, axis=0)
    per = np.array([_parabola_peak(lags, s[:, g], int(best_i[g])) for g in range(G)])
    score = s[best_i, np.arange(G)]
    inside = (best_i > 0) & (best_i < len(lags) - 1) & (score > 0)
    if not inside.any():  # the pooled search (estimate_lag's), from the same fits
        pooled = explained.sum(axis=1) / max(float(total.sum()), 1e-300)
        return _parabola_peak(lags, pooled, int(np.argmax(pooled))), per, score
    order = np.argsort(per[inside])
    w = score[inside][order]
    cum = np.cumsum(w)
    return float(per[inside][order][np.searchsorted(cum, 0.5 * cum[-1])]), per, score


def edge_margin(fc: float) -> float:
    """Seconds at each end (and around each long gap) where :func:`lowpass` still rings: 2 / fc."""
    return 2.0 / fc


def encoders_moved(rec: Recording, seconds: float) -> Recording:
    """``rec`` with its encoder stamps ``seconds`` later: the IMU then lags them by that much less.

    For a monitor that knows the lag it last measured between a robot's two clocks: the estimators
    search the lag within ±100 ms (:class:`bodyschema.fast.FastOptions`), and two free-running clocks
    30 ppm apart drift 108 ms an hour; on a robot whose motion repeats (a gait) a search that misses
    the true peak finds a wrong one inside its range. Moving the stamps by the last lag keeps the true
    one near the middle; :func:`lag_moved` puts the move back into what the estimate reports. A
    single-clock ``rec`` with measured velocities is returned as it is (it has no lag to search); one
    without is read as ``t_q = t`` first (:func:`timed_view`).

    >>> import numpy as np
    >>> rec = Recording(t=np.arange(4.0), joint_names=("j",), q=np.zeros((4, 1)), imu_names=(),
    ...                 acc=np.zeros((4, 0, 3)), gyro=np.zeros((4, 0, 3)), t_q=np.arange(4.0))
    >>> encoders_moved(rec, 0.25).t_q.tolist(), lag_moved({"lag_ms": 3.0, "skew_ms": 1.0}, 0.25)
    ([0.25, 1.25, 2.25, 3.25], {'lag_ms': 253.0, 'skew_ms': 251.0})
    """
    rec = timed_view(rec) if seconds != 0.0 else rec  # positions only, on one clock: t_q = t
    if rec.t_q is None or seconds == 0.0:
        return rec
    return replace(rec, t_q=rec.t_q + float(seconds))


def lag_search_centre(last_lag: float, max_lag: float = 0.1) -> float:
    """How far to move the encoder stamps (:func:`encoders_moved`) given the lag last measured between
    the two clocks (s): all of it once it lies more than half the search range ``max_lag`` from zero,
    else nothing (the search as it is). :meth:`LagHint.centre` with the estimator's range.

    >>> lag_search_centre(0.013), lag_search_centre(-0.08)
    (0.0, -0.08)
    """
    return float(last_lag) if abs(last_lag) > 0.5 * max_lag else 0.0


def lag_moved(timing: dict[str, float], seconds: float) -> dict[str, float]:
    """``timing`` (a topology's) of a recording whose encoder stamps :func:`encoders_moved` moved by
    ``seconds``, as the original stamps see it."""
    out = dict(timing)
    for key in ("lag_ms", "skew_ms"):
        if key in out:
            out[key] = float(out[key]) + 1e3 * float(seconds)
    return out


@dataclass(frozen=True)
class LagHint:
    """Where a monitor that follows one robot from window to window centres the next window's lag
    search, and the one place that moves a window's encoder stamps and puts the move back.

    The estimators search the lag within ±``max_lag`` (:class:`bodyschema.fast.FastOptions`); two
    free-running clocks drift past that within an hour. :meth:`centre` turns the lag last measured
    into a hint, :meth:`apply` moves a window's encoder stamps by it (returning the hint actually
    applied: none to a single-clock window with measured velocities, which has no lag to search) and
    :meth:`put_back` adds that move to the timing an estimate on the moved window reports. The worker,
    the training queue and the cluster's retrain task all go through it.

    >>> import numpy as np
    >>> rec = Recording(t=np.arange(4.0), joint_names=("j",), q=np.zeros((4, 1)), imu_names=(),
    ...                 acc=np.zeros((4, 0, 3)), gyro=np.zeros((4, 0, 3)), t_q=np.arange(4.0))
    >>> hint = LagHint.centre(0.12)
    >>> moved, applied = hint.apply(rec)
    >>> moved.t_q.tolist(), applied.put_back(Topology({"j": None}, {}, timing={"lag_ms": 10.0})).timing
    ([0.12, 1.12, 2.12, 3.12], {'lag_ms': 130.0})
    >>> LagHint.centre(0.013)
    LagHint(seconds=0.0)
    """

    #: how far the encoder stamps are moved, s (0: the search as it is)
    seconds: float = 0.0

    @classmethod
    def centre(cls, last_lag: float | None, max_lag: float | None = None) -> LagHint:
        """The hint for a lag last measured at ``last_lag`` s (None: none measured): all of it once it
        lies more than half the search range ``max_lag`` (default the fast estimator's) from zero."""
        if max_lag is None:
            from bodyschema.fast_core import FastOptions  # fast_core imports this module

            max_lag = FastOptions.max_lag
        return cls(lag_search_centre(last_lag or 0.0, max_lag))

    def apply(self, rec: Recording) -> tuple[Recording, LagHint]:
        """``rec`` with its encoder stamps moved by the hint, and the hint applied (zero where nothing
        moved: a zero hint, or a single-clock ``rec`` with measured velocities)."""
        if not self.seconds or timed_view(rec).t_q is None:
            return rec, LagHint()
        return encoders_moved(rec, self.seconds), self

    def put_back(self, topo: Topology) -> Topology:
        """``topo``, learned on a window :meth:`apply` moved by this hint, with its timing as the
        original stamps see it."""
        if not self.seconds or not topo.timing:
            return topo
        return replace(topo, timing=lag_moved(topo.timing, self.seconds))

    def estimate(self, estimate: Callable[[Recording], Topology], rec: Recording) -> Topology:
        """``estimate(rec)`` on ``rec`` moved by the hint, the move put back into its timing."""
        moved, applied = self.apply(rec)
        return applied.put_back(estimate(moved))


def lag_hinted(estimate: Callable[[Recording], Topology], rec: Recording, hint: float) -> Topology:
    """``estimate(rec)`` with ``rec``'s encoder stamps moved by the lag ``hint`` (s,
    :func:`lag_search_centre`) and the move put back into the timing it reports (:class:`LagHint`):
    a lag that drifted past the search range stays in it. ``hint`` 0 (or a single-clock ``rec`` with
    measured velocities) is the estimate as it is.

    >>> import numpy as np
    >>> rec = Recording(t=np.arange(4.0), joint_names=("j",), q=np.zeros((4, 1)), imu_names=(),
    ...                 acc=np.zeros((4, 0, 3)), gyro=np.zeros((4, 0, 3)), t_q=np.arange(4.0))
    >>> def search(r):  # a lag of 130 ms, searched within ±100 ms
    ...     return Topology({"j": None}, {}, timing={"lag_ms": min(130.0 - 1e3 * float(r.t_q[0]), 100.0)})
    >>> search(rec).timing["lag_ms"], round(lag_hinted(search, rec, 0.12).timing["lag_ms"], 6)
    (100.0, 130.0)
    """
    return LagHint(hint).estimate(estimate, rec)


def measured_lag(topo: Topology) -> float | None:
    """The encoder-to-IMU lag (s) a tree was found with (its ``timing``), None where none was measured:
    what a monitor centres the next window's search on (:meth:`LagHint.centre`)."""
    return 1e-3 * float(topo.timing["lag_ms"]) if "lag_ms" in topo.timing else None


def timed_view(rec: Recording) -> Recording:
    """``rec`` as the timed path reads it: a single-clock recording with positions but no velocities
    measured by the robot has its encoders sampled at the IMU stamps (``t_q = t``); anything else is
    returned as it is.

    Such a file is what a logger writes when one process stamps every stream: the velocities must be
    derived, and only the timed path's band and error model allow for a derived velocity's error
    (:func:`bodyschema.fast.fit_path`). The skew between the streams is still estimated.
    """
    if rec.t_q is None and rec.qd is None and rec.q is not None:
        return replace(rec, t_q=rec.t.copy(), qdd=None)
    return rec


def aligned_recording(rec: Recording, lag: float, drift: float = 0.0, lag_time: float = 0.0) -> Recording:
    """A single-clock copy of a multi-rate ``rec`` with the encoder stream moved onto the IMU's time.

    For estimators that need one sample of every signal per instant (the sensor networks). The IMU
    streams are resampled to a uniform grid at their median rate; joint positions and their first two
    derivatives come from the encoder positions band-limited to what that grid can hold
    (:func:`lowpass`, the same differentiator as the fast estimator's) and are evaluated ``lag + drift
    (t - lag_time)`` seconds before each grid instant, the IMU's lag behind the encoders as estimated by
    :func:`bodyschema.fast.fast_fit`. Grid points in long IMU gaps and within
    :func:`edge_margin` of the ends are dropped. A single-clock ``rec`` is returned as it is.
    """
    if rec.t_q is None or rec.q is None:
        return rec
    t, t_q = rec.t, rec.t_q
    f_imu, f_enc = median_rate(t), median_rate(t_q)
    fa = min(0.4 * f_imu, 0.45 * f_enc)
    margin = edge_margin(fa) + abs(lag)
    lo, hi = max(t[0], t_q[0]) + margin, min(t[-1], t_q[-1]) - margin
    if not hi > lo:
        raise ValueError("the IMU and encoder streams overlap too little to align them")
    grid = lo + np.arange(int(np.floor((hi - lo) * f_imu)) + 1) / f_imu
    K = rec.n_imus
    imu, valid = resample(t, np.concatenate([rec.gyro, rec.acc], axis=1).reshape(len(t), -1), grid)
    imu = imu.reshape(len(grid), 2 * K, 3)
    egrid = t_q[0] + np.arange(int(np.floor((t_q[-1] - t_q[0]) * f_enc)) + 1) / f_enc
    q_e, _ = resample(t_q, rec.q, egrid)
    qd_e = lowpass(q_e, f_enc, fa, derivative=True)
    at = grid - (lag + drift * (grid - lag_time))
    q = CubicSpline(egrid, lowpass(q_e, f_enc, fa), axis=0)(at)
    qd = CubicSpline(egrid, qd_e, axis=0)(at)
    qdd = CubicSpline(egrid, lowpass(qd_e, f_enc, fa, derivative=True), axis=0)(at)
    keep = np.flatnonzero(valid)
    extra = {k: v for k, v in rec.extra.items() if np.ndim(v) == 0 or np.shape(v)[0] != len(t)}
    return replace(
        rec,
        t=grid[keep],
        t_q=None,
        q=q[keep],
        qd=qd[keep],
        qdd=qdd[keep],
        gyro=imu[keep, :K],
        acc=imu[keep, K:],
        ref_quat=None,
        ref_pos=None,
        extra=extra,
    )
