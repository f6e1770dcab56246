"""The fast estimator's timed path: encoder positions and gyro rates as real robots log them.

Positions without velocities measured by the robot, on the encoders' own stamps or on the IMU's (a
single-clock recording: ``t_q = t``, docs/recording-format.md), go through :func:`timed_fit`: the
velocity is the band-limited derivative of the positions, the IMU's lag behind the encoders is
estimated, and the tests of :mod:`bodyschema.fast_core` run with an error model in place of a tolerance.
The public entry point is :func:`bodyschema.fast.fast_fit`, which picks the path.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from bodyschema.fast_core import (
    FastFit,
    FastOptions,
    _explained,
    _fit,
    _hop_features,
    _TimedTerms,
    _two_hop_features,
)
from bodyschema.recording import Recording

__all__ = ["stated_filter", "timed_fit"]


def stated_filter(rec: Recording, opts: FastOptions) -> FastOptions:
    """``opts`` with the IMU filter the recording states (``extra["sensing"]``) where ``opts`` does
    not state one."""
    if "sensing" not in rec.extra or opts.imu_bandwidth is not None:
        return opts
    import json

    from bodyschema.timing import DLPF_GYRO

    cfg = json.loads(str(rec.extra["sensing"])).get("dlpf_cfg")
    if cfg is None:
        return opts
    bandwidth, delay = DLPF_GYRO[int(cfg)]
    stated_delay = delay if opts.imu_delay is None else opts.imu_delay
    return replace(opts, imu_bandwidth=bandwidth, imu_delay=stated_delay)


def timed_fit(q: np.ndarray, gyro: np.ndarray, t: np.ndarray, t_q: np.ndarray, opts: FastOptions) -> FastFit:
    """The fast estimator on encoder positions ``q`` (T_q, N) stamped ``t_q`` and gyro rates ``gyro``
    (T, K, 3) stamped ``t`` (docs/recording-format.md; ``t_q`` may be ``t`` itself: one clock).

    ``rel_tol`` (the synced path's tolerance) is not used here. Steps (the tools and their reasons are
    in :mod:`bodyschema.timing`):

    1. both streams go to uniform grids by cubic splines through their own stamps; gyro samples in
       gaps over 5 periods are left out;
    2. the velocity is the band-limited derivative of the positions; a velocity the encoders may
       report is not used (it is usually a difference itself, of unknown quality);
    3. the IMU's lag behind the encoders is the shift that lets the encoder velocities explain the most
       band-limited gyro variance (first per IMU, weighted median over the IMUs: an IMU the encoders
       cannot explain does not decide it, :func:`bodyschema.timing.robust_lag`; then from the accepted
       models), per quarter of the recording when it is long enough, so a clock drift shows as a slope;
       ``skew_ms`` is that lag less ``imu_delay``, the stated on-chip filter delay (docs/design.md,
       'Facts the error models use', lists the MPU-6050's);
    4. positions and velocities are evaluated at the lagged instants on the IMU grid, every regressor
       is formed there, and the regressors and the gyro go through one band (``band`` Hz, chosen by
       :func:`bodyschema.timing.choose_band` from the rates and ``imu_bandwidth`` when not given),
       then are thinned to 2.5 samples per band period;
    5. the model tests are those of :mod:`bodyschema.fast` with an **error model** in place of a tolerance:
       the expected residual variance of a right model, per gyro channel, is the in-band gyro noise
       (:func:`bodyschema.timing.gyro_band_noise`: white noise through the stated low-pass) + a relative
       model error ``ε²·RMS²`` with ``ε² = model_tol² + (2π f_rms δ)² + (1 - |H_imu(fc)|)²`` (``δ`` the
       lag's uncertainty: the scatter of the per-quarter lags about their line, at least
       :data:`LAG_RESOLUTION`; ``f_rms`` the gyro's RMS frequency in band; ``H_imu`` a first-order roll-off
       at ``imu_bandwidth``, or at the IMU Nyquist frequency when not stated) + ``n_j² / 3`` for each joint
       ``j`` whose derived rate the model uses (``n_j`` its in-band error, quantization and noise,
       :func:`bodyschema.timing.rate_noise`; it enters as ``e n_j`` with ``|e| = 1``, spread over three
       channels). The on-base and same-link models compare gyros alone; they carry the largest ``n_j² / 3``.
       A joint is tested when its in-band rate RMS is ``min_excitation_snr`` times each per-channel std a
       right model leaves (gyro noise, the model error at :data:`LAG_RESOLUTION`, its own ``n_j / √3``);
       else it is undetermined. A model is accepted when its residual variance is below ``fit_ratio`` times
       that (a variance-ratio test), and rival models are ranked by BIC with the effective sample size of
       the band-limited residuals, ``2 fc`` independent values per second and channel; a rival through
       another joint that fits within the F quantile of the chosen model's residual variance, for those
       degrees of freedom, leaves both joints undetermined (:func:`bodyschema.fast_core._rival_joints`).
    """
    q, gyro, t, t_q = _checked_timed(q, gyro, t, t_q)
    data, lag, shift = _centred_lag(q, gyro, t, t_q, opts)
    err = _error_model(q, data, lag, opts)
    lag_unc = 2e-3  # the first lag is good to a ms or two
    fit = _fit_at(data, err, lag, lag_unc, opts)
    n_seg = int(min(4, (data.tk[-1] - data.tk[0]) // 15.0))
    if fit.edges:
        # the lag again, now from the accepted models themselves (exact where the first search is only
        # nearly so: it ignores the rotation terms), per segment for the drift; then the final fit
        lag, lag_unc = _refined_lag(fit, data, err, lag, n_seg, opts.max_lag)
        fit = _fit_at(data, err, lag, lag_unc, opts)
    fit.lag_ms = 1e3 * float(lag.mid + shift)
    fit.lag_time = lag.t_mid
    fit.skew_ms = 1e3 * float(lag.mid + shift - (opts.imu_delay or 0.0))
    # a drift is a slope through the lags of several 15 s segments, and the lag's uncertainty their
    # scatter about it: neither is claimed from fewer (one segment states 2 ms, unmeasured)
    segments = n_seg >= 2 and bool(fit.edges)
    fit.drift_ppm = 1e6 * float(lag.drift) if segments else None
    fit.lag_unc_ms = 1e3 * float(lag_unc) if segments else None
    fit.band_hz = data.fc
    fit.path = "timed"
    return fit


def _checked_timed(
    q: np.ndarray, gyro: np.ndarray, t: np.ndarray, t_q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The timed inputs as float arrays, refused when their shapes or stamps do not fit or they are
    not finite."""
    q = np.asarray(q, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    t = np.asarray(t, dtype=float)
    t_q = np.asarray(t_q, dtype=float)
    if q.ndim != 2 or q.shape[0] != t_q.shape[0]:
        raise ValueError(f"q {q.shape} must have one row per encoder stamp ({t_q.shape[0]})")
    if gyro.ndim != 3 or gyro.shape[0] != t.shape[0] or gyro.shape[2] != 3:
        raise ValueError(f"gyro {gyro.shape} must be (T, K, 3) with one row per IMU stamp ({t.shape[0]})")
    for name, ts in (("t", t), ("t_q", t_q)):
        if ts.shape[0] < 8 or not np.all(np.diff(ts) > 0):
            raise ValueError(f"{name} must hold at least 8 strictly increasing stamps")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(gyro))):
        raise ValueError("q and gyro must be finite")
    return q, gyro, t, t_q


