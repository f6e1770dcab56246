"""Whether the two predictions of a floating base's IMU (encoders, motion capture) tell one story.

Each prediction gives the IMU's time offset and mount rotation in its own final model
(:func:`agreement`). The two can agree on the offset only when the encoders and the motion capture
were stamped on one clock, and on the mount only when the motion capture's body frame is the URDF's.
So the predictions are also compared with each other, without the IMU: the lag
(:func:`prediction_lag`) and the rotation (:func:`prediction_rotation`) that best align their base
angular velocities. The IMU's two estimates close over them (:func:`closure`) when their
difference equals what lies between the predictions, within the errors; a disagreement is then the
recording's clocks or frames, not a model's error.

>>> import numpy as np
>>> t = np.arange(0, 40, 0.01); w = np.c_[np.sin(3 * t), np.cos(2 * t), np.sin(t)]
>>> late = np.c_[np.sin(3 * (t - 0.004)), np.cos(2 * (t - 0.004)), np.sin(t - 0.004)]
>>> lag = prediction_lag(t, late, w, np.ones(t.size, bool))
>>> round(lag["estimate"][0] * 1e3, 2)
4.0
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation
from scipy.stats import norm
from scipy.stats import t as t_dist

__all__ = ["MAX_LAG_S", "agreement", "closure", "prediction_lag", "prediction_rotation"]

#: Lags searched between two predictions, s (a clock more than this apart is not one recording's).
MAX_LAG_S = 0.05


def _best_lag(t: np.ndarray, a: np.ndarray, b: np.ndarray, use: np.ndarray) -> float:
    """The ``tau`` that minimises the squared difference of ``a(t)`` and ``b(t - tau)`` on ``use``."""

    def sse(tau: float) -> float:
        shifted = np.stack([np.interp(t - tau, t, b[:, i]) for i in range(b.shape[1])], axis=1)
        return float(np.sum((a[use] - shifted[use]) ** 2))

    grid = np.linspace(-MAX_LAG_S, MAX_LAG_S, 41)  # 2.5 ms apart: the bracket for the fine search
    k = int(np.argmin([sse(x) for x in grid]))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    return float(minimize_scalar(sse, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5}).x)


def _blocks(t: np.ndarray, n_blocks: int) -> np.ndarray:
    return np.minimum((n_blocks * (t - t[0]) / (t[-1] - t[0])).astype(int), n_blocks - 1)


def _jackknife(fit, use: np.ndarray, block: np.ndarray, n_blocks: int, unit: str) -> dict[str, object]:
    """``fit(mask)`` (k,) on all of ``use``, its leave-one-block-out standard error and a 95 %
    interval (t with ``n_blocks - 1`` degrees of freedom: samples within a block are not
    independent)."""
    est = np.atleast_1d(fit(use))
    jack = np.array([np.atleast_1d(fit(use & (block != g))) for g in range(n_blocks)])
    se = np.sqrt((n_blocks - 1) / n_blocks * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
    q = float(t_dist.ppf(0.975, n_blocks - 1))
    return {
        "estimate": est.tolist(),
        "stderr": se.tolist(),
        "interval": np.c_[est - q * se, est + q * se].tolist(),
        "unit": unit,
    }


def prediction_lag(
    t: np.ndarray, a: np.ndarray, b: np.ndarray, valid: np.ndarray, n_blocks: int = 8
) -> dict[str, object]:
    """How late ``a`` (T, 3) runs against ``b`` (T, 3) on the grid ``t`` (``a(t) = b(t - tau)``), s."""
    use = np.asarray(valid, bool)
    return _jackknife(lambda m: _best_lag(t, a, b, m), use, _blocks(t, n_blocks), n_blocks, "s")


def prediction_rotation(
    t: np.ndarray, a: np.ndarray, b: np.ndarray, valid: np.ndarray, n_blocks: int = 8
) -> dict[str, object]:
    """The rotation (rotation vector, rad) that carries ``b`` (T, 3) onto ``a`` (T, 3) in least
    squares (``a = R b``; Kabsch, through scipy's ``align_vectors``)."""
    use = np.asarray(valid, bool)

    def fit(m: np.ndarray) -> np.ndarray:
        return Rotation.align_vectors(a[m], b[m])[0].as_rotvec()

    return _jackknife(fit, use, _blocks(t, n_blocks), n_blocks, "rad")


def agreement(reports: dict[str, dict[str, object]]) -> dict[str, object]:
    """Whether the encoder and mocap predictions agree on the time offset and the mount rotation:
    each prediction's estimate in its final model (named or not; both channels) with a 95 %
    interval from its block-robust standard error; they agree when the intervals overlap on every
    axis."""
    if not {"encoders", "mocap"} <= set(reports):
        return {}
    out: dict[str, object] = {}
    for effect in ("time_offset", "mounting_rotation"):
        got = {}
        for name, rep in reports.items():
            ev = next((e for e in rep["evidence"] if e["effect"] == effect and e["channel"] == "both"), None)
            if ev is None:
                continue
            q = float(t_dist.ppf(0.975, max(int(ev["clusters"]) - 1, 1)))
            est, se = np.asarray(ev["estimate"], float), np.asarray(ev["stderr"], float)
            named = any(c["effect"] == effect for c in rep["causes"])
            got[name] = {
                "estimate": est.tolist(),
                "stderr": se.tolist(),
                "interval": np.c_[est - q * se, est + q * se].tolist(),
                "named": named,
            }
        if len(got) == 2:
            a, b = got["encoders"]["interval"], got["mocap"]["interval"]
            agree = all(max(x[0], y[0]) <= min(x[1], y[1]) for x, y in zip(a, b, strict=True))
            out[effect] = {"agree": bool(agree), **got}
    return out


def closure(got: dict[str, object], between: dict[str, object], sign: int) -> dict[str, object]:
    """Do the IMU's estimates against the encoders and the mocap (an ``agreement(...)`` entry) differ
    by what lies between the two predictions (``between``: the encoders' against the mocap's)?

    * time: the IMU reads ``enc(t - o_enc)`` and ``mocap(t - o_moc)``, so ``enc(t) = mocap(t - (o_moc
      - o_enc))``: the lag is the offsets' difference with ``sign = -1``;
    * mount: the IMU reads ``R(r_p)^T w_p`` of either, so ``w_enc = R(r_enc - r_moc) w_moc`` to first
      order: ``sign = +1``.

    Closes when every axis's gap is within 1.96 of its standard error (the three errors taken as
    independent)."""
    enc, moc = (np.asarray(got[k]["estimate"], float) for k in ("encoders", "mocap"))
    se = np.sqrt(
        np.asarray(got["encoders"]["stderr"]) ** 2
        + np.asarray(got["mocap"]["stderr"]) ** 2
        + np.asarray(between["stderr"]) ** 2
    )
    expected = sign * (enc - moc)
    gap = np.asarray(between["estimate"], float) - expected
    return {
        "between_predictions": between,
        "expected": expected.tolist(),
        "gap": gap.tolist(),
        "gap_stderr": se.tolist(),
        "closes": bool(np.all(np.abs(gap) <= float(norm.ppf(0.975)) * se)),
    }
