"""The robot's geometry compared with the one learned on its baseline (the worker's step 5).

Every ``kinematics_interval_cycles`` cycles (staggered per robot), or sooner when that many worker
intervals of wall time have passed since its last estimate, when the diff holds no finding, the
robot's geometry is estimated (:func:`bodyschema.kinematics.estimate_kinematics`: joint axes, IMU lever
arms). The first estimate under a baseline is kept as its geometry (:mod:`service.store.kinematics`);
later ones are compared with it (:func:`bodyschema.lever_pool.stored_drift`), their lever arms against
those of the first ``kinematics_pool_base`` estimates pooled.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import zlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from bodyschema.findings import Diff, Finding
from bodyschema.lever_pool import POOL_KEY, LeverPool, stored_drift
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.metrics import Metrics
from service.monitor.state import RobotState, full_window
from service.settings import Settings
from service.store import Store, TopologyRecord

if TYPE_CHECKING:
    from bodyschema.kinematics import Kinematics

__all__ = ["FRAME_KEY", "MAX_HOLE_SECONDS", "GeometryDrift"]

log = logging.getLogger("service.worker")

#: The key of a kept geometry's JSON that says whether its axes are the accelerometers' frame's
#: (``kinematics_accelerometer_frame``); absent in rows kept before it was recorded, whose were the gyros'.
FRAME_KEY = "accelerometer_frame"
#: The longest pause between two samples of one stream in a window the geometry is judged on: every
#: transport samples at 10 Hz or faster, so a longer hole is lost frames or a restarted source.
MAX_HOLE_SECONDS = 0.5


class GeometryDrift:
    """Estimates a robot's geometry on its turn and judges it against its baseline's (module doc).
    ``compute(fn, *args)`` runs the estimate (:data:`service.worker.Compute`); ``state(robot)`` is what
    the worker keeps for the robot (its last estimate's cycle and window end)."""

    def __init__(
        self,
        store: Store,
        settings: Settings,
        metrics: Metrics,
        compute: Callable[..., Any],
        clock: Callable[[], float],
        state: Callable[[str], RobotState],
    ) -> None:
        self.store = store
        self.settings = settings
        self.metrics = metrics
        self.compute = compute
        self.clock = clock
        self.state = state

    def turn(self, robot: str, cycle: int, window_end: float) -> bool:
        """True when ``robot``'s geometry is due: ``kinematics_interval_cycles`` cycles after its last
        estimate, or once its data has advanced that many worker intervals past the last estimate's
        window. On a loaded machine, whose cycles overrun their interval, the robot's data still comes
        in real time, so each estimate comes an interval's worth of data after the last instead of
        waiting for slow cycles, and damage to the geometry is seen as soon as on a quiet one. Data
        time, not the wall clock: a replay or a test that feeds data faster or slower than real time
        gets the same estimates for the same data. The first (and the first after the robot's clock
        went back) is staggered by the robot's name so a fleet's estimates spread over the cycles."""
        n = self.settings.kinematics_interval_cycles
        if not n:
            return False
        last = self.state(robot).geometry_last
        if last is None or window_end < last[1]:
            return (cycle + zlib.crc32(robot.encode())) % n == 0
        span = n * self.settings.worker_interval_seconds
        return cycle - last[0] >= n or window_end - last[1] >= span - 1e-9

    def judge(
        self, robot: str, cycle: int, rec: Recording, fast: Topology, base: TopologyRecord, diff: Diff
    ) -> tuple[tuple[Finding, ...], bool] | None:
        """Geometry drift of ``robot`` against the geometry learned on its baseline, and whether its
        lever arms were judged (the baseline's pool is full); None when this cycle does not judge it
        (not its turn, the body differs from the baseline, or no geometry is kept yet: then this one is
        kept, once an IMU's axis converged). A judged estimate is kept as the robot's newest geometry,
        the one the API serves beside the baseline's; its lever arms join the baseline's pool until
        that holds ``kinematics_pool_base`` estimates, then the newest's pool of the last
        ``kinematics_pool_recent`` (both kept in the store, so a restart neither forgets the baseline's
        lever arms nor compares them with the slid ones).

        On the robot's turn (:meth:`turn`); on the raw window (the estimate band-limits its
        signals, and the impact removal's gaps would break its filters), on the baseline's tree with
        this window's encoder timing. The baseline's tree, not this cycle's fast one: the diff holding
        no finding says the body is the baseline's, while a fault the geometry is there to find (a dead
        band's encoder steps) can leave the fast screen unable to place a joint's IMUs at all.
        """
        window_end = float(rec.t[-1]) if len(rec.t) else 0.0
        if not self.turn(robot, cycle, window_end):
            return None
        if not self.one_motion(rec):
            return None  # a partial window or one with a hole: not the motion the geometry was learned on
        if diff.findings:
            return None  # another body: its geometry is not the baseline's
        from bodyschema.kinematics import KinematicsOptions, estimate_kinematics

        t0 = time.perf_counter()
        self.state(robot).geometry_last = (cycle, window_end)
        frame = self.settings.kinematics_accelerometer_frame
        tree = dataclasses.replace(base.topology, timing=dict(fast.timing))
        kin = self.compute(estimate_kinematics, rec, tree, KinematicsOptions(accelerometer_frame=frame))
        self.metrics.retrain_seconds.labels(method="kinematics").observe(time.perf_counter() - t0)
        kept = self.store.kinematics_baseline(robot, base.id)
        # a geometry kept in the other frame (or before the frame was recorded: the gyros') has lever
        # arms fitted about other axes, a mm or so apart: compared with these it would read as a slide
        if kept is None or bool(kept.data.get(FRAME_KEY, False)) != frame:
            self._keep_first(robot, base, kin, kept, window_end)
            return None
        return self._compare(robot, base, kin, dict(kept.data), kept.id, window_end)

    def one_motion(self, rec: Recording) -> bool:
        """True when ``rec`` is one stretch of motion as long as the baseline's geometry windows: a full
        window (:func:`~service.monitor.state.full_window`) and no hole over :data:`MAX_HOLE_SECONDS`.
        The geometry's error model is that of a full window; after a restart (a new clock epoch, or
        frames lost while the service was down) the first windows are short or hold a hole, and an
        estimate on them is not comparable with it."""
        if not full_window(rec, self.settings.window_seconds):
            return False
        stamps = [rec.t] if rec.t_q is None else [rec.t, rec.t_q]
        return all(len(t) < 2 or float(np.max(np.diff(t))) <= MAX_HOLE_SECONDS for t in stamps)

    def _keep_first(
        self, robot: str, base: TopologyRecord, kin: Kinematics, kept: Any, window_end: float
    ) -> None:
        """Keep ``kin`` as the baseline's geometry (in ``kept``'s place when one of the other frame is
        kept: it also becomes the newest, whose pool of the other frame goes), once an IMU's axis
        converged."""
        if not any(k.axis_converged for k in kin.imus.values()):
            return
        frame = self.settings.kinematics_accelerometer_frame
        data = {**kin.to_json(), POOL_KEY: LeverPool().add(kin).to_json(), FRAME_KEY: frame}
        if kept is None:
            self.store.save_kinematics(robot, base.id, data, wall_time=self.clock(), window_end_t=window_end)
        else:
            self.store.update_kinematics(kept.id, data, wall_time=self.clock(), window_end_t=window_end)
            newest = {**kin.to_json(), POOL_KEY: []}
            self.store.save_kinematics(
                robot, base.id, newest, wall_time=self.clock(), window_end_t=window_end, latest=True
            )
        log.info(
            "geometry baseline kept" + ("" if kept is None else " again, in the frame now set"),
            extra={"robot": robot, "baseline_id": base.id},
        )

    def _compare(
        self,
        robot: str,
        base: TopologyRecord,
        kin: Kinematics,
        first: dict[str, Any],
        kept_id: int,
        window_end: float,
    ) -> tuple[tuple[Finding, ...], bool]:
        """``kin`` against the kept geometry ``first``: its lever arms fill the baseline's pool first,
        slides are judged once that is full."""
        pools = self.settings.pool_options
        pool = LeverPool.from_json(first.get(POOL_KEY))
        recent = LeverPool()
        if pool.n < pools.n_base:
            first[POOL_KEY] = pool.add(kin).to_json()
            self.store.update_kinematics(kept_id, first)
        else:
            newest = self.store.kinematics_latest(robot, base.id)
            if newest is not None and newest.id != kept_id:
                recent = LeverPool.from_json(newest.data.get(POOL_KEY))
            recent = recent.add(kin, keep=pools.n_recent)
        latest = {**kin.to_json(), POOL_KEY: recent.to_json()}
        self.store.save_kinematics(
            robot, base.id, latest, wall_time=self.clock(), window_end_t=window_end, latest=True
        )
        return stored_drift(first, latest, base.topology, pools), recent.n > 0
