"""Samples around encoder impacts, which a gyro-on-encoder regression must not read (pure).

A joint that hits a stop or a contact changes its velocity within one sample; a central difference
then reports a velocity the gyros never saw.
"""

from __future__ import annotations

import numpy as np

from bodyschema.recording import Recording

__all__ = ["drop_impacts"]


def drop_impacts(rec: Recording, factor: float = 24.0) -> Recording:
    """``rec`` with velocities derived, minus the samples around encoder impacts.

    Where a joint hits a stop or a contact its velocity jumps within one sample; the central
    difference then reports a velocity the gyros never saw, and a method that regresses gyros on
    encoder velocities reads those few samples as a contradiction. A sample (and its neighbours) is
    dropped when any joint's acceleration exceeds ``factor`` × that joint's median absolute
    acceleration. ``qd``/``qdd`` are derived on the full window first, so the kept samples carry the
    right values. Returns ``rec`` itself (derived) when nothing is dropped.

    A multi-rate ``rec`` comes back as it is: its estimators band-limit the encoder positions
    themselves, and a central-difference acceleration of quantized positions would mark noise.

    >>> import numpy as np
    >>> from bodyschema.recording import Recording
    >>> t = np.arange(400) * 0.01
    >>> q = np.sin(t)[:, None]; q[200:] += 0.5          # a jump: an impact
    >>> rec = Recording(t=t, joint_names=("j",), q=q, imu_names=(), acc=np.zeros((400, 0, 3)),
    ...                 gyro=np.zeros((400, 0, 3)))
    >>> drop_impacts(rec).n_samples < 400, drop_impacts(rec).qd is not None
    (True, True)
    """
    if rec.t_q is not None:
        return rec
    d = rec.derived()
    if d.qdd is None or d.n_samples < 5:
        return d
    a = np.abs(d.qdd)
    med = np.median(a, axis=0)
    scale = np.where(med > 1e-9, med, np.inf)
    bad = np.any(a > factor * scale, axis=1)
    if not bad.any():
        return d
    bad = bad | np.roll(bad, 1) | np.roll(bad, -1)
    return d.select(~bad)
