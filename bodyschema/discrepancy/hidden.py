"""Hide an IMU error effect in readings: draw it over a realistic range and hide it there.

How far to trust the analysis on *your* data: hide an effect of known size in a recording, run the
analysis, and compare. The hidden-effect tests and the benchmark do exactly that, on simulated and on
measured (BROAD) readings. Every draw returns the true parameters in the discrepancy JSON layout.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> p = draw("time_offset", rng)
>>> RANGES["time_offset"][0] <= p["seconds"] <= RANGES["time_offset"][1]
True
>>> t = np.arange(5) * 0.01
>>> g, a = hide_effect("gyro_bias", {"vector": [0.1, 0.0, 0.0]}, t, np.zeros((5, 3)), np.zeros((5, 3)),
...               np.tile([1.0, 0, 0, 0], (5, 1)), rng)
>>> g[0].tolist()
[0.1, 0.0, 0.0]
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bodyschema import imu_effects as fx
from bodyschema.rigid_motion import quat_to_matrix

__all__ = ["RANGES", "draw", "hide_effect"]

#: Realistic magnitude ranges of each effect (the hidden-effect tests draw from these).
RANGES: dict[str, tuple[float, float]] = {
    "time_offset": (0.002, 0.040),  # s
    "gyro_bias": (0.01, 0.3),  # rad/s, norm
    "acc_bias": (0.05, 0.8),  # m/s², norm (MPU-6050: ±50-80 mg)
    "gyro_scale": (0.01, 0.05),  # per-axis |gain - 1|
    "acc_scale": (0.01, 0.05),
    "mounting_rotation": (np.radians(2.0), np.radians(15.0)),  # rad
    "lever_arm": (0.005, 0.050),  # m, norm
    "gravity": (np.radians(0.5), np.radians(3.0)),  # tilt of the world vertical, rad (+ magnitude)
    "noise": (1e-4, 1e-3),  # gyro density rad/s/√Hz; acc density is 10x that in m/s²/√Hz
}


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def draw(effect: str, rng: np.random.Generator) -> dict[str, object]:
    """Random true parameters of ``effect`` within :data:`RANGES`."""
    lo, hi = RANGES[effect]
    mag = float(rng.uniform(lo, hi))
    if effect == "time_offset":
        return {"seconds": mag}
    if effect in ("gyro_bias", "acc_bias"):
        return {"vector": (mag * _unit(rng)).tolist()}
    if effect in ("gyro_scale", "acc_scale"):
        return {"matrix": (1.0 + rng.choice([-1.0, 1.0], size=3) * rng.uniform(lo, hi, size=3)).tolist()}
    if effect == "mounting_rotation":
        return {"rotvec": (mag * _unit(rng)).tolist()}
    if effect == "lever_arm":
        return {"meters": (mag * _unit(rng)).tolist()}
    if effect == "gravity":
        axis = np.array([*rng.normal(size=2), 0.0])
        axis /= np.linalg.norm(axis)
        g = Rotation.from_rotvec(mag * axis).apply([0.0, 0.0, -9.81])
        g *= 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.001, 0.005)
        return {"vector": g.tolist()}
    if effect == "noise":
        return {"gyro_density": [mag] * 3, "acc_density": [10 * mag] * 3}
    raise KeyError(effect)


def hide_effect(
    effect: str,
    params: dict[str, object],
    t: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    quat: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The readings ``(gyro, acc)`` with ``effect`` applied the way a real sensor would show it."""
    g, a = gyro.copy(), acc.copy()
    if effect == "time_offset":
        return fx.time_shift(t, g, params["seconds"]), fx.time_shift(t, a, params["seconds"])
    if effect == "gyro_bias":
        return fx.affine(g, bias=params["vector"]), a
    if effect == "acc_bias":
        return g, fx.affine(a, bias=params["vector"])
    if effect == "gyro_scale":
        return fx.affine(g, matrix=params["matrix"]), a
    if effect == "acc_scale":
        return g, fx.affine(a, matrix=params["matrix"])
    if effect == "mounting_rotation":
        return fx.rotate(g, params["rotvec"]), fx.rotate(a, params["rotvec"])
    if effect == "lever_arm":
        return g, fx.lever_arm(a, g, fx.angular_acceleration(t, g), params["meters"])
    if effect == "gravity":
        dg = np.asarray(params["vector"]) - np.array([0.0, 0.0, -9.81])
        # a - g_true = (a - g_nominal) - dg, seen in the sensor frame.
        return g, a - np.einsum("tji,j->ti", quat_to_matrix(quat), dg)
    if effect == "noise":
        rate = 1.0 / np.median(np.diff(t))
        return (
            g + fx.white_noise(g.shape, params["gyro_density"], rate, rng),
            a + fx.white_noise(a.shape, params["acc_density"], rate, rng),
        )
    raise KeyError(effect)
