"""The simulated robot farm (:class:`simulators.farm.Farm`) as an ingest source.

The farm is stepped in ``step_seconds`` of simulated (device) time, paced to ``speed`` × the wall clock
(``math.inf``: as fast as the simulation runs). Every step yields one batch per robot. The source
exposes ``.farm`` and a thread-safe :meth:`FarmSource.apply_damage` so the API can damage a robot while
the reader thread is stepping it (through :class:`FarmDamage`, the service's
:class:`~service.control.DamageControl`). It declares its robots simulated
(:meth:`FarmSource.simulated_robots`); the pipeline registers them in the store, like every frame it
carries.

Example (any object with the farm's ``advance``/``robot_names``/``catalog_name`` works)
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> class Still:
...     robot_names = ("r1",)
...     t = 0.0
...     def catalog_name(self, name): return "toy"
...     def advance(self, seconds):
...         t = self.t + np.arange(1, 11) * seconds / 10
...         self.t = float(t[-1])
...         return {"r1": Recording(t=t, joint_names=["j1"], q=np.zeros((10, 1)), imu_names=["i0"],
...                                 acc=np.zeros((10, 1, 3)), gyro=np.zeros((10, 1, 3)))}
>>> src = FarmSource(Still(), speed=math.inf, max_steps_per_read=3)
>>> [(b.robot, b.n_samples) for b in src.read()]
[('r1', 10), ('r1', 10), ('r1', 10)]
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from service.children import CHILDREN, exit_with_service
from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.replay import recording_batch

__all__ = ["FarmDamage", "FarmProcess", "FarmSource", "farm_robot_names"]

#: Wall seconds within which a step counts as due.
_SLACK = 1e-6


def farm_robot_names(catalog_names: list[str]) -> dict[str, str]:
    """Robot names for catalog models: ``["ur5e", "ur5e", "paper-3"]`` ->
    ``{"ur5e-1": "ur5e", "ur5e-2": "ur5e", "paper-3-1": "paper-3"}``.

    >>> farm_robot_names(["ur5e", "ur5e", "paper-3"])
    {'ur5e-1': 'ur5e', 'ur5e-2': 'ur5e', 'paper-3-1': 'paper-3'}
    """
    counts: dict[str, int] = {}
    out: dict[str, str] = {}
    for c in catalog_names:
        counts[c] = counts.get(c, 0) + 1
        out[f"{c}-{counts[c]}"] = c
    return out


class FarmSource(Source):
    """Batches from a stepping farm (see the module docstring)."""

    def __init__(
        self,
        farm: Any,
        *,
        speed: float = 1.0,
        step_seconds: float = 0.1,
        max_steps_per_read: int = 20,
        name: str = "farm",
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be positive (math.inf = as fast as possible), got {speed}")
        if not step_seconds > 0:
            raise ValueError(f"step_seconds must be positive, got {step_seconds}")
        super().__init__(name)
        self.farm = farm
        self.speed = float(speed)
        self.step_seconds = float(step_seconds)
        self.max_steps_per_read = int(max_steps_per_read)
        self.sim_seconds = 0.0  # simulated time advanced so far
        #: Held while the farm steps; take it to touch the farm from another thread.
        self.lock = threading.RLock()
        self._clock, self._sleep = clock, sleep
        self._wall0: float | None = None

    @property
    def robot_names(self) -> list[str]:
        return list(self.farm.robot_names)

    def simulated_robots(self) -> dict[str, str]:
        """Every robot of the farm, with its catalog model."""
        return {name: self.farm.catalog_name(name) for name in self.robot_names}

    def apply_damage(self, robot: str, kind: str, **params: Any) -> Any:
        """Damage ``robot`` (e.g. ``apply_damage("ur5e-1", "imu_moved", imu="imu3")``); returns the
        farm's ground-truth diff. Safe to call while the reader thread is stepping the farm."""
        with self.lock:
            return self.farm.apply_damage(robot, kind, **params)

    def close(self) -> None:
        """End the farm's child process, when it runs in one (:class:`FarmProcess`)."""
        close = getattr(self.farm, "close", None)
        if close is not None:
            close()

    def _behind(self) -> float:
        """Simulated seconds the farm is behind its wall-clock target (negative: ahead)."""
        assert self._wall0 is not None
        return (self._clock() - self._wall0) * self.speed - self.sim_seconds

    def _step_due(self) -> bool:
        # The slack keeps float rounding of the clock from leaving a step "almost due" forever.
        return self._behind() >= self.step_seconds - _SLACK * self.speed

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        if self._wall0 is None:
            self._wall0 = self._clock() - self.step_seconds / self.speed  # the first step is due now
        if math.isfinite(self.speed):
            wait = (self.step_seconds - self._behind()) / self.speed
            if wait > _SLACK:
                self._sleep(min(wait, timeout))
                if not self._step_due():
                    return []
        out: list[FrameBatch] = []
        for _ in range(self.max_steps_per_read):
            with self.lock:
                chunks = self.farm.advance(seconds=self.step_seconds)
            self.sim_seconds += self.step_seconds
            out.extend(recording_batch(name, rec) for name, rec in chunks.items() if rec.n_samples)
            if math.isfinite(self.speed) and not self._step_due():
                break
        return out


