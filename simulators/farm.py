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
>>> farm.apply_damage("ur5e-1", "imu_moved", imu="imu3", to="wrist_3").findings[0].to
'wrist_3'
>>> farm.truth("ur5e-1").imu_joint["imu3"]
'wrist_3'

With ``sensing="robot"`` (:mod:`simulators.sensing`) the physics runs at the options' inner rate (1 kHz)
and each robot's chunks come out as a real robot logs them: multi-rate, IMU and encoders on their own
stamps, continuing from chunk to chunk (one :class:`~simulators.sensing.SensingStream` per robot), the
output trailing the physics by the stream's latency (about 50 ms):

>>> farm = Farm(robots={"p": "paper-2"}, seed=0, imu_model="ideal", sensing="robot")
>>> rec = farm.advance(seconds=0.2)["p"]
>>> rec.is_multirate, rec.qd is None, rec.t_q.shape[0] > 2 * rec.n_samples > 0
(True, True, True)
"""

from __future__ import annotations

import copy
import time
import zlib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from bodyschema.excitation_plan import PlanOptions
from bodyschema.findings import Diff
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from simulators.excitation import Excitation
from simulators.imu_model import ImuModel, resolve_imu_model
from simulators.sensing import SensingOptions, SensingStream, resolve_sensing
from simulators.simulation import Simulation

__all__ = ["Farm"]


class Farm:
    """Robots by name -> catalog name (or model file). All share ``imu_model``, ``excitation`` and
    ``rate`` unless ``overrides[name]`` gives ``imu_model``/``excitation``/``rate`` for one robot.

    ``sensing`` (a :mod:`simulators.sensing` preset or options, shared by all robots): ``ideal`` gives
    single-clock chunks at ``rate``; anything else simulates at the options' inner rate (``rate`` and
    per-robot rate overrides are then unused) and gives multi-rate chunks, each robot's sensing drawn
    from its own seed stream.

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
        sensing: str | SensingOptions | None = "ideal",
    ) -> None:
        if not robots:
            raise ValueError("a farm needs at least one robot")
        self.sensing = resolve_sensing(sensing)
        self.seed = int(seed)
        self._streams: dict[str, SensingStream] = {}
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
            key = [self.seed, zlib.crc32(name.encode("utf-8"))]
            ss = np.random.SeedSequence(key)
            if not self.sensing.is_ideal:
                if resolve_imu_model(kw["imu_model"]).rate is not None:
                    raise ValueError("an IMU model with its own sample_rate cannot be combined with sensing")
                kw["rate"] = self.sensing.inner_rate
                # a stream after the four the simulation spawns: the motion and the IMU noise stay
                # those of the same seed's run at the inner rate
                sensing_rng = np.random.default_rng(np.random.SeedSequence(key).spawn(5)[4])
                self._streams[name] = SensingStream(self.sensing, sensing_rng)
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
        """Run every robot ``seconds`` further; return each robot's new samples (t continues).

        Under non-ideal sensing a robot is left out of the result while its sensing stream holds back
        everything it has (a step shorter than a few samples)."""
        if not seconds > 0:
            raise ValueError("seconds must be > 0")
        target = self._elapsed + float(seconds)
        out: dict[str, Recording] = {}
        for name, sim in self._sims.items():
            n = round(target * sim.rate) - round(sim.time * sim.rate)
            if n > 0:
                rec = sim.advance(n)
                stream = self._streams.get(name)
                if stream is not None:
                    sensed = stream.push(rec)
                    if sensed is None:
                        continue
                    rec = sensed
                out[name] = rec
        self._elapsed = target
        return out

    def fork(self) -> Farm:
        """An independent copy of the farm at this instant: the same robots in the same state, with the
        same random streams, so both continue with the same data until one of them is changed.

        Damage scenarios that share a healthy history fork the farm where they diverge instead of
        simulating that history once per scenario. Every part is deep-copied; the editable MuJoCo spec
        of each robot cannot be pickled and is copied with ``MjSpec.copy`` (the compiled model and its
        state are copied as they are, so a later recompile keeps the state as in the original).

        >>> farm = Farm({"p": "paper-1"}, seed=0, imu_model="ideal")
        >>> _ = farm.advance(0.5)
        >>> twin = farm.fork()
        >>> _ = twin.apply_damage("p", "imu_dead", imu="imu0")
        >>> a, b = farm.advance(0.2)["p"], twin.advance(0.2)["p"]
        >>> bool((a.q == b.q).all()), bool((a.gyro[:, 0] == b.gyro[:, 0]).all()), farm.diff("p").findings
        (True, False, ())
        """
        memo: dict[int, Any] = {id(sim.robot.spec): sim.robot.spec.copy() for sim in self._sims.values()}
        return copy.deepcopy(self, memo)

    def apply_damage(self, robot: str, kind: str, **kwargs: Any) -> Diff:
        """Damage ``robot`` now; parts left out are picked by the robot's seeded damage generator."""
        return self._sims[self._known(robot)].apply_damage(kind, **kwargs)

    def excite(
        self,
        robot: str,
        joints: Sequence[str] | None = None,
        seconds: float = 30.0,
        groups: Sequence[Sequence[str]] | None = None,
        options: PlanOptions | None = None,
    ) -> dict[str, Any]:
        """Plan an excitation of ``joints`` (None: all) for ``robot`` from its pose now, within its
        model's limits (:mod:`simulators.limits`), and have it follow the plan from now on for the
        plan's ``seconds``, then its own excitation again. Returns the plan's JSON without samples,
        with ``start`` (farm time, s) added."""
        from bodyschema.excitation_plan import plan_excitation
        from simulators.limits import robot_limits
        from simulators.planned_motion import PlannedMotion

        sim = self._sims[self._known(robot)]
        sim.sync()  # act at the last returned sample, not at the end of any read-ahead
        plan = plan_excitation(robot_limits(sim.robot), sim.robot.q(), seconds, joints, groups, options)
        base = sim.excitation.base if isinstance(sim.excitation, PlannedMotion) else sim.excitation
        sim.excitation = PlannedMotion(plan, start=sim.time, base=base).adopt(sim.robot)
        sim._ctrl_cache = (0, np.empty((0, sim.robot.model.nu)))  # commands are a new function of time
        return {**plan.to_json(samples=False), "start": sim.time}

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
