"""Encoders and IMUs on one clock: the stream every joint check compares (pure).

The estimators report the IMU's lag behind the encoders (and the drift between their clocks) in a
topology's ``timing``; the health checks and the kinematics read both streams on the IMU's samples
with that lag taken out, so that a gyro and an encoder velocity are compared at the same instant.
"""

from __future__ import annotations

from bodyschema.recording import Recording
from bodyschema.timing import aligned_recording, timed_view
from bodyschema.topology import Topology

__all__ = ["one_clock"]


def one_clock(rec: Recording, current: Topology | None = None) -> Recording:
    """``rec`` with encoders and IMUs on one clock, velocities derived (what the joint checks compare).

    A single-clock ``rec`` comes back derived. A multi-rate one is aligned with
    :func:`bodyschema.timing.aligned_recording` using the lag, drift and reference time the estimator
    reported in ``current.timing`` (none: no lag); when the streams overlap too little for that, the
    encoder positions are interpolated at the IMU stamps (:meth:`Recording.synced`).
    """
    rec = timed_view(rec)  # positions only, on one clock: aligned like two clocks (t_q = t)
    if rec.t_q is None:
        return rec.derived()
    timing = current.timing if current is not None else {}
    try:
        return aligned_recording(
            rec,
            lag=float(timing.get("lag_ms", 0.0)) * 1e-3,
            drift=float(timing.get("drift_ppm", 0.0)) * 1e-6,
            lag_time=float(timing.get("at_s", 0.0)),
        )
    except ValueError:
        return rec.synced().derived()
