"""A fitted IMU's noise as a Kalibr ``imu.yaml``: the noise densities, bias random walks and rate that
Kalibr's camera-IMU calibration and most visual-inertial estimators read.

Kalibr's format (github.com/ethz-asl/kalibr, wiki "IMU Noise Model")::

    accelerometer_noise_density: 0.0186   # m/s^2/sqrt(Hz)   white noise, continuous time
    accelerometer_random_walk: 0.000433   # m/s^3/sqrt(Hz)   bias random walk
    gyroscope_noise_density: 0.00187      # rad/s/sqrt(Hz)
    gyroscope_random_walk: 2.66e-05       # rad/s^2/sqrt(Hz)
    rostopic: /imu0
    update_rate: 200.0                    # Hz

The densities come from the analysis's ``noise`` (its std above the motion band divided by the square
root of the rate, the same continuous-time convention). The random walks are estimates that tend
high: the analysis has no static recording for an Allan variance, so they come from how much the
residual the fitted model leaves drifts between adjacent 2 s blocks, less the white noise, which
leaves the model's misfit in them (Kalibr's advice is to inflate datasheet or Allan values anyway).
Written by hand rather than with a YAML dumper, to keep each line's unit as a comment.

>>> from bodyschema.discrepancy.report import Cause, DiscrepancyReport
>>> noise = Cause("noise", {"std": [0.01] * 3 + [0.1] * 3, "gyro_density": [0.001] * 3,
...                         "acc_density": [0.01] * 3, "rate_hz": 100.0}, {}, 0.0, 0.0, "", 0.0)
>>> rep = DiscrepancyReport({}, [noise], {}, {}, params={"noise": noise.params})
>>> print(to_kalibr_yaml(kalibr_imu(rep, random_walk=(2e-4, 3e-6))))  # doctest: +NORMALIZE_WHITESPACE
accelerometer_noise_density: 0.01  # m/s^2/sqrt(Hz)
accelerometer_random_walk: 0.0002  # m/s^3/sqrt(Hz), from the residual's drift
gyroscope_noise_density: 0.001  # rad/s/sqrt(Hz)
gyroscope_random_walk: 3e-06  # rad/s^2/sqrt(Hz), from the residual's drift
rostopic: /imu0
update_rate: 100.0  # Hz
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bodyschema.discrepancy.fit import residual
from bodyschema.discrepancy.report import DiscrepancyReport

__all__ = ["bias_random_walk", "kalibr_imu", "to_kalibr_yaml", "write_kalibr_imu"]

#: Length of the blocks whose mean residual drifts like the bias, s.
BLOCK_S = 2.0


def bias_random_walk(report: DiscrepancyReport, block_s: float = BLOCK_S) -> tuple[float, float]:
    """(accelerometer, gyro) bias random walk densities from the drift of the residual (tending high).

    For a random walk of density ``q``, the means of two adjacent blocks of ``T`` seconds differ with
    variance ``2 q² T / 3``, and white noise of density ``D`` adds ``2 D² / T``; the variance of the
    differences measured over the usable, unbroken stretches of the recording, less the white noise
    the analysis measured, is read that way (RMS over the axes). The model's misfit adds to the
    differences too, so the value tends high.
    """
    prob = report.problem
    if prob is None:
        raise ValueError("the report carries no data (problem is None)")
    fitted = {k: v for k, v in report.params.items() if k != "noise"}
    r, _ = residual(prob, fitted)
    n = max(2, round(block_s * prob.rate))
    # unbroken stretches of usable samples, cut into whole blocks
    idx = prob.index
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    diffs: list[np.ndarray] = []
    for run in runs:
        k = run.size // n
        if k < 2:
            continue
        means = r[run[: k * n]].reshape(k, n, 6).mean(axis=1)
        diffs.append(np.diff(means, axis=0))
    if not diffs:
        raise ValueError(f"no unbroken stretch of {2 * block_s:g} s to measure the bias drift on")
    d = np.concatenate(diffs)
    T = n / prob.rate
    # white noise of density D moves a block mean by D²/T in variance: take it out of the differences
    noise = report.params.get("noise") or {}
    density = np.concatenate([noise.get("gyro_density", [0.0] * 3), noise.get("acc_density", [0.0] * 3)])
    walk = np.maximum(np.mean(d**2, axis=0) - 2.0 * np.square(density) / T, 0.0)
    q = np.sqrt(walk / (2.0 * T / 3.0))
    return float(np.sqrt(np.mean(q[3:] ** 2))), float(np.sqrt(np.mean(q[:3] ** 2)))


def kalibr_imu(
    report: DiscrepancyReport, rostopic: str = "/imu0", random_walk: tuple[float, float] | None = None
) -> dict[str, object]:
    """The Kalibr IMU parameters of one analysed IMU (``random_walk``: (acc, gyro) to use instead of
    :func:`bias_random_walk`)."""
    noise = report.params.get("noise")
    if not noise:
        raise ValueError("no noise was measured on this IMU (below the noise floor): nothing to export")
    acc_rw, gyro_rw = random_walk if random_walk is not None else bias_random_walk(report)
    return {
        "accelerometer_noise_density": float(np.sqrt(np.mean(np.square(noise["acc_density"])))),
        "accelerometer_random_walk": float(acc_rw),
        "gyroscope_noise_density": float(np.sqrt(np.mean(np.square(noise["gyro_density"])))),
        "gyroscope_random_walk": float(gyro_rw),
        "rostopic": rostopic,
        "update_rate": round(float(noise["rate_hz"]), 3),
    }


_UNITS = {
    "accelerometer_noise_density": "m/s^2/sqrt(Hz)",
    "accelerometer_random_walk": "m/s^3/sqrt(Hz), from the residual's drift",
    "gyroscope_noise_density": "rad/s/sqrt(Hz)",
    "gyroscope_random_walk": "rad/s^2/sqrt(Hz), from the residual's drift",
    "update_rate": "Hz",
}


def to_kalibr_yaml(imu: dict[str, object]) -> str:
    """The parameters as Kalibr's ``imu.yaml`` text (one key per line, units as comments)."""
    lines = []
    for key, value in imu.items():
        text = f"{value:.6g}" if isinstance(value, float) and key != "update_rate" else str(value)
        unit = _UNITS.get(key)
        lines.append(f"{key}: {text}" + (f"  # {unit}" if unit else ""))
    return "\n".join(lines)


def write_kalibr_imu(
    report: DiscrepancyReport, path: str | os.PathLike[str], rostopic: str = "/imu0"
) -> Path:
    """Write :func:`kalibr_imu` of ``report`` to ``path``; returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(to_kalibr_yaml(kalibr_imu(report, rostopic)) + "\n", encoding="utf-8")
    return out
