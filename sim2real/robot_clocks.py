"""Whether the two predictions of a floating base's IMU (encoders, motion capture) tell one story.

Each prediction gives the IMU's time offset and mount rotation in its own final model
(:func:`agreement`). The two can only agree on the offset when the encoders and the motion capture
were stamped on one clock. So the predictions are also compared with each other, without the IMU
(:func:`prediction_lag`): the lag that best aligns their base angular velocities. The three clocks
close when the offsets' difference equals that lag within their errors; then a disagreement of the
offsets is the recording's two clocks, not a model's error.

>>> import numpy as np
>>> t = np.arange(0, 40, 0.01); w = np.c_[np.sin(3 * t), np.cos(2 * t), np.sin(t)]
>>> late = np.c_[np.sin(3 * (t - 0.004)), np.cos(2 * (t - 0.004)), np.sin(t - 0.004)]
>>> lag = prediction_lag(t, late, w, np.ones(t.size, bool))
>>> round(lag["estimate_s"] * 1e3, 2)
4.0
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import norm
from scipy.stats import t as t_dist

__all__ = ["MAX_LAG_S", "agreement", "clock_closure", "prediction_lag"]

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


def prediction_lag(
    t: np.ndarray, a: np.ndarray, b: np.ndarray, valid: np.ndarray, n_blocks: int = 8
) -> dict[str, object]:
    """How late ``a`` (T, 3) runs against ``b`` (T, 3) on the grid ``t`` (``a(t) = b(t - tau)``), with
    a 95 % interval from a leave-one-block-out jackknife over ``n_blocks`` contiguous time blocks
    (samples within a block are not independent)."""
    use = np.asarray(valid, bool).copy()
    block = np.minimum((n_blocks * (t - t[0]) / (t[-1] - t[0])).astype(int), n_blocks - 1)
    tau = _best_lag(t, a, b, use)
    jack = np.array([_best_lag(t, a, b, use & (block != g)) for g in range(n_blocks)])
    se = float(np.sqrt((n_blocks - 1) / n_blocks * np.sum((jack - jack.mean()) ** 2)))
    q = float(t_dist.ppf(0.975, n_blocks - 1))
    return {"estimate_s": tau, "stderr_s": se, "interval_s": [tau - q * se, tau + q * se]}


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


def clock_closure(offsets: dict[str, object], lag: dict[str, object]) -> dict[str, object]:
    """Do the IMU's offsets against the encoders and the mocap (``agreement(...)["time_offset"]``)
    differ by the lag between the two predictions (encoders against mocap, :func:`prediction_lag`)?
    The IMU reads ``enc(t - o_enc)`` and ``mocap(t - o_moc)``, so ``enc(t) = mocap(t - (o_moc -
    o_enc))``: the lag should be ``o_moc - o_enc``. Closes when the gap is within 1.96 of its
    standard error (the three errors taken as independent)."""
    o_enc = float(offsets["encoders"]["estimate"][0])
    o_moc = float(offsets["mocap"]["estimate"][0])
    se = np.sqrt(
        offsets["encoders"]["stderr"][0] ** 2 + offsets["mocap"]["stderr"][0] ** 2 + lag["stderr_s"] ** 2
    )
    gap = float(lag["estimate_s"]) - (o_moc - o_enc)
    return {
        "encoders_against_mocap_s": lag,
        "offsets_difference_s": o_moc - o_enc,
        "gap_s": gap,
        "gap_stderr_s": float(se),
        "closes": bool(abs(gap) <= float(norm.ppf(0.975)) * se),
    }
