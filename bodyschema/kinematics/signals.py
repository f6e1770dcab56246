"""The aligned, band-limited signals every kinematics fit reads, and the regressors built from them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bodyschema.alignment import one_clock
from bodyschema.kinematics.results import KinematicsOptions
from bodyschema.recording import Recording
from bodyschema.rigid_motion import skew
from bodyschema.timing import choose_band, edge_margin, lowpass, median_rate
from bodyschema.topology import Topology

__all__ = [
    "Signals",
    "kmats",
    "lever_basis",
    "prepare_signals",
    "stack_design",
]


@dataclass(frozen=True)
class Signals:
    """The aligned recording and what every fit needs: rate, band, decimation and the band filter."""

    rec: Recording
    rate: float
    band: float
    step: int
    trim: int
    lags: int
    fa: float

    def band_limit(self, x: np.ndarray) -> np.ndarray:
        """``x`` (T, ...) through the common band, decimated and trimmed at the edges."""
        flat = x.reshape(x.shape[0], -1)
        y = lowpass(flat, self.rate, self.band, step=self.step)
        y = y[self.trim : y.shape[0] - self.trim]
        return y.reshape((y.shape[0], *x.shape[1:]))

    def derivative(self, x: np.ndarray) -> np.ndarray:
        """Band-limited time derivative at the aligned rate (wide band: the common band comes later)."""
        return lowpass(x.reshape(x.shape[0], -1), self.rate, self.fa, derivative=True).reshape(x.shape)


def prepare_signals(rec: Recording, topo: Topology, opts: KinematicsOptions) -> Signals:
    al = one_clock(rec, topo)
    if al.q is None or al.n_samples < 64:
        raise ValueError("too little data for kinematics (needs encoder positions and 64 samples)")
    rate = median_rate(al.t)
    if opts.band_hz is not None:
        band = float(opts.band_hz)
    elif rec.t_q is not None:
        band = choose_band(median_rate(rec.t), median_rate(rec.t_q), opts.imu_bandwidth_hz)
    else:
        band = choose_band(rate, rate, None)
    step = max(1, int(rate // (2.5 * band)))
    trim = math.ceil(edge_margin(band) * rate / step)
    lags = max(1, math.ceil(2.0 * rate / step / band))
    fa = min(0.4 * rate, 4.0 * band)
    if al.n_samples // step <= 2 * trim + 16:
        raise ValueError("too little data for kinematics in the chosen band")
    return Signals(rec=al, rate=rate, band=band, step=step, trim=trim, lags=lags, fa=fa)


def kmats(sig: Signals, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangential ``[α]×`` and centripetal ``[ω]×[ω]×`` parts of ``K`` (each (T, 3, 3)) of a rebuilt
    angular velocity; they are fitted with separate lever arms (module docstring)."""
    w = skew(omega)
    return skew(sig.derivative(omega)), w @ w


def stack_design(rows: np.ndarray, shared: list[np.ndarray]) -> np.ndarray:
    """Design (n, 3, p): ``rows`` (n, w) repeated as a block per accelerometer axis, then shared columns."""
    n, w = rows.shape
    X = np.zeros((n, 3, 3 * w + sum(s.shape[2] for s in shared)))
    for i in range(3):
        X[:, i, i * w : (i + 1) * w] = rows
    col = 3 * w
    for s in shared:
        X[:, :, col : col + s.shape[2]] = s
        col += s.shape[2]
    return X


def lever_basis(sig: Signals, kc: tuple[np.ndarray, np.ndarray], U: np.ndarray) -> np.ndarray:
    """The band-limited tangential and centripetal regressors (T, 3, 4) of a lever arm in the plane ``U``."""
    return np.concatenate([sig.band_limit(kc[0] @ U), sig.band_limit(kc[1] @ U)], axis=2)
