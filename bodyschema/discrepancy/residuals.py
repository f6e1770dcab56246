"""Residual analysis: the structure of measured-minus-predicted, per axis, and the sensor noise.

A residual that is only noise has no structure. One with structure carries its cause in its shape:
what it correlates with says which effect is missing. :func:`residual_structure` measures, per axis,
how much of the residual each family of regressors explains (R², in-sample — it is descriptive; the
selection procedure judges effects on held-out data): time (drift), angular rate, the derivative of
the reading, rate products (centripetal terms), orientation (the direction of gravity in the sensor
frame), and the reading itself; plus where the residual's energy lies in frequency.

:func:`noise_std` measures the white noise of a sensor from the band above the motion, where only
noise lives, and scales it to the full band.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> x = rng.normal(0.0, 0.02, size=(20000, 3))
>>> np.round(noise_std(x, 200.0), 2).tolist()
[0.02, 0.02, 0.02]
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfreqz, welch

from bodyschema.rigid_motion import ReferenceMotion, lowpass

__all__ = ["FEATURE_FAMILIES", "explained_fraction", "noise_std", "residual_structure"]

#: The regressor families of :func:`residual_structure`, with what each points to.
FEATURE_FAMILIES: dict[str, str] = {
    "constant": "bias",
    "trend": "drift (bias changing over time, e.g. temperature)",
    "rate": "gyro scale / misalignment (gyro), mounting rotation",
    "derivative": "time offset (residual follows the derivative of the reading)",
    "rate_products": "lever arm (centripetal terms w_i w_j)",
    "orientation": "gravity vector or mounting rotation (residual turns with the body)",
    "reading": "scale factor (residual proportional to the reading on the same axis)",
}


def noise_std(x: np.ndarray, rate: float, index: np.ndarray | None = None, band: float = 0.25) -> np.ndarray:
    """White-noise std per axis (unit of ``x``) from the band above ``band * rate`` Hz.

    The residual of the zero-phase low-pass (:func:`~bodyschema.rigid_motion.lowpass`) passes white
    noise with power gain ``(1 - |H|²)²``; dividing by its mean over the band gives the full-band
    std (the convention of :func:`bodyschema.imu_effects.white_noise`: ``std = density *
    sqrt(rate)``). Motion must lie well below ``band * rate``.
    """
    a = np.asarray(x, dtype=np.float64)
    if not 0 < band < 0.5:
        raise ValueError("band must lie in (0, 0.5)")
    hp = a - lowpass(a, rate, band * rate)
    sel = hp if index is None else hp[index]
    _, h = sosfreqz(butter(4, band * rate, fs=rate, output="sos"), worN=4096, fs=rate)
    passed = float(np.mean((1.0 - np.abs(h) ** 2) ** 2))
    return np.sqrt(np.mean(sel**2, axis=0) / passed)


def explained_fraction(y: np.ndarray, X: np.ndarray) -> float:
    """R² of the least-squares fit of ``y`` (n,) on the columns of ``X`` (n, p), no intercept added.

    >>> x = np.linspace(0, 1, 50)
    >>> round(explained_fraction(3 * x, x[:, None]), 6)
    1.0
    """
    ss = float(np.sum(y**2))
    if ss <= 0 or X.shape[1] == 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(max(0.0, 1.0 - np.sum((y - X @ coef) ** 2) / ss))


def _families(ref: ReferenceMotion, reading: np.ndarray) -> dict[str, np.ndarray]:
    """Regressor columns per family, each (T, p), for one channel whose reading is ``reading``."""
    T = ref.t.shape[0]
    w = ref.omega
    tc = (ref.t - ref.t.mean())[:, None]
    g = float(np.linalg.norm(ref.gravity))
    if g > 0:
        up = -np.einsum("tji,j->ti", ref.R, ref.gravity / g)
    else:  # a gravity-free reference: any world-fixed direction, i.e. every world axis in the sensor frame
        up = ref.R.reshape(T, 9)
    prods = np.stack([w[:, i] * w[:, j] for i in range(3) for j in range(i, 3)], axis=1)
    deriv = np.gradient(reading, ref.t, axis=0)
    return {
        "constant": np.ones((T, 1)),
        "trend": tc,
        "rate": w,
        "derivative": deriv,
        "rate_products": prods,
        "orientation": up,
        "reading": reading,
    }


def residual_structure(
    ref: ReferenceMotion,
    resid: np.ndarray,
    predicted: np.ndarray,
    index: np.ndarray,
    rate: float,
) -> dict[str, dict[str, object]]:
    """Per channel and axis: RMS, mean, R² of each feature family, and the residual's spectrum.

    ``resid`` and ``predicted`` are (T, 6), gyro xyz then acc xyz, on ``ref``'s time grid; only the
    samples ``index`` count. Returns ``{"gyro": {...}, "acc": {...}}`` with lists per axis.
    """
    out: dict[str, dict[str, object]] = {}
    for c, name in enumerate(("gyro", "acc")):
        cols = slice(3 * c, 3 * c + 3)
        r = resid[index][:, cols]
        fam = {k: v[index] for k, v in _families(ref, predicted[:, cols]).items()}
        r2: dict[str, list[float]] = {k: [] for k in fam}
        for ax in range(3):
            for k, X in fam.items():
                if k in ("reading", "derivative"):
                    X = X[:, ax : ax + 1]
                r2[k].append(round(explained_fraction(r[:, ax], X), 4))
        nper = min(1024, r.shape[0])
        f, pxx = welch(r, fs=rate, nperseg=nper, axis=0)
        total = np.sum(pxx, axis=0) + 1e-300
        bands = {"below_1hz": f < 1.0, "1_to_5hz": (f >= 1.0) & (f < 5.0), "above_5hz": f >= 5.0}
        out[name] = {
            "rms": [float(x) for x in np.sqrt(np.mean(r**2, axis=0))],
            "mean": [float(x) for x in np.mean(r, axis=0)],
            "r2": r2,
            "peak_hz": [float(f[np.argmax(pxx[:, ax])]) for ax in range(3)],
            "energy": {k: [float(x) for x in np.sum(pxx[m], axis=0) / total] for k, m in bands.items()},
        }
    return out
