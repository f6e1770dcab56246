"""How a joint's child link turns against its parent link, over a window and over its last still stretch.

:func:`relative_motion` is what :func:`bodyschema.health.signal_health` judges a joint by; the rest
judges the stretch since the encoder last moved on its own (a window that straddles a change hides it).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from bodyschema.hinge import hinge_design
from bodyschema.lstsq import scaled_lstsq
from bodyschema.recording import Recording
from bodyschema.topology import Topology

__all__ = ["StillLimits", "on_imu_clock", "relative_motion", "still_lately", "still_since"]


class StillLimits(Protocol):
    """The limits the still-stretch judgement reads (:class:`bodyschema.health.HealthThresholds`)."""

    still_rad: float
    still_seconds: float
    stop_margin_s: float
    lock_seconds: float
    motion_rad_s: float
    min_samples: int
    max_pairs: int


def _lstsq_residual(X: np.ndarray, Y: np.ndarray) -> float:
    """Sum of squared residuals of the least-squares fit Y ≈ X B (a frozen encoder makes columns
    collinear: :func:`bodyschema.lstsq.scaled_lstsq` takes the minimum-norm solution)."""
    fit = scaled_lstsq(X, Y)
    res = Y - fit.Xs @ fit.beta
    return float(np.sum(res**2))


def relative_motion(
    child_gyro: np.ndarray, parent_gyro: np.ndarray | None, q: np.ndarray, qd: np.ndarray
) -> tuple[float, float]:
    """RMS rate of the child link against its parent, and the fraction of it the encoder explains.

    ``child_gyro``/``parent_gyro`` are ``(T,3)`` gyro series of IMUs on the joint's child and parent
    links (``parent_gyro`` None = the parent link is fixed: the world base); ``q``/``qd`` the joint's
    ``(T,)`` encoder position and velocity. Returns ``(rms, explained)``; ``explained`` is 1 when the
    encoder accounts for all relative motion and 0 when it accounts for none.

    >>> import numpy as np
    >>> t = np.linspace(0, 10, 1000); q = np.sin(t); qd = np.cos(t)
    >>> child = np.c_[np.zeros(1000), np.zeros(1000), qd]
    >>> rms, explained = relative_motion(child, None, q, qd)
    >>> round(rms, 2), round(explained, 3)
    (0.72, 1.0)
    >>> relative_motion(child, None, np.zeros(1000), np.zeros(1000))[1] < 0.01
    True
    """
    T = child_gyro.shape[0]
    ones = np.ones((T, 1))
    if parent_gyro is None:
        rigid = ones
    else:
        rigid = np.c_[parent_gyro, ones]
    full = hinge_design(parent_gyro, q, qd)
    ss_rigid = _lstsq_residual(rigid, child_gyro)
    ss_full = _lstsq_residual(full, child_gyro)
    rms = float(np.sqrt(ss_rigid / T))
    explained = 0.0 if ss_rigid <= 1e-18 else float(np.clip(1.0 - ss_full / ss_rigid, 0.0, 1.0))
    return rms, explained


def still_since(rec: Recording, th: StillLimits) -> np.ndarray:
    """Per joint, the time since which its encoder stays within ``still_rad`` of its last reading
    (the encoder's own stamps, before any alignment: a band-limited resampling would smear the edge).
    ``inf`` when it moved at the very end."""
    assert rec.q is not None
    t = rec.t_q if rec.t_q is not None else rec.t
    out = np.full(rec.n_joints, np.inf)
    for k in range(rec.n_joints):
        moved = np.flatnonzero(np.abs(rec.q[:, k] - rec.q[-1, k]) > th.still_rad)
        first = 0 if moved.size == 0 else int(moved[-1]) + 1
        if first < len(t):
            out[k] = float(t[first])
    return out


def on_imu_clock(times: np.ndarray, rec: Recording, current: Topology | None) -> np.ndarray:
    """Encoder-clock ``times`` on the IMU's clock, as :func:`bodyschema.alignment.one_clock` maps the
    encoder stream: the IMU reports what the encoders saw at ``t`` at ``t + lag + drift (t - at)``."""
    if rec.t_q is None or current is None:
        return times
    timing = current.timing or {}
    lag = float(timing.get("lag_ms", 0.0)) * 1e-3
    drift = float(timing.get("drift_ppm", 0.0)) * 1e-6
    return times + lag + drift * (times - float(timing.get("at_s", 0.0)))


def still_lately(
    rec: Recording,
    d: Recording,
    k: int,
    since: float,
    child: list[str],
    refs: list[np.ndarray | None],
    present: dict[str, int],
    th: StillLimits,
) -> tuple[str, float, float, float | None] | None:
    """Judge joint ``k`` on its encoder's trailing still stretch (from ``since``, on the IMU's clock,
    plus ``stop_margin_s``): ``(state,
    excitation, relative motion, explained)`` when that stretch decides, else None.

    A window that straddles a change is a mix of the body before and after it, and over the whole
    window the change hides: a frozen encoder still explains much of its link's motion, and the
    estimator, seeing the IMUs below follow the joint only part of the time, loses their dependency,
    which reads as a lost link; a seized joint still shows most of the window's excitation. The
    stretch since the encoder last moved is all after such a change, so it is judged on its own:

    * every child IMU turns against the parent link (``motion_rad_s``) while the encoder stays within
      ``still_rad`` for ``still_seconds``: a physical contradiction (see :class:`HealthThresholds`),
      ``frozen_encoder``, however the rest of the window looks;
    * every child IMU stays rigid with the parent link and the stretch lasts ``lock_seconds``: the
      joint does not move now, ``still`` (the diff calls it locked only if others move and it moved
      on the baseline). ``lock_seconds`` is a policy, how long a joint that moved on the baseline
      may rest before it counts as locked; without it a whole window has to pass.

    Anything in between (some IMUs turn, some do not: a moved or loose IMU on the link) is left to the
    whole-window judgement.
    """
    since = since + th.stop_margin_s  # the IMU's view of the stop settles (HealthThresholds)
    stretch = float(d.t[-1]) - since
    if not np.isfinite(since) or stretch < th.still_seconds:
        return None
    seg = np.flatnonzero(d.t >= since)
    if seg.size < th.min_samples:
        return None
    assert d.q is not None and d.qd is not None
    q, qd = d.q[seg, k], d.qd[seg, k]
    rates = [
        min(
            relative_motion(rec.gyro[seg, present[c], :], None if pg is None else pg[seg], q, qd)[0]
            for pg in refs
        )
        for c in child[: th.max_pairs]
    ]
    if not rates:
        return None
    excitation = float(np.sqrt(np.mean(qd**2)))
    if min(rates) > th.motion_rad_s:
        return "frozen_encoder", excitation, min(rates), 0.0
    if max(rates) <= th.motion_rad_s and stretch >= th.lock_seconds:
        return "still", excitation, max(rates), None
    return None
