"""Many simulated robots at once, producing frames for the service's ingestors.

Each robot is a :class:`simulators.simulation.Simulation` with its own seed derived from the farm's
seed and the robot's name, so a robot's data does not depend on which other robots share the farm,
and the same farm seed gives the same data. :meth:`Farm.advance` runs every robot for the same
simulated time as fast as the machine allows; :meth:`Farm.stream` paces chunks at a chosen multiple
of real time.

Example
-------
>>> farm = Farm(robots={"ur5e-1": "ur5e", "paper-3-1": "paper-3"}, seed=0, imu_model="ideal")
>>> chunks = farm.advance(seconds=0.1)
>>> sorted(chunks), chunks["ur5e-1"].n_samples, chunks["ur5e-1"].acc.shape
(['paper-3-1', 'ur5e-1'], 10, (10, 12, 3))
>>> float(farm.advance(seconds=0.1)["ur5e-1"].t[0])
0.1
>>> farm.inject("ur5e-1", "imu_moved", imu="imu3", to="wrist_3").findings[0].to
'wrist_3'
>>> farm.truth("ur5e-1").imu_joint["imu3"]
'wrist_3'
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from bodyschema.findings import Diff
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from simulators.excitation import Excitation
from simulators.imu_model import ImuModel
from simulators.simulation import Simulation

__all__ = ["Farm"]


class Farm:
    """Robots by name -> catalog name (or model file). All share ``imu_model``, ``excitation`` and
    ``rate`` unless ``overrides[name]`` gives ``imu_model``/``excitation``/``rate`` for one robot.

    Each robot simulates at least ``readahead`` seconds per physics call and serves smaller chunks
    from that buffer (damage rewinds to the last returned sample first), so small chunks cost little
    more than large ones; the data are the same with any ``readahead``.
    """

    def __init__(
        self,
        robots: Mapping[str, str],
        *,
        seed: int = 0,
        imu_model: str | ImuModel | None = "mpu6050",
        excitation: str = "observable",
        rate: float = 100.0,
        overrides: Mapping[str, Mapping[str, Any]] | None = None,
        readahead: float = 1.0,
    ) -> None:
        if not robots:
            raise ValueError("a farm needs at least one robot")
        self.seed = int(seed)
        self._catalog: dict[str, str] = {}
        self._sims: dict[str, Simulation] = {}
        overrides = overrides or {}
        unknown = set(overrides) - set(robots)
        if unknown:
            raise ValueError(f"overrides name unknown robots {sorted(unknown)}")
        for name, source in robots.items():
            if not name or not isinstance(name, str):
                raise ValueError("robot names must be non-empty strings")
            kw: dict[str, Any] = {"imu_model": imu_model, "excitation": excitation, "rate": rate}
            kw.update(overrides.get(name, {}))
            ss = np.random.SeedSequence([self.seed, zlib.crc32(name.encode("utf-8"))])
            exc: str | Excitation = kw["excitation"]
            self._sims[name] = Simulation(
                source,
                seed=ss,
                imu_model=kw["imu_model"],
                excitation=exc,
                rate=float(kw["rate"]),
                readahead=readahead,
            )
            self._catalog[name] = source
        self._elapsed = 0.0

    # ------------------------------------------------------------------ queries
    @property
    def robot_names(self) -> list[str]:
        return list(self._sims)

    def catalog_name(self, robot: str) -> str:
        return self._catalog[self._known(robot)]

    def simulation(self, robot: str) -> Simulation:
        return self._sims[self._known(robot)]

    def truth(self, robot: str) -> Topology:
        """Ground truth of ``robot`` from its compiled model, current damage applied."""
        return self._sims[self._known(robot)].truth()

    def diff(self, robot: str) -> Diff:
        """All damage injected into ``robot`` so far."""
        return self._sims[self._known(robot)].diff

    @property
    def time(self) -> float:
        """Simulated seconds so far."""
        return self._elapsed

    def _known(self, robot: str) -> str:
        if robot not in self._sims:
            raise KeyError(f"unknown robot {robot!r}; farm has {', '.join(self._sims)}")
        return robot

    # ------------------------------------------------------------------ running
    def advance(self, seconds: float) -> dict[str, Recording]:
        """Run every robot ``seconds`` further; return each robot's new samples (t continues)."""
        if not seconds > 0:
            raise ValueError("seconds must be > 0")
        target = self._elapsed + float(seconds)
        out: dict[str, Recording] = {}
        for name, sim in self._sims.items():
            n = round(target * sim.rate) - round(sim.time * sim.rate)
            if n > 0:
                out[name] = sim.advance(n)
        self._elapsed = target
        return out

    def inject(self, robot: str, kind: str, **kwargs: Any) -> Diff:
        """Damage ``robot`` now; parts left out are picked by the robot's seeded damage generator."""
        return self._sims[self._known(robot)].inject(kind, **kwargs)

    def stream(
        self, chunk: float = 0.1, speed: float | None = 1.0, seconds: float | None = None
    ) -> Iterator[dict[str, Recording]]:
        """Chunks of ``chunk`` simulated seconds, paced at ``speed`` × real time (None: unpaced),
        for ``seconds`` in total (None: forever)."""
        start, done = time.monotonic(), 0.0
        while seconds is None or done < seconds - 1e-9:
            step = chunk if seconds is None else min(chunk, seconds - done)
            out = self.advance(step)
            done += step
            if speed:
                lag = start + done / speed - time.monotonic()
                if lag > 0:
                    time.sleep(lag)
            yield out
