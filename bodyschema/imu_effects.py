"""Forward models of the IMU error effects: one piece of code for the simulator and for sim-to-real.

The simulator composes these functions to turn MuJoCo's ideal sensor readings into what a real IMU
would report (:mod:`simulators.imu_model`); the discrepancy analysis fits the same functions to
measured data. Keeping one implementation means a fitted ``time_offset`` or ``lever_arm`` means the
same thing in both directions.

Conventions (all functions are pure numpy, no I/O; the only randomness is an injected Generator):

* signals are ``(T, 3)`` or ``(T, K, 3)``: time first, sensor-frame axis last, ``K`` IMUs between;
* ``t`` is ``(T,)`` seconds, strictly increasing;
* per-IMU parameters carry a leading ``K`` axis (``(K, 3)`` vectors, ``(K, 3, 3)`` matrices) and
  broadcast against ``(T, K, 3)`` signals;
* a rotation ``R_world_sensor`` maps sensor-frame coordinates to world coordinates
  (``v_world = R @ v_sensor``).

Effect names used in the IMU model JSON and in the discrepancy JSON (docs/design.md, 'Discrepancy JSON') map
onto these functions: ``time_offset`` -> :func:`time_shift`, ``gyro_bias``/``acc_bias``/``gyro_scale``/
``acc_scale`` -> :func:`affine`, ``mounting_rotation`` -> :func:`rotate`, ``lever_arm`` -> :func:`lever_arm`
(with :func:`angular_acceleration`), ``gravity`` -> :func:`specific_force`, ``noise`` -> :func:`white_noise`,
plus :func:`quantize` and :func:`resample`.

Example
-------
>>> import numpy as np
>>> t = np.arange(5) * 0.01
>>> x = np.stack([t, 2 * t, 3 * t], axis=1)
>>> np.round(time_shift(t, x, 0.01)[:, 0], 3).tolist()   # the sensor lags by one sample
[0.0, 0.0, 0.01, 0.02, 0.03]
>>> affine(np.ones((1, 3)), matrix=[1.0, 2.0, 3.0], bias=[0.0, 0.0, 1.0]).tolist()
[[1.0, 2.0, 4.0]]
>>> np.round(rotate(np.array([[1.0, 0.0, 0.0]]), [0.0, 0.0, np.pi / 2]), 6).tolist()
[[0.0, -1.0, 0.0]]
>>> specific_force(np.eye(3)[None], np.zeros((1, 3)), np.array([0.0, 0.0, -9.81])).tolist()
[[0.0, 0.0, 9.81]]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

__all__ = [
    "affine",
    "angular_acceleration",
    "cross_axis_matrix",
    "lever_arm",
    "quantize",
    "resample",
    "rotate",
    "rotation_matrix",
    "specific_force",
    "time_shift",
    "white_noise",
]


def _signal(x: ArrayLike) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(f"a signal must have shape (T, 3) or (T, K, 3), got {a.shape}")
    return a


def _times(t: ArrayLike, n: int) -> np.ndarray:
    tt = np.asarray(t, dtype=np.float64)
    if tt.ndim != 1 or tt.shape[0] != n:
        raise ValueError(f"t must have shape ({n},), got {tt.shape}")
    if n > 1 and not np.all(np.diff(tt) > 0):
        raise ValueError("t must be strictly increasing")
    return tt


def _interp_rows(t: np.ndarray, x: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``x`` (T, ...) linearly interpolated along time at times ``at``, edge-held outside ``t``.

    Interpolates the sample *index* once and blends neighbouring rows, so every trailing channel is
    handled in one vectorised step (``np.interp`` alone works on 1-D data only).
    """
    if t.shape[0] == 1:
        return np.repeat(x[:1], at.shape[0], axis=0)
    idx = np.interp(at, t, np.arange(t.shape[0], dtype=np.float64))
    lo = np.minimum(np.floor(idx).astype(np.intp), t.shape[0] - 2)
    frac = (idx - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    return x[lo] * (1.0 - frac) + x[lo + 1] * frac


def time_shift(t: ArrayLike, x: ArrayLike, seconds: float) -> np.ndarray:
    """``y(t) = x(t - seconds)`` by linear interpolation, edge-held at both ends.

    Positive ``seconds`` means the IMU samples lag the reference (what happens at time t is reported
    ``seconds`` later).

    >>> t = np.arange(4) * 0.1
    >>> x = np.repeat(t[:, None], 3, axis=1)
    >>> np.round(time_shift(t, x, -0.05)[:, 0], 3).tolist()
    [0.05, 0.15, 0.25, 0.3]
    """
    xs = _signal(x)
    tt = _times(t, xs.shape[0])
    if seconds == 0.0:
        return xs.copy()
    return _interp_rows(tt, xs, tt - float(seconds))


def _apply_matrix(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    if m.ndim == 1:
        if m.shape != (3,):
            raise ValueError(f"a diagonal scale must have shape (3,), got {m.shape}")
        return x * m
    if m.ndim == 2:
        if m.shape == (3, 3):
            return x @ m.T
        if m.shape[1] == 3 and x.ndim == 3 and m.shape[0] == x.shape[1]:
            return x * m  # per-IMU diagonal (K, 3)
        raise ValueError(f"matrix must be (3,), (3, 3), (K, 3) or (K, 3, 3), got {m.shape}")
    if m.ndim == 3 and m.shape[1:] == (3, 3) and x.ndim == 3 and m.shape[0] == x.shape[1]:
        # y[t, k] = m[k] @ x[t, k] as one batched matmul over IMUs (fastest numpy form for 3x3s)
        return np.matmul(x.transpose(1, 0, 2), m.transpose(0, 2, 1)).transpose(1, 0, 2)
    raise ValueError(f"matrix {m.shape} does not fit a signal of shape {x.shape}")


def affine(x: ArrayLike, matrix: ArrayLike | None = None, bias: ArrayLike | None = None) -> np.ndarray:
    """``y = x @ M.T + b``: scale factor, cross-axis coupling and bias of one sensor triad.

    ``matrix`` is a (3, 3) matrix (diagonal ``1 + s`` for a scale error ``s``, off-diagonal terms for
    cross-axis sensitivity) or a (3,) vector holding that diagonal (a gain, 1 = ideal). For ``(T, K, 3)``
    signals a per-IMU ``(K, 3, 3)`` matrix or ``(K, 3)`` diagonal is accepted (with K == 3 a (3, 3)
    array is read as one shared matrix). ``bias`` is (3,) or per-IMU (K, 3).

    >>> affine(np.array([[1.0, 1.0, 1.0]]), matrix=np.eye(3) * 2, bias=[0.5, 0.0, 0.0]).tolist()
    [[2.5, 2.0, 2.0]]
    """
    y = _signal(x)
    if matrix is not None:
        y = _apply_matrix(y, np.asarray(matrix, dtype=np.float64))
    else:
        y = y.copy()
    if bias is not None:
        y = y + np.asarray(bias, dtype=np.float64)
    return y


def rotation_matrix(rotvec: ArrayLike) -> np.ndarray:
    """Rotation matrix (3, 3) or (K, 3, 3) of a rotation vector (axis * angle, rad)."""
    rv = np.asarray(rotvec, dtype=np.float64)
    if rv.shape[-1] != 3 or rv.ndim > 2:
        raise ValueError(f"rotvec must have shape (3,) or (K, 3), got {rv.shape}")
    return Rotation.from_rotvec(rv).as_matrix()


def rotate(x: ArrayLike, rotvec: ArrayLike) -> np.ndarray:
    """Mounting rotation: the sensor frame is rotated by ``R(rotvec)`` from nominal, so ``y = x @ R``.

    ``x`` holds vectors in the nominal frame; the result is the same vectors in the rotated sensor
    frame (``R^T x``). ``rotvec`` is (3,) or per-IMU (K, 3).

    >>> np.round(rotate(np.array([[0.0, 1.0, 0.0]]), [0.0, 0.0, np.pi / 2]), 6).tolist()
    [[1.0, 0.0, 0.0]]
    """
    xs = _signal(x)
    r = rotation_matrix(rotvec)
    if r.ndim == 2:
        return xs @ r
    if xs.ndim != 3 or xs.shape[1] != r.shape[0]:
        raise ValueError(f"per-IMU rotvec {r.shape[:1]} does not fit a signal of shape {xs.shape}")
    return np.matmul(xs.transpose(1, 0, 2), r).transpose(1, 0, 2)  # y[t, k] = x[t, k] @ r[k]


def angular_acceleration(t: ArrayLike, gyro: ArrayLike) -> np.ndarray:
    """``d(gyro)/dt`` by central differences (one-sided at the ends), same shape as ``gyro``."""
    g = _signal(gyro)
    tt = _times(t, g.shape[0])
    if g.shape[0] < 2:
        return np.zeros_like(g)
    return np.gradient(g, tt, axis=0)


def lever_arm(acc: ArrayLike, gyro: ArrayLike, gyro_dot: ArrayLike, meters: ArrayLike) -> np.ndarray:
    """Accelerometer displaced by ``r`` (sensor frame, m) on the same rigid body.

    ``acc + w x (w x r) + wdot x r``: centripetal and tangential terms of a rigid-body point offset by
    ``r``. Gravity and the body's own acceleration are already in ``acc``. ``meters`` is (3,) or (K, 3).

    >>> w = np.array([[0.0, 0.0, 2.0]])
    >>> lever_arm(np.zeros((1, 3)), w, np.zeros((1, 3)), [0.5, 0.0, 0.0]).tolist()
    [[-2.0, 0.0, 0.0]]
    """
    a, w, wd = _signal(acc), _signal(gyro), _signal(gyro_dot)
    r = np.asarray(meters, dtype=np.float64)
    r = np.broadcast_to(r, w.shape)
    return a + np.cross(w, np.cross(w, r)) + np.cross(wd, r)


def specific_force(R_world_sensor: ArrayLike, lin_acc_world: ArrayLike, gravity: ArrayLike) -> np.ndarray:
    """What an accelerometer reads: ``R^T (a - g)`` in the sensor frame.

    ``R_world_sensor`` is (T, 3, 3) or (T, K, 3, 3), ``lin_acc_world`` (T, 3) or (T, K, 3) the sensor
    point's acceleration in the world, ``gravity`` the world gravity vector (3,). At rest with z up
    the reading is ``+9.81`` along the sensor's view of world-up.
    """
    R = np.asarray(R_world_sensor, dtype=np.float64)
    a = _signal(lin_acc_world)
    g = np.asarray(gravity, dtype=np.float64)
    if R.shape[-2:] != (3, 3) or R.shape[:-2] != a.shape[:-1]:
        raise ValueError(f"R {R.shape} does not fit accelerations {a.shape}")
    if g.shape != (3,):
        raise ValueError(f"gravity must have shape (3,), got {g.shape}")
    return np.einsum("...ji,...j->...i", R, a - g)


def quantize(x: ArrayLike, lsb: ArrayLike) -> np.ndarray:
    """Round to the converter's resolution ``lsb`` (scalar or per axis; 0 = no quantization).

    >>> quantize(np.array([[0.26, -0.26, 1.0]]), 0.5).tolist()
    [[0.5, -0.5, 1.0]]
    """
    xs = np.asarray(x, dtype=np.float64)
    q = np.asarray(lsb, dtype=np.float64)
    if np.any(q < 0):
        raise ValueError("lsb must be >= 0")
    safe = np.where(q > 0, q, 1.0)
    return np.where(q > 0, np.round(xs / safe) * safe, xs)


def white_noise(
    shape: tuple[int, ...], density: ArrayLike, rate: float, rng: np.random.Generator
) -> np.ndarray:
    """Band-limited white noise of spectral ``density`` (unit/√Hz) sampled at ``rate`` Hz.

    ``std = density * sqrt(rate)`` (the noise bandwidth is taken as the sample rate, the convention
    of datasheet noise densities). ``density`` broadcasts against ``shape`` (scalar or per axis).
    """
    if rate <= 0:
        raise ValueError("rate must be > 0")
    d = np.asarray(density, dtype=np.float64)
    if np.any(d < 0):
        raise ValueError("density must be >= 0")
    return rng.standard_normal(shape) * (d * np.sqrt(float(rate)))


def resample(t: ArrayLike, x: ArrayLike, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples of ``x`` at a uniform ``rate`` (Hz) from ``t[0]`` up to ``t[-1]``, linear interpolation.

    >>> t = np.array([0.0, 0.1, 0.2])
    >>> tn, xn = resample(t, np.stack([t, t, t], axis=1), 20.0)
    >>> tn.round(3).tolist(), xn[:, 0].round(3).tolist()
    ([0.0, 0.05, 0.1, 0.15, 0.2], [0.0, 0.05, 0.1, 0.15, 0.2])
    """
    if rate <= 0:
        raise ValueError("rate must be > 0")
    xs = np.asarray(x, dtype=np.float64)
    tt = _times(t, xs.shape[0])
    n = int(np.floor((tt[-1] - tt[0]) * rate + 1e-9)) + 1
    tn = tt[0] + np.arange(n) / float(rate)
    return tn, _interp_rows(tt, xs, tn)


def cross_axis_matrix(scale: ArrayLike, cross_axis: ArrayLike | None = None) -> np.ndarray:
    """A (3, 3) sensitivity matrix: ``diag(scale)`` with off-diagonal cross-axis terms.

    ``cross_axis`` is (6,) ordered ``xy, xz, yx, yz, zx, zy`` (row axis reads a fraction of column
    axis), or a full (3, 3) whose diagonal is ignored.

    >>> cross_axis_matrix([1.0, 1.0, 1.0], [0.01, 0, 0, 0, 0, 0])[0].tolist()
    [1.0, 0.01, 0.0]
    """
    m = np.diag(np.asarray(scale, dtype=np.float64).reshape(3))
    if cross_axis is None:
        return m
    c = np.asarray(cross_axis, dtype=np.float64)
    if c.shape == (6,):
        off = np.array([(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)])
        m[off[:, 0], off[:, 1]] = c
    elif c.shape == (3, 3):
        m = m + c - np.diag(np.diag(c))
    else:
        raise ValueError(f"cross_axis must have shape (6,) or (3, 3), got {c.shape}")
    return m