@dataclass(frozen=True)
class _TimedGrid:
    """Timed data on uniform grids. Rates ``f_imu``, ``f_enc`` and the comparison band ``fc`` (Hz);
    the IMU ``grid`` and the gyro on it, ``gyro_g`` (n, K, 3); ``step`` the thinning of the fit
    samples, which are ``ok`` (on the grid) and ``keep_d`` (among every ``step``-th grid point),
    ``keep`` on the grid, at times ``tk``; ``gyro_b`` (fit samples, 3K) the banded gyro there;
    ``q_s``, ``qd_s`` the positions and velocities as splines (everything the IMU grid can hold),
    ``qd_c`` the velocities in the comparison band."""

    f_imu: float
    f_enc: float
    fc: float
    step: int
    grid: np.ndarray
    gyro_g: np.ndarray
    ok: np.ndarray
    keep_d: np.ndarray
    keep: np.ndarray
    tk: np.ndarray
    gyro_b: np.ndarray
    q_s: Callable[[np.ndarray], np.ndarray]
    qd_s: Callable[[np.ndarray], np.ndarray]
    qd_c: Callable[[np.ndarray], np.ndarray]

    def band(self, x: np.ndarray, axis: int = -1) -> np.ndarray:
        """One band for the gyro and every regressor, picked at the fit samples."""
        from bodyschema import timing as tm

        return np.take(tm.lowpass(x, self.f_imu, self.fc, axis=axis, step=self.step), self.keep_d, axis=axis)


