"""Builders of the service tests, shared by several test files: the scripted estimators and frame feeds
of the worker tests, frame batches and bodies (the storage-fault parts: tests/service/faults.py).

They live here, not in a test module, so that no test file imports another (tests/test_suite_rules.py).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.frames import FrameBatch
from service.store import Store, open_store
from tests.builders import LAYOUT

# ------------------------------------------- the worker: scripted estimators, frames fed to a store
MOVED = Topology(
    dict(LAYOUT.joint_parent),
    {**LAYOUT.imu_joint, "c1": "j2"},
    method="fast",
    excitation=dict(LAYOUT.excitation),
)
GOOD = Topology(
    dict(LAYOUT.joint_parent), dict(LAYOUT.imu_joint), method="fast", excitation=dict(LAYOUT.excitation)
)


class Scripted:
    """Returns ``self.next`` for "fast" and records every call."""

    def __init__(self, topo: Topology) -> None:
        self.next = topo
        self.calls: list[tuple[str, int]] = []

    def __call__(self, rec: Recording, method: str) -> Topology:
        self.calls.append((method, rec.n_samples))
        t = self.next
        return dataclasses.replace(
            t, imu_joint={k: v for k, v in t.imu_joint.items() if k in rec.imu_names}, method=method
        )


def feed(
    store: Store, rec: Recording, robot: str = "arm", offset: float = 0.0, dead: str | None = None
) -> float:
    acc, gyro = rec.acc.copy(), rec.gyro.copy()
    if dead is not None:
        k = rec.imu_names.index(dead)
        acc[:, k] = 0.0
        gyro[:, k] = 0.0
    for s in range(0, rec.n_samples, 500):
        sl = slice(s, s + 500)
        store.write(
            FrameBatch(
                robot, rec.t[sl] + offset, rec.joint_names, rec.q[sl], rec.imu_names, acc[sl], gyro[sl]
            )
        )
    return float(rec.t[-1] + offset + 0.01)


def ticking(start: float = 1000.0, step: float = 1e-3) -> Callable[[], float]:
    """A wall clock that moves ``step`` s per reading: the worker's idle rule (no new frame for
    ``window_seconds`` of wall time) then follows the cycles run, not how fast the machine runs them."""
    now = [start]

    def clock() -> float:
        now[0] += step
        return now[0]

    return clock


class ByMethod(Scripted):
    """Returns ``self.by_method[method]`` (default ``self.next``) and records every call."""

    def __init__(self, topo: Topology) -> None:
        super().__init__(topo)
        self.by_method: dict[str, Topology] = {}

    def __call__(self, rec: Recording, method: str) -> Topology:
        self.calls.append((method, rec.n_samples))
        t = self.by_method.get(method, self.next)
        return dataclasses.replace(
            t, imu_joint={k: v for k, v in t.imu_joint.items() if k in rec.imu_names}, method=method
        )


# ------------------------------------------------------------------------- frame batches and bodies
def batch(robot: str = "arm", n: int = 20, t0: float = 0.0) -> FrameBatch:
    """``n`` frames at 100 Hz from ``t0`` of a still robot: two joints, two IMUs reading gravity."""
    t = t0 + np.arange(n) * 0.01
    return FrameBatch(
        robot,
        t,
        ("j1", "j2"),
        np.zeros((n, 2)),
        ("imu0", "imu1"),
        np.full((n, 2, 3), 9.81),
        np.zeros((n, 2, 3)),
    )


RATE = 100.0


def make_batch(
    rng: np.random.Generator,
    robot: str = "r1",
    t0: float = 0.0,
    n: int = 10,
    joints: tuple[str, ...] = ("j1", "j2"),
    imus: tuple[str, ...] = ("imu0", "imu1", "imu2"),
) -> FrameBatch:
    t = (round(t0 * RATE) + np.arange(n)) / RATE  # on one grid, so overlapping batches share stamps
    return FrameBatch(
        robot,
        t,
        joints,
        rng.normal(size=(n, len(joints))),
        imus,
        rng.normal(size=(n, len(imus), 3)),
        rng.normal(size=(n, len(imus), 3)),
    )


def stream(rng: np.random.Generator, seconds: float, batch: int = 10, **kw: object) -> list[FrameBatch]:
    n_total = round(seconds * RATE)
    return [make_batch(rng, t0=i / RATE, n=min(batch, n_total - i), **kw) for i in range(0, n_total, batch)]


def frames_body(n: int = 5, t0: float = 1.0, seed: int = 0) -> dict[str, Any]:
    """The JSON body of ``n`` frames at 100 Hz from ``t0``: two joints, two IMUs, values drawn from
    ``seed``."""
    rng = np.random.default_rng(seed)
    return {
        "t": [t0 + k * 0.01 for k in range(n)],
        "joint_names": ["j1", "j2"],
        "q": rng.normal(size=(n, 2)).tolist(),
        "imu_names": ["imu0", "imu1"],
        "acc": rng.normal(size=(n, 2, 3)).tolist(),
        "gyro": rng.normal(size=(n, 2, 3)).tolist(),
    }


def frame_batch(
    robot: str, t: np.ndarray, joints: tuple[str, ...] = ("j1",), imus: tuple[str, ...] = ("imu0",)
) -> FrameBatch:
    """All-zero frames of ``robot`` at the stamps ``t``."""
    n = len(t)
    return FrameBatch(
        robot,
        t,
        joints,
        np.zeros((n, len(joints))),
        imus,
        np.zeros((n, len(imus), 3)),
        np.zeros((n, len(imus), 3)),
    )


def simulated_store(path: Path) -> Store:
    """A store on the SQLite file ``path`` holding ten frames of ``sim``, a simulated UR5e: a robot the
    routes that act on the farm (damage, excitation) accept."""
    s = open_store(f"sqlite:///{path}")
    s.write(frame_batch("sim", np.arange(10) * 0.01))
    s.mark_simulated("sim", "ur5e")
    return s
