"""Fast topology estimator: which joints move each IMU, from exact linear gyro models (the physics
and the tests: :mod:`bodyschema.fast_core`).

One entry point, :func:`fast_fit` (a recording and a :class:`FastOptions`; :class:`FastEstimator` wraps
it), and two paths chosen by the data (:func:`fit_path`): positions without velocities measured by the
robot, whatever the file's form, go through the timed path (:mod:`bodyschema.fast_timed`: band-limited
derivative, lag estimate, error model); the synced path, sample by sample, only takes velocities the
robot measured.

Example
-------
>>> from dataclasses import replace
>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> T = 2000; t = np.arange(T) / 100
>>> q = np.stack([np.sin(0.9 * t), np.cos(0.6 * t + 1)], 1)
>>> qd = np.stack([0.9 * np.cos(0.9 * t), -0.6 * np.sin(0.6 * t + 1)], 1)  # measured by the robot
>>> w1 = np.stack([0 * t, 0 * t, qd[:, 0]], 1)                     # link 1 spins about z
>>> c, s = np.cos(q[:, 1]), np.sin(q[:, 1])                        # link 2: x-hinge on link 1
>>> w2 = np.stack([qd[:, 1], s * w1[:, 2], c * w1[:, 2]], 1)
>>> gyro = np.stack([w1, w2], 1) + rng.normal(scale=1e-3, size=(T, 2, 3))
>>> rec = Recording(t=t, joint_names=["a", "b"], q=q, qd=qd, imu_names=["i1", "i2"],
...                 acc=np.zeros((T, 2, 3)), gyro=gyro)
>>> fit = FastEstimator().fit(rec)
>>> fit.dependency_.astype(int).tolist(), fit.result_.path
([[1, 0], [1, 1]], 'synced')
>>> fast_fit(replace(rec, qd=None)).dependency.astype(int).tolist()  # positions only: the timed path
[[1, 0], [1, 1]]
"""

from __future__ import annotations

from typing import Any

from bodyschema.fast_core import (
    _FIELDS,
    PATH_SETTINGS,
    FastFit,
    FastOptions,
    _fit,
    fast_options,
    insufficient_excitation,
    noise_level,
)
from bodyschema.fast_timed import stated_filter, timed_fit
from bodyschema.recording import Recording

__all__ = [
    "PATH_SETTINGS",
    "FastEstimator",
    "FastFit",
    "FastOptions",
    "fast_fit",
    "fast_options",
    "fit_path",
    "insufficient_excitation",
    "noise_level",
]


# ----------------------------------------------------------------------------------- the estimator
class FastEstimator:
    """Per-IMU ancestor sets from gyro regression tests (the physics: :mod:`bodyschema.fast_core`).

    Settings: ``options`` (:class:`FastOptions`) with any of its fields given as a keyword replacing
    its value (``FastEstimator(fit_ratio=10.0)``); kept as ``options``, and each field reads as an
    attribute too. :meth:`fit` is :func:`fast_fit` on a recording.
    """

    def __init__(self, options: FastOptions | None = None, **overrides: Any):
        self.options = fast_options(options, **overrides)

    def __getattr__(self, name: str) -> Any:
        # only called for names not found otherwise: the settings read through to the options
        if name != "options" and name in _FIELDS:
            return getattr(self.options, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def fit(self, rec: Recording) -> FastEstimator:
        res = fast_fit(rec, self.options)
        self.result_ = res
        self.dependency_ = res.dependency
        self.group_ = res.group
        self.undetermined_ = res.undetermined
        self.imu_confidence_ = res.imu_confidence
        self.joint_confidence_ = res.joint_confidence
        self.excitation_ = res.excitation
        return self


def fit_path(rec: Recording) -> str:
    """Which path of the fast estimator ``rec`` takes: ``"synced"`` or ``"timed"``.

    ``"synced"`` only for a single-clock recording that carries velocities measured by the robot
    (``qd``; the simulator's ideal output is such data): the gyro is then compared with them sample by sample.
    Every other recording with positions is ``"timed"``: the velocity is derived from the positions, and a
    derived velocity is about 2 % off the true one at 100 Hz (docs/design.md, 'Science notes'), which only the
    timed path's band and error model allow for. A single-clock recording there is read as encoders sampled at
    the IMU stamps (``t_q = t``), with the skew between them still estimated. Note that
    :meth:`Recording.derived` fills ``qd``: derive after the fit, never before.
    """
    return "synced" if rec.t_q is None and rec.qd is not None else "timed"


def fast_fit(rec: Recording, options: FastOptions | None = None) -> FastFit:
    """The fast estimator on a recording: its one entry point (:class:`FastEstimator` wraps it).

    The path is the data's (:func:`fit_path`), not the caller's. A setting belongs to the path that
    uses it (:data:`PATH_SETTINGS`); one the path does not use is not applied, and when it was stated
    (off its default) :attr:`FastFit.unused` names it. On the timed path the IMU's on-chip filter, when
    the recording states it (``extra["sensing"]`` JSON with ``dlpf_cfg``, docs/recording-format.md),
    gives ``imu_bandwidth`` and ``imu_delay`` unless ``options`` states them.
    """
    if rec.q is None:
        raise ValueError("the fast estimator needs joint positions q")
    opts = options or FastOptions()
    path = fit_path(rec)
    if path == "synced":
        assert rec.qd is not None
        fit = _fit(rec.q, rec.qd, rec.gyro, opts)
    else:
        fit = timed_fit(rec.q, rec.gyro, rec.t, rec.encoder_t, stated_filter(rec, opts))
    fit.path = path
    default = FastOptions()
    fit.unused = tuple(
        f for f in sorted(_FIELDS - PATH_SETTINGS[path]) if getattr(opts, f) != getattr(default, f)
    )
    return fit