def _timed_grid(
    q: np.ndarray, gyro: np.ndarray, t: np.ndarray, t_q: np.ndarray, opts: FastOptions
) -> _TimedGrid:
    """Steps 1, 2 and the fit samples: uniform grids, band-limited splines, samples away from the ends
    and from long gaps (the filter rings there), thinned."""
    from scipy.interpolate import CubicSpline

    from bodyschema import timing as tm

    K = gyro.shape[1]
    f_imu, f_enc = tm.median_rate(t), tm.median_rate(t_q)
    fc = float(opts.band) if opts.band is not None else tm.choose_band(f_imu, f_enc, opts.imu_bandwidth)
    lo, hi = max(t[0], t_q[0]) + opts.max_lag, min(t[-1], t_q[-1]) - opts.max_lag
    if hi - lo < 4 * tm.edge_margin(fc):
        span = min(t[-1], t_q[-1]) - max(t[0], t_q[0])
        what = "the recording spans" if np.array_equal(t, t_q) else "the streams overlap for"
        raise ValueError(
            f"{what} {span:.3g} s; need at least {4 * tm.edge_margin(fc) + 2 * opts.max_lag:.3g} s at a "
            f"{fc:g} Hz band to derive velocities from positions"
        )
    # 1. uniform grids; the IMU grid's length is ``step`` times a length the FFT handles fast (a few
    # samples at the end are given up so that no filter call pads: hundreds of calls per fit)
    step = max(1, int(f_imu // (2.5 * fc)))
    n_grid = int(np.floor((hi - lo) * f_imu)) + 1
    grid = lo + np.arange(step * _fast_len_below(n_grid // step)) / f_imu
    g_flat, valid = tm.resample(t, gyro.reshape(len(t), -1), grid)
    gyro_g = g_flat.reshape(len(grid), K, 3)
    egrid = t_q[0] + np.arange(int(np.floor((t_q[-1] - t_q[0]) * f_enc)) + 1) / f_enc
    q_e, _ = tm.resample(t_q, q, egrid)
    # 2. band-limited positions and velocities on the encoder grid: ``fa`` keeps everything the IMU
    # grid can hold (they are sampled there next), ``fc`` is the comparison band for the lag search
    fa = min(0.4 * f_imu, 0.45 * f_enc)
    q_s = CubicSpline(egrid, tm.lowpass(q_e, f_enc, fa), axis=0)
    qd_s = CubicSpline(egrid, tm.lowpass(q_e, f_enc, fa, derivative=True), axis=0)
    qd_c = CubicSpline(egrid, tm.lowpass(q_e, f_enc, fc, derivative=True), axis=0)
    # fit samples: away from the ends and from long gaps (the filter rings there), thinned
    margin = tm.edge_margin(fc)
    bad = ~valid
    if bad.any():
        reach = int(np.ceil(margin * f_imu))
        bad = np.convolve(bad.astype(float), np.ones(2 * reach + 1), mode="same") > 0
    ok = ~bad & (grid >= grid[0] + margin) & (grid <= grid[-1] - margin)
    keep_d = np.flatnonzero(ok[::step])  # fit samples among every step-th grid point
    keep = keep_d * step  # the same samples on the grid
    if len(keep) < 50:
        raise ValueError(f"only {len(keep)} usable samples in the {fc:g} Hz band; record longer")
    gyro_b = tm.lowpass(gyro_g, f_imu, fc, step=step)[keep_d].reshape(len(keep), 3 * K)
    return _TimedGrid(
        f_imu, f_enc, fc, step, grid, gyro_g, ok, keep_d, keep, grid[keep], gyro_b, q_s, qd_s, qd_c
    )


@dataclass(frozen=True)
class _Lag:
    """The IMU's lag behind the encoders, s: ``mid`` at encoder-clock time ``t_mid``, with slope
    ``drift`` (s/s)."""

    mid: float
    drift: float
    t_mid: float

    def at(self, tt: np.ndarray) -> np.ndarray:
        return self.mid + self.drift * (tt - self.t_mid)


#: How often :func:`_centred_lag` moves its search past ``max_lag``: two free-running clocks 30 ppm
#: apart drift 108 ms an hour, and nothing resynchronises a robot's encoders with its IMUs. The search
#: follows the flank of the explained-variance peak, so it reaches as far as that flank shows within
#: ``±max_lag``: lags of 0.4 s on a UR5e's 30 s window, not 1 s.
_RECENTRE_STEPS = 10


def _centred_lag(
    q: np.ndarray, gyro: np.ndarray, t: np.ndarray, t_q: np.ndarray, opts: FastOptions
) -> tuple[_TimedGrid, _Lag, float]:
    """Steps 1 to 3's first pass, with the encoder stamps moved by ``shift`` (s) when the lag lies beyond
    ``max_lag``: the grids, the first lag (behind the moved stamps) and the shift; the lag behind the
    encoders' own stamps is ``lag + shift``.

    The search covers ``±max_lag``; a lag found at its edge says the peak lies further, so the encoder
    stamps move by it and the search runs again, at most :data:`_RECENTRE_STEPS` times. Each run's grid
    keeps ``max_lag`` from the ends of the moved streams, so the splines are never read outside their
    data. A lag inside the range (every recording of a clock that was synchronised within minutes)
    takes one pass, as before.
    """
    shift = 0.0
    for _ in range(_RECENTRE_STEPS):
        data = _timed_grid(q, gyro, t, t_q + shift, opts)
        lag = _first_lag(data, opts.max_lag)
        if abs(lag.mid) < opts.max_lag - 4e-3:
            break
        shift += lag.mid
    return data, lag, shift


def _first_lag(data: _TimedGrid, max_lag: float) -> _Lag:
    """Step 3, first pass: the lag from a linear regression of each IMU's gyro on all joint velocities,
    combined over the IMUs by :func:`bodyschema.timing.robust_lag` (it ignores the rotation terms of
    the models, so it is good to a ms or two; per IMU, so a broken link cannot pull it away)."""
    from bodyschema import timing as tm

    tk = data.tk
    lag_mid, _, _ = tm.robust_lag(data.gyro_b, lambda d: data.qd_c(tk - d), max_lag=max_lag, step=2e-3)
    return _Lag(lag_mid, 0.0, float(tk.mean()))


#: The finest lag uncertainty claimed, s: the scatter of the per-segment lags, never under this.
LAG_RESOLUTION = 0.25e-3


@dataclass(frozen=True)
class _ErrorModel:
    """Step 5's error model: in-band gyro noise ``sigma`` (K,), the gyro's in-band RMS ``rms`` and RMS
    frequency ``f_rms`` (K,), the IMU filter's gain variation ``roll`` (K,), what each joint's derived
    rate leaves per gyro channel ``rate_var`` (N,), the independent observations per fit sample
    ``n_eff`` and the joints the band cannot see, ``undetermined`` (N,)."""

    sigma: np.ndarray
    rms: np.ndarray
    f_rms: np.ndarray
    roll: np.ndarray
    rate_var: np.ndarray
    n_eff: float
    undetermined: np.ndarray


def _error_model(q: np.ndarray, data: _TimedGrid, lag: _Lag, opts: FastOptions) -> _ErrorModel:
    """What a right model leaves in band: gyro noise, encoder derivative noise, relative model error;
    and which joints move enough (at the first lag) to be tested."""
    from bodyschema import timing as tm

    f_imu, fc, step, K = data.f_imu, data.fc, data.step, data.gyro_g.shape[1]
    sigma_b = tm.gyro_band_noise(data.gyro_g[data.ok], f_imu, fc, opts.imu_bandwidth)
    qd_noise = tm.rate_noise(q, data.f_enc, fc)
    gc = data.gyro_b.reshape(len(data.keep), K, 3)
    gc = gc - gc.mean(axis=0)
    rms = np.sqrt(np.mean(gc * gc, axis=(0, 2)))
    dg = np.diff(gc, axis=0) * (f_imu / step)
    f_rms = np.sqrt(np.mean(dg * dg, axis=(0, 2)) / np.maximum(np.mean(gc * gc, axis=(0, 2)), 1e-300))
    f_rms = f_rms / (2 * np.pi)
    bw = opts.imu_bandwidth if opts.imu_bandwidth is not None else f_imu / 2
    # a first-order roll-off's gain varies over the motion's band by about 1 - |H(f_rms)| (its phase is
    # a delay, which the lag absorbs; a constant gain folds into the model's coefficients)
    roll = 1 - 1 / np.sqrt(1 + (f_rms / bw) ** 2)
    qdb = data.band(data.qd_s(data.grid - lag.at(data.grid)), axis=0)
    excitation = np.sqrt(np.mean(qdb * qdb, axis=0))
    sigma_ref = float(np.median(sigma_b)) if K else 0.0
    # a joint's rate error n enters a model through e n (|e| = 1, the axis), spread over the three
    # channels a test averages: n² / 3 per channel, as the gyro noise leaves σ² per channel and the
    # model error ε² RMS² (at the lag's resolution, LAG_RESOLUTION). A joint is tested when its rate
    # RMS is min_excitation_snr times each of these per-channel stds.
    rate_var = qd_noise**2 / 3.0
    eps2 = opts.model_tol**2 + (2 * np.pi * f_rms * LAG_RESOLUTION) ** 2 + roll**2
    model_ref = float(np.median(eps2 * rms**2)) if K else 0.0
    undetermined = excitation < np.maximum(
        max(opts.min_excitation, opts.min_excitation_snr * max(sigma_ref, np.sqrt(model_ref))),
        opts.min_excitation_snr * np.sqrt(rate_var),
    )
    n_eff = min(1.0, 2 * fc * step / f_imu)
    return _ErrorModel(sigma_b, rms, f_rms, roll, rate_var, n_eff, undetermined)


def _fit_at(data: _TimedGrid, err: _ErrorModel, lag: _Lag, lag_unc: float, opts: FastOptions) -> FastFit:
    """Step 4 and the tests of :func:`fast_fit` on the signals aligned at ``lag``, with the error
    model at the lag uncertainty ``lag_unc``."""
    shifted = data.grid - lag.at(data.grid)
    eps2 = opts.model_tol**2 + (2 * np.pi * err.f_rms * lag_unc) ** 2 + err.roll**2
    timed = _TimedTerms(
        apply=data.band,
        sigma=err.sigma,
        floor_add=eps2 * err.rms**2,
        rate_var=err.rate_var,
        n_eff=err.n_eff,
        undetermined=err.undetermined,
    )
    return _fit(data.q_s(shifted), data.qd_s(shifted), data.gyro_g, opts, timed)


def _refined_lag(
    fit: FastFit, data: _TimedGrid, err: _ErrorModel, lag: _Lag, n_seg: int, max_lag: float
) -> tuple[_Lag, float]:
    """Step 3, second pass: per segment, the shift that minimizes the accepted edge models' residual;
    a line through the segments' lags gives the lag and the drift, its scatter the uncertainty."""
    segs = np.array_split(np.arange(len(data.keep)), max(n_seg, 1))
    shift_step = 1.0e-3
    shifts, rss = _shift_window(fit, data, err, lag, segs, shift_step, max_lag)
    seg_lags = []
    for i, part in enumerate(segs):
        j = int(np.argmin(rss[:, i]))
        off = 0.0
        if 0 < j < len(shifts) - 1:
            r0, r1, r2 = rss[j - 1, i], rss[j, i], rss[j + 1, i]
            den = r0 - 2 * r1 + r2
            off = float(np.clip(0.5 * (r0 - r2) / den, -1, 1)) if den > 0 else 0.0
        ts = float(data.tk[part].mean())
        seg_lags.append((ts, float(lag.at(np.array([ts]))[0] + shifts[j] + off * shift_step)))
    xs, ys = np.array(seg_lags).T
    if len(xs) < 2:
        return _Lag(float(ys[0]), lag.drift, lag.t_mid), 2e-3
    drift, lag_mid = np.polyfit(xs - lag.t_mid, ys, 1)
    resid = ys - (lag_mid + drift * (xs - lag.t_mid))
    return _Lag(lag_mid, drift, lag.t_mid), max(LAG_RESOLUTION, float(np.sqrt(np.mean(resid**2))))


def _shift_window(
    fit: FastFit,
    data: _TimedGrid,
    err: _ErrorModel,
    lag: _Lag,
    segs: list[np.ndarray],
    shift_step: float,
    max_lag: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The shifts tried around ``lag`` and the edge models' residual per (shift, segment).

    ±4 ms around the lag in 1 ms steps, to be refined by a parabola: the residual is smooth in the
    shift (both sides band-limited to fc <= 10 Hz, whose period is >= 100 ms). The first lag can be
    more than these 4 ms off: while the whole fit's best shift sits on the edge of the window, the
    window moves there (at most ``max_lag`` away).
    """
    shifts = np.arange(-4.0e-3, 4.0e-3 + 1e-9, shift_step)
    base = data.grid - lag.at(data.grid)
    banded_gyro: dict[int, np.ndarray] = {}  # the gyro does not move with the shift: band it once

    def edge_rss(center: float) -> np.ndarray:
        return np.array(
            [
                _edge_rss(
                    fit,
                    err.sigma,
                    data.gyro_g,
                    data.q_s,
                    data.qd_s,
                    base - center - d,
                    data.band,
                    segs,
                    banded_gyro,
                )
                for d in shifts
            ]
        )

    center = 0.0
    rss = edge_rss(center)
    while True:
        j = int(np.argmin(rss.sum(axis=1)))
        if 0 < j < len(shifts) - 1 or abs(center + shifts[j]) > max_lag:
            break
        center += shifts[j]
        rss = edge_rss(center)
    return shifts + center, rss


def _fast_len_below(n: int) -> int:
    """The largest length <= ``n`` whose FFT is fast (a product of small primes)."""
    from scipy.fft import next_fast_len

    k = max(int(n), 1)
    while next_fast_len(k, real=True) != k:
        k -= 1
    return k


def _edge_rss(
    fit: FastFit,
    sigma: np.ndarray,
    gyro: np.ndarray,
    q_s: Callable[[np.ndarray], np.ndarray],
    qd_s: Callable[[np.ndarray], np.ndarray],
    at: np.ndarray,
    band: Callable[..., np.ndarray],
    segments: list[np.ndarray],
    banded_gyro: dict[int, np.ndarray],
) -> np.ndarray:
    """Residual sum of squares of the accepted edge models, per segment of the fit samples, with the
    encoder signals evaluated at the instants ``at``. ``banded_gyro`` caches the banded reference gyro
    columns across calls (filled here)."""
    q, qd = q_s(at), qd_s(at)
    c, s = np.cos(q), np.sin(q)
    out = np.zeros(len(segments))
    for g, h, js, _ in fit.edges:
        members = [np.flatnonzero(fit.group == x) for x in (g, h)]
        rg = members[0][np.argmin(sigma[members[0]])]
        wh = None if h < 0 else gyro[:, members[1][np.argmin(sigma[members[1]])]].T
        if len(js) == 1:
            j = js[0]
            F = _hop_features(wh, c[None, :, j], s[None, :, j], qd[None, :, j])
        else:
            a, b = js
            F = _two_hop_features(
                None if wh is None else wh[None], c[:, a], s[:, a], qd[:, a], c[:, b], s[:, b], qd[:, b]
            )
        Fb = band(F)
        if rg not in banded_gyro:
            banded_gyro[rg] = band(gyro[:, rg], axis=0)
        Yb = banded_gyro[rg]
        for i, part in enumerate(segments):
            Y = Yb[part] - Yb[part].mean(axis=0)
            out[i] += float(np.sum(Y * Y) - _explained(Fb[:, :, part], Y).sum())
    return out