class FarmDamage:
    """The :class:`~service.control.DamageControl` over the farm sources of one service process: a
    damage request goes to the farm that simulates the robot.

    >>> FarmDamage([]).simulates("ur5e-1")
    False
    """

    def __init__(self, farms: Sequence[FarmSource]) -> None:
        self.farms = list(farms)

    def _farm_of(self, robot: str) -> FarmSource:
        for src in self.farms:
            if robot in src.robot_names:
                return src
        raise KeyError(robot)

    def simulates(self, robot: str) -> bool:
        return any(robot in src.robot_names for src in self.farms)

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        truth = self._farm_of(robot).apply_damage(robot, kind, **params)
        return truth.to_json() if hasattr(truth, "to_json") else dict(truth or {})


class FarmProcess:
    """A :class:`simulators.farm.Farm` built from ``farm_kwargs`` in a child process, with the calls
    :class:`FarmSource` and :class:`FarmDamage` make: ``advance``, ``apply_damage``, ``robot_names``,
    ``catalog_name`` and ``sensing``.

    The farm stands for robots, and robots do not share the service's interpreter: stepping the demo's
    three robots at the ``robot`` preset's 1 kHz physics rate in the service process held its
    interpreter lock in runs of milliseconds, every request that came meanwhile waited for it, and
    that was a large part of the API's latency tail (docs/bench/load.md). Here the service's reader
    thread waits on a pipe, which leaves the lock free, and pays only for unpickling each step's
    recordings. The child is started as every child of the service is (:mod:`service.children`) and
    ends with it: on :meth:`close`, when the pipe breaks, or within a second of a SIGKILL of the
    service. Errors raised in the child (an unknown damage part) are raised here.

    >>> farm = FarmProcess(robots={"p": "paper-1"}, seed=0, imu_model="ideal")
    >>> farm.robot_names, farm.catalog_name("p"), sorted(farm.advance(0.2)["p"].t.shape)
    (('p',), 'paper-1', [20])
    >>> farm.apply_damage("p", "imu_dead", imu="nope")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: ...
    >>> farm.close()
    """

    def __init__(self, **farm_kwargs: Any) -> None:
        self._conn, child = CHILDREN.Pipe()
        self._proc = CHILDREN.Process(
            target=_serve_farm, args=(child, farm_kwargs, os.getpid()), name="farm", daemon=True
        )
        self._proc.start()
        child.close()
        self._lock = threading.Lock()
        names, catalog, sensing = self._call("describe")
        self.robot_names: tuple[str, ...] = tuple(names)
        self._catalog: dict[str, str] = dict(catalog)
        self.sensing = sensing

    def _call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            try:
                self._conn.send((name, args, kwargs))
                ok, value = self._conn.recv()
            except (EOFError, OSError) as err:
                raise RuntimeError(f"the farm process ended (exit code {self._proc.exitcode})") from err
        if not ok:
            raise value
        return value

    def catalog_name(self, robot: str) -> str:
        return self._catalog[robot]

    def advance(self, seconds: float) -> Any:
        return self._call("advance", seconds)

    def apply_damage(self, robot: str, kind: str, **params: Any) -> Any:
        return self._call("apply_damage", robot, kind, **params)

    def close(self) -> None:
        """End the child (idempotent)."""
        with self._lock:
            if self._proc.is_alive():
                try:
                    self._conn.send(None)
                except OSError:
                    pass
            self._proc.join(5)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(5)
            self._conn.close()


def _serve_farm(conn: Any, farm_kwargs: dict[str, Any], service: int) -> None:
    """The child's loop: build the farm, then answer calls until told to stop or the service is gone."""
    from simulators.farm import Farm

    try:
        farm = Farm(**farm_kwargs)
    except Exception as err:  # a bad spec: said to the parent, which raises it
        conn.send((False, err))
        return
    exit_with_service(service)
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            return
        name, args, kwargs = msg
        try:
            if name == "describe":
                value: Any = (
                    farm.robot_names,
                    {n: farm.catalog_name(n) for n in farm.robot_names},
                    farm.sensing,
                )
            else:
                value = getattr(farm, name)(*args, **kwargs)
            conn.send((True, value))
        except Exception as err:
            conn.send((False, err))
