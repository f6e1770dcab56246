"""A loose IMU that still turns with its link is found against its own residual share on the baseline,
and the common motion of a link does not make a firm IMU look loose (bodyschema.health.loose_imus)."""

from __future__ import annotations

import numpy as np

from bodyschema.health import imu_fingerprints, loose_imus, loose_tolerance, signal_health
from bodyschema.recording import Recording
from bodyschema.topology import Topology

LAYOUT = Topology({"j1": None}, {"a": "j1", "b": "j1", "c": "j1"})
RATE, SECONDS = 100.0, 30.0


def _window(rng: np.random.Generator, amplitude: float, wobble: float = 0.0, t0: float = 0.0) -> Recording:
    """Three IMUs on the link of a base joint turning about z; each gyro has its own noise density and
    the common model error grows with the motion; ``wobble`` adds a loose IMU's own motion to ``c``."""
    t = t0 + np.arange(int(RATE * SECONDS)) / RATE
    q = amplitude * np.sin(0.7 * t) * np.sin(0.13 * t)
    qd = np.gradient(q, t)
    common = 0.01 * amplitude * rng.normal(size=t.shape)  # what the model misses, shared by the link
    gyro = np.zeros((t.size, 3, 3))
    for k, sigma in enumerate((0.002, 0.003, 0.0025)):
        gyro[:, k, 2] = qd + common
        gyro[:, k, :] += rng.normal(0.0, sigma, (t.size, 3))
    gyro[:, 2, :] += wobble * rng.normal(size=(t.size, 3))
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 3, 1)) + rng.normal(0, 0.01, (t.size, 3, 3))
    return Recording(t=t, joint_names=("j1",), q=q[:, None], imu_names=("a", "b", "c"), acc=acc, gyro=gyro)


def test_a_loose_imu_is_found_and_common_motion_is_not() -> None:
    rng = np.random.default_rng(11)
    fps = imu_fingerprints(_window(rng, 1.0), LAYOUT)
    assert set(fps) == {"a", "b", "c"} and all(fp.joint == "j1" and fp.ref is None for fp in fps.values())
    healthy = {"a", "b", "c"}
    # three times the motion, so three times the common model error: no IMU's share changes
    assert loose_imus(_window(rng, 3.0, t0=30.0), fps, healthy) == {}
    # c picks up motion of its own, about as large as what the model misses on the link: its share
    # of the residual more than doubles
    loose = loose_imus(_window(rng, 1.0, wobble=0.012, t0=60.0), fps, healthy)
    assert set(loose) == {"c"} and loose["c"] > loose_tolerance(3000, RATE, None, 1e-9)
    health = signal_health(_window(rng, 1.0, wobble=0.012, t0=90.0), LAYOUT, imu_fingerprints=fps)
    assert set(health.loose) == {"c"}


def test_the_tolerance_follows_the_degrees_of_freedom() -> None:
    """More samples: a tighter tolerance; a low-passed gyro (fewer independent samples): a looser one;
    a rarer false alarm: a looser one."""
    base = loose_tolerance(3000, 100.0, None, 1e-9)
    assert loose_tolerance(6000, 100.0, None, 1e-9) < base < loose_tolerance(3000, 100.0, 20.0, 1e-9)
    assert loose_tolerance(3000, 100.0, None, 1e-6) < base
