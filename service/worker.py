"""The monitoring worker: per robot, learn the body from the latest window, compare it with the
baseline, and turn lasting differences into alerts.

One cycle, for every robot the store knows:

1. read the latest ``window_seconds`` of device time (skipped when too short, and for a robot idle
   longer than ``window_seconds`` of wall time: see :meth:`Worker._idle`);
2. judge signal health (:func:`bodyschema.health.signal_health`, the baseline as layout);
3. learn the topology with the fast estimator (and with the sensor networks every
   ``network_interval_cycles`` cycles, when asked, and at once when the fast estimate's diff
   against the baseline shows a finding the previous cycle did not: ``network_on_change``), store
   each result with time and method;
4. without a baseline: adopt the fast topology once it has come out the same ``baseline_repeat_k``
   cycles in a row (an operator may also approve one, :meth:`Worker.approve_baseline`). With the
   sensor networks on (``network_interval_cycles`` > 0) they are the authority: the baseline adopted
   is the newest network topology, once it has the structure of the fast streak; until one does, the
   streak waits and a network retrain is asked for;
5. with a baseline: :func:`bodyschema.diff.diff_bodies` → :class:`service.alerts.AlertTracker`
   (hysteresis) → alerts in the store. An IMU moved to another link while the window straddles
   the move fits neither link and reads as ``imu_detached``; such a finding is judged again on the
   part of the window after the cycle that first saw the IMU displaced (all of it after the change,
   see :meth:`Worker._after_onset`), so a move raises ``imu_moved`` and a detachment
   ``imu_detached``, and never the one before the other. With the sensor networks on, a structural
   finding (:data:`~bodyschema.diff.STRUCTURAL_KINDS`) of the fast screen is only counted once the
   newest network topology, learned from a window that ended at or after the cycle that first saw it,
   also shows a structural change of that part; until then its kind is held (neither raised nor
   cleared) and a network retrain is asked for; a network topology that shows no change there drops
   it (:meth:`Worker._confirmed`). Every ``kinematics_interval_cycles`` cycles (staggered per robot),
   when the diff holds no finding, the robot's geometry is estimated
   (:func:`bodyschema.kinematics.estimate_kinematics`: joint axes, IMU lever arms): the first estimate
   under a baseline is kept as its geometry (:mod:`service.store.kinematics`), later ones are compared
   with it (:func:`bodyschema.lever_pool.stored_drift`: the two estimates' axes, turns and dead
   bands; lever arms against those of the first ``kinematics_pool_base`` estimates pooled: the mean
   of the newest ``k`` for every ``k`` up to ``kinematics_pool_recent``, down to slides smaller than
   one window's scatter) and their ``imu_rotated``,
   ``imu_shifted``, ``axis_changed`` and ``backlash`` findings join the diff; in the cycles between,
   those kinds are held (:meth:`Worker._drift`);
6. a heartbeat to the store, which ``/readyz`` checks.

The sensor-network methods run in another process when the worker is given a
:class:`~service.training.RemoteRetrains` (the service's default: a Dask cluster, docs/service.md
"Training on Dask"): the cycle only marks them wanted, submits them, and stores the results of those
that finished since the last cycle; it never waits for one. Without it they run here, in the cycle.

The worker runs in its own thread so the API and the ingest pipeline never wait for it; a failing robot
is logged and counted, and the others go on. :meth:`Worker.run_cycle` runs one cycle synchronously
(tests, the offline tools).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from bodyschema.diff import diff_bodies, is_ambiguous
from bodyschema.fast import FastOptions
from bodyschema.findings import Diff, Finding
from bodyschema.health import (
    BaselineFingerprints,
    SignalHealth,
    baseline_fingerprints,
    signal_health,
)
from bodyschema.impacts import drop_impacts
from bodyschema.lever_pool import POOL_KEY, LeverPool, stored_drift
from bodyschema.recording import Recording, RecordingError
from bodyschema.timing import lag_hinted, lag_search_centre, measured_lag
from bodyschema.topology import Topology
from service.alert_path import Waits, queue_entries, with_finish
from service.alerts import AlertTracker
from service.metrics import Metrics
from service.settings import Settings, get_settings
from service.store import Store, TopologyRecord, UnknownRobot
from service.training import RemoteRetrains
from service.worker_alerts import AlertPath, CycleResult

__all__ = [
    "FRAME_KEY",
    "HEARTBEAT_COMPONENT",
    "Compute",
    "CycleResult",
    "Estimator",
    "Worker",
    "default_estimator",
    "next_wait",
]

log = logging.getLogger(__name__)

HEARTBEAT_COMPONENT = "worker"

#: The key of a kept geometry's JSON that says whether its axes are the accelerometers' frame's
#: (``kinematics_accelerometer_frame``); absent in rows kept before it was recorded, whose were the gyros'.
FRAME_KEY = "accelerometer_frame"

#: ``(recording, method) -> Topology``; the default is :func:`bodyschema.estimate.estimate_topology`.
Estimator = Callable[[Recording, str], Topology]
#: ``compute(fn, *args, **kwargs)`` returns ``fn(*args, **kwargs)``: where the worker's other CPU-bound
#: steps (impact removal, signal health, fingerprints) run. Inline by default; the service runs them in
#: the estimator's child process (:meth:`service.estimation.EstimatorProcess.run`), off the API's
#: interpreter lock.
Compute = Callable[..., Any]


def _inline(fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
    return fn(*args, **kwargs)


def next_wait(elapsed: float, interval: float, rest: float) -> float:
    """Seconds from the end of a cycle that took ``elapsed`` to the start of the next: the next tick of
    ``interval`` after it at least ``rest`` away (ticks an overrunning cycle missed are skipped).

    >>> next_wait(2.0, 5.0, 1.0), next_wait(7.0, 5.0, 1.0), next_wait(9.5, 5.0, 1.0)
    (3.0, 3.0, 5.5)
    """
    ticks = max(1, math.ceil((elapsed + rest) / interval))
    return ticks * interval - elapsed


def default_estimator(rec: Recording, method: str, imu_delay: float | None = None) -> Topology:
    """:func:`~bodyschema.estimate.estimate_topology` timed in CPU seconds; ``imu_delay`` (s) is the
    IMUs' stated filter delay (``Settings.imu_filter_delay_ms``), taken out of the lag for the skew."""
    from bodyschema.estimate import estimate_topology  # heavy (torch) only when first needed

    return estimate_topology(rec, method=method, timer=time.process_time, imu_delay=imu_delay)


class Worker(AlertPath):
    """Learns, compares and alerts for every robot in ``store`` (see the module doc).

    ``estimator`` is injected so tests and benchmarks can swap the method; ``clock`` is the wall clock
    (alert and heartbeat times). Settings give the interval, window, K, M and the network schedule.
    ``remote``, when given, runs every method but ``fast`` on a cluster (module doc); ``compute``
    runs the other CPU-bound steps (:data:`Compute`).
    """

    def __init__(
        self,
        store: Store,
        settings: Settings | None = None,
        *,
        estimator: Estimator | None = None,
        metrics: Metrics | None = None,
        clock: Callable[[], float] = time.time,
        min_samples: int = 50,
        remote: RemoteRetrains | None = None,
        compute: Compute | None = None,
    ) -> None:
        self.store = store
        self.remote = remote
        self.compute = compute or _inline
        self.settings = settings or get_settings()
        self.estimator = estimator or functools.partial(
            default_estimator, imu_delay=self.settings.imu_filter_delay
        )
        self.metrics = metrics or Metrics()
        self.clock = clock
        self.min_samples = min_samples
        self.tracker = AlertTracker(m=self.settings.alert_hysteresis_m)
        self.cycles = 0
        self._recent: dict[str, deque[Topology]] = {}
        #: Per robot, each joint's encoder-to-gyro relation and each IMU's residual share on the
        #: baseline (learned state, :class:`~bodyschema.health.BaselineFingerprints`): set when
        #: a baseline is adopted, or, after a restart or an operator approval, from the first window
        #: that matches the baseline.
        self.fingerprints_: dict[str, BaselineFingerprints] = {}
        self._requests: dict[str, set[str]] = {}
        #: Per robot: the (kind, part) of the previous cycle's findings (see :meth:`_on_change`).
        self._findings: dict[str, frozenset[tuple[str, str]]] = {}
        #: Per (robot, kind, part): window end of the first cycle of the current run of cycles whose
        #: fast screen showed that structural finding (see :meth:`_confirmed`).
        self._first_seen: dict[tuple[str, str, str], float] = {}
        #: Per robot: wall time (``clock``) of the last network retrain asked for by the worker itself
        #: (confirmations, baselines); asked again only once a network topology newer than it is stored.
        self._network_asked: dict[str, float] = {}
        #: Per robot: window end of the cycle that first completed the current baseline streak while
        #: the networks did not agree with it (see :meth:`_maybe_baseline`).
        self._streak_since: dict[str, float] = {}
        #: Per (robot, IMU): window end of the first cycle of the current run of cycles whose diff
        #: placed the IMU elsewhere than the baseline (detached or moved); every sample after it was
        #: recorded after the change.
        self._onset: dict[tuple[str, str], float] = {}
        #: Per robot: the ``last_frame_t`` the worker last saw, and the wall time (``clock``) it first
        #: saw that value; see :meth:`_idle`.
        self._activity: dict[str, tuple[float | None, float]] = {}
        #: Per robot: the device clock epoch of the last cycle (see :meth:`_epoch_seen`).
        self._epochs: dict[str, int] = {}
        #: Per robot: the encoder-to-IMU lag (s) of its last fast topology (see :meth:`_lag_hint`).
        self._lags: dict[str, float] = {}
        #: Per robot: the id of the baseline its last cycle compared with (None: none yet); a new id
        #: (an operator approved one) makes the worker forget what it tracked against the old one.
        self._baseline_ids: dict[str, int | None] = {}
        #: Robots whose alerts were read back after a restart and are judged again on their first
        #: full window (:meth:`_restore`).
        self._rejudge: set[str] = set()
        #: Per robot: the current baseline streak's length in cycles, the window end of its first
        #: cycle, and the wall time it started waiting for the networks (see :meth:`_maybe_baseline`).
        self._streak_n: dict[str, int] = {}
        self._streak_start: dict[str, float] = {}
        self._streak_wall: dict[str, float] = {}
        #: Per robot: what it waits on, as last written to the store (:meth:`_write_waits`).
        self._waits_written: dict[str, dict[str, Any]] = {}
        #: ``time.monotonic()`` when the running cycle began (None between cycles) and the last ended.
        self._cycle_began: float | None = None
        self._cycle_ended: float | None = None
        self._lock = threading.Lock()
        self._cycle_lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self._restore()

    # ------------------------------------------------------------------------------- control
    def start(self) -> None:
        """Run cycles every ``worker_interval_seconds`` in a daemon thread."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._started = True
        self._thread = threading.Thread(target=self._loop, name="bodyhealth-worker", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        """Ask the thread to stop after the current robot and wait for it."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def died(self) -> bool:
        """The loop was started and its thread is gone (ended, or stopped): not ready. A worker that
        never started one (driven cycle by cycle) is judged by its heartbeat alone."""
        return self._started and not self.running

    def request(self, robot: str, method: str) -> None:
        """Run ``method`` for ``robot`` in the next cycle (on demand retrain), and wake the thread."""
        with self._lock:
            self._requests.setdefault(robot, set()).add(method)
        self._wake.set()

    def progress(self) -> dict[str, float | None]:
        """How the worker keeps up: seconds the running cycle has taken so far (None between cycles),
        seconds since the last cycle ended, and the interval; ``/readyz`` reports it as lag, never as
        death (a busy machine slows cycles down, it does not stop them)."""
        now = time.monotonic()
        began, ended = self._cycle_began, self._cycle_ended
        return {
            "cycle_running_s": None if began is None else round(now - began, 3),
            "since_last_cycle_s": None if ended is None else round(now - ended, 3),
            "interval_s": self.settings.worker_interval_seconds,
        }

    def training_fault(self) -> str | None:
        """Why retrains cannot run now (the cluster named), None when they can or run in this process."""
        return None if self.remote is None else self.remote.fault

    def _loop(self) -> None:
        """Cycles every interval; one that overran skips the ticks it missed, and at least
        ``worker_min_rest_seconds`` separate two cycles, so requests and the API get the interpreter
        between them. Wake-ups during a cycle (requests) coalesce into one cycle after the rest."""
        interval = self.settings.worker_interval_seconds
        rest = self.settings.worker_min_rest_seconds
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                self.run_cycle()
            except Exception:  # never let one bad cycle end monitoring
                log.exception("worker cycle failed")
            elapsed = time.monotonic() - started
            woken = self._wake.is_set()
            self._wake.clear()
            wait = rest if woken else next_wait(elapsed, interval, rest)
            if elapsed > interval:
                log.info("worker cycle overran its interval", extra={"seconds": round(elapsed, 3)})
            if self._stop.wait(rest):
                break
            self._wake.wait(max(0.0, wait - rest))
            self._wake.clear()

    # ---------------------------------------------------------------------------- baselines
    def approve_baseline(self, robot: str, topo: Topology | None = None) -> TopologyRecord:
        """Make ``topo`` (default: the newest fast topology) the robot's baseline, by operator decision.

        Open alerts of the robot are resolved: they were differences to the old baseline. The store does
        both in one transaction of its own (:meth:`~service.store.Store.approve_baseline`), without the
        cycle lock, so the request never waits for a cycle; the worker sees the new baseline's id in
        its next cycle and forgets what it tracked against the old one (:meth:`_baseline_seen`; a
        cycle running now drops what it found against the old one). Raises
        :class:`~service.store.UnknownRobot`, or ``LookupError`` when nothing was learned yet.
        """
        base = self.store.approve_baseline(robot, topo, source="operator", wall_time=self.clock())
        self.tracker.forget(robot)
        self.fingerprints_.pop(robot, None)
        self._wake.set()
        log.info("baseline approved", extra={"robot": robot, "source": "operator"})
        return base

    def _restore(self) -> None:
        """Pick up open alerts after a restart so they are neither raised twice nor left dangling: each
        is judged again on its robot's first full window (confirmed, or resolved then)."""
        try:
            for a in [*self.store.alerts(state="pending"), *self.store.alerts(active=True)]:
                pending = a.state == "pending"
                f = [Finding.from_json(a.finding)]
                self.tracker.restore(a.robot, f, pending=pending, since=a.raised_at, confirmed=a.confirmed)
                self._rejudge.add(a.robot)
        except Exception:
            log.exception("could not restore open alerts")

    def _baseline_seen(self, robot: str, base: TopologyRecord | None) -> None:
        """Forget what was tracked for ``robot`` against a baseline that is no longer current (an
        operator approved another since the last cycle): its alerts were resolved with it."""
        bid = None if base is None else base.id
        if robot in self._baseline_ids and self._baseline_ids[robot] != bid:
            self.tracker.forget(robot)
            self.fingerprints_.pop(robot, None)
            self._onset = {k: v for k, v in self._onset.items() if k[0] != robot}
            self._first_seen = {k: v for k, v in self._first_seen.items() if k[0] != robot}
            self._findings.pop(robot, None)
            self._rejudge.discard(robot)
            log.info("new baseline seen: tracking starts over", extra={"robot": robot, "baseline_id": bid})
        self._baseline_ids[robot] = bid

    # -------------------------------------------------------------------------------- cycle
    def run_cycle(self) -> dict[str, CycleResult]:
        """One pass over every robot; returns what happened per robot."""
        t0 = time.perf_counter()
        out: dict[str, CycleResult] = {}
        with self._cycle_lock:
            self._cycle_began = time.monotonic()
            self.cycles += 1
            self.store.heartbeat(HEARTBEAT_COMPONENT, self.clock())
            self._collect_retrains()
            robots = self.store.robots()
            self.metrics.robots.set(len(robots))
            for info in robots:
                if self._stop.is_set():
                    break
                self._epoch_seen(info.name, info.epoch)
                if self._idle(info.name, info.last_frame_t):
                    out[info.name] = CycleResult(info.name, skipped="idle: no new frame within the window")
                    continue
                try:
                    out[info.name] = self._robot_cycle(info.name, info.imus)
                except UnknownRobot:
                    continue
                except Exception:
                    self.metrics.cycle_errors.inc()
                    log.exception("worker cycle failed for robot", extra={"robot": info.name})
            for info in robots:
                try:
                    n = len(self.store.alerts(info.name, active=True))
                except UnknownRobot:
                    continue
                self.metrics.alerts_active.labels(robot=info.name).set(n)
            self._submit_retrains()
            self.store.heartbeat(HEARTBEAT_COMPONENT, self.clock())
            self._cycle_began, self._cycle_ended = None, time.monotonic()
        seconds = time.perf_counter() - t0
        self.metrics.cycles.inc()
        self.metrics.cycle_seconds.observe(seconds)
        log.debug(
            "worker cycle", extra={"cycle": self.cycles, "robots": len(out), "seconds": round(seconds, 3)}
        )
        return out

    def _collect_retrains(self) -> None:
        """Store the cluster retrains that finished since the last cycle (never waits for one)."""
        if self.remote is None:
            return
        try:
            self.remote.collect(self.clock)
        except Exception:
            self.metrics.cycle_errors.inc()
            log.exception("collecting retrains failed")

    def _submit_retrains(self) -> None:
        """Hand the wanted retrains to the cluster; without one they wait (ingest and the API never do)."""
        if self.remote is None:
            return
        try:
            self.remote.submit_wanted()
        except Exception:
            self.metrics.cycle_errors.inc()
            log.exception("submitting retrains failed")

    def _epoch_seen(self, robot: str, epoch: int) -> None:
        """Forget the device times remembered for ``robot`` when its clock went back (a new epoch,
        :mod:`service.store.frames`): an onset stamped on the old clock would lie in the new clock's
        future and hold the IMU's finding forever. The fingerprints go too: a restarted robot's
        encoders may count from other offsets, and no finding may come from comparing windows across
        the restart; they are learned again from the first window that matches the baseline. Alerts
        stay; the first full window of the new epoch confirms or resolves them."""
        if self._epochs.get(robot, epoch) != epoch:
            self._onset = {k: v for k, v in self._onset.items() if k[0] != robot}
            self._first_seen = {k: v for k, v in self._first_seen.items() if k[0] != robot}
            self._lags[robot] = 0.0
            self.fingerprints_.pop(robot, None)
            self.tracker.rejudge(robot)
            self._rejudge.add(robot)
            log.info(
                "device clock went back: analysing the new epoch", extra={"robot": robot, "epoch": epoch}
            )
        self._epochs[robot] = epoch

    def _idle(self, robot: str, last_frame_t: float | None) -> bool:
        """True when ``robot``'s last frame has not moved for more than ``window_seconds`` of wall time
        and nothing was asked for it. Its window is then the one already judged: estimating it again
        costs a full estimate per cycle and learns nothing, so the robot waits, alerts as they stand,
        until frames arrive (its ``last_frame_t`` moves) or a retrain is requested."""
        now = self.clock()
        seen = self._activity.get(robot)
        if seen is None or seen[0] != last_frame_t:
            self._activity[robot] = (last_frame_t, now)
            return False
        with self._lock:
            if self._requests.get(robot):
                return False
        return now - seen[1] > self.settings.window_seconds

    def _methods(self, robot: str) -> list[str]:
        methods = ["fast"]
        n = self.settings.network_interval_cycles
        if n and self.cycles % n == 0:
            methods.append("network")
        with self._lock:
            for m in sorted(self._requests.pop(robot, set())):
                if m not in methods:
                    methods.append(m)
        return methods

    def _robot_cycle(self, robot: str, expected_imus: list[str]) -> CycleResult:
        res = CycleResult(robot)
        rec = self.store.read_window(robot, self.settings.window_seconds)
        if rec is None or rec.n_samples < self.min_samples or rec.q is None:
            res.skipped = "not enough data in the window"
            return res
        base = self.store.baseline(robot)
        self._baseline_seen(robot, base)
        layout = base.topology if base is not None else None
        window_end = float(rec.t[-1])
        fast: Topology | None = None
        # velocity jumps at stops read as contradictions to the estimators
        learn = self.compute(drop_impacts, rec)
        hint = self._lag_hint(robot)
        for method in self._methods(robot):
            if method != "fast" and self.remote is not None:
                self.remote.want(robot, method)  # submitted at the end of the cycle, stored when done
                continue
            t0 = time.perf_counter()
            topo = self._estimate(learn, method, hint)
            self.metrics.retrain_seconds.labels(method=method).observe(time.perf_counter() - t0)
            self.store.save_topology(robot, topo, self.clock(), window_end)
            res.methods.append(method)
            if method == "fast":
                fast = topo
        if fast is None:
            return res
        lag = measured_lag(fast)
        if lag is not None:
            self._lags[robot] = lag
        res.health = self.compute(
            signal_health,
            rec,
            layout,
            expected_imus,
            current=fast,
            fingerprints=fp.joints if (fp := self.fingerprints_.get(robot)) else None,
            imu_fingerprints=fp.imus if fp else None,
        )
        res.topology = fast
        if fast.excitation:
            self.store.set_excitation(robot, fast.excitation)
        waits = Waits(queue=with_finish(queue_entries(self.remote, robot), self.clock()))
        full = rec.duration >= 0.8 * self.settings.window_seconds
        if base is None:
            res.baseline_set = full and self._maybe_baseline(robot, fast, res.health, window_end)
            if not res.baseline_set and robot in self._streak_wall:
                n, need = self._streak_n.get(robot, 0), self.settings.baseline_unconfirmed_cycles
                later = f", adopted unconfirmed after {need} cycles" if need else ""
                what = (
                    f"baseline: the sensor networks' answer (the fast screen's body held {n} cycles{later})"
                )
                waits.add(what, self._streak_wall[robot])
            self._write_waits(robot, waits)
            return res
        res.diff = diff_bodies(base.topology, fast, res.health)
        self._on_change(robot, res.diff)
        if robot not in self.fingerprints_ and not res.diff.findings:
            self.fingerprints_[robot] = self.compute(baseline_fingerprints, rec, base.topology, current=fast)
        self._judge_alerts(robot, res, (rec, learn), base, waits, full and not is_ambiguous(fast))
        self._write_waits(robot, waits)
        return res

    def _lag_hint(self, robot: str) -> float:
        """Where to centre the search for ``robot``'s encoder-to-IMU lag (s): the lag last measured, when
        it lies more than half the search range (``FastOptions.max_lag``) from zero; else 0, the search
        as it is. From the newest stored fast topology after a restart; 0 after the device clock went
        back (:meth:`_epoch_seen`: the clocks may have restarted apart)."""
        if robot not in self._lags:
            self._lags[robot] = self.store.last_lag(robot)
        return lag_search_centre(self._lags[robot], FastOptions.max_lag)

    def _estimate(self, rec: Recording, method: str, hint: float) -> Topology:
        """``self.estimator`` on ``rec``, its encoder stamps moved by the lag ``hint`` (s) and the move put
        back into the timing reported (:func:`bodyschema.timing.encoders_moved`): a lag that drifted
        past the search range stays in it."""
        return lag_hinted(lambda r: self.estimator(r, method), rec, hint)

    def _drift(
        self, robot: str, rec: Recording, fast: Topology, base: TopologyRecord, diff: Diff, window_end: float
    ) -> tuple[tuple[Finding, ...], bool] | None:
        """Geometry drift of ``robot`` against the geometry learned on its baseline (module doc, 5), and
        whether its lever arms were judged (the baseline's pool is full); None when this cycle does not
        judge it (not its turn, the body differs from the baseline, or
        no geometry is kept yet: then this one is kept, once an IMU's axis converged). A judged
        estimate is kept as the robot's newest geometry, the one the API serves beside the baseline's;
        its lever arms join the baseline's pool until that holds ``kinematics_pool_base`` estimates,
        then the newest's pool of the last ``kinematics_pool_recent`` (both kept in the store, so a
        restart neither forgets the baseline's lever arms nor compares them with the slid ones).

        Every ``kinematics_interval_cycles`` cycles per robot, staggered by the robot's name so a fleet's
        estimates spread over the cycles; on the raw window (the estimate band-limits its signals, and
        the impact removal's gaps would break its filters), on the baseline's tree with this window's
        encoder timing. The baseline's tree, not this cycle's fast one: the diff holding no finding
        says the body is the baseline's, while a fault the geometry is there to find (a dead band's
        encoder steps) can leave the fast screen unable to place a joint's IMUs at all.
        """
        n = self.settings.kinematics_interval_cycles
        if not n or (self.cycles + zlib.crc32(robot.encode())) % n:
            return None
        if diff.findings:
            return None  # another body: its geometry is not the baseline's
        from bodyschema.kinematics import KinematicsOptions, estimate_kinematics

        t0 = time.perf_counter()
        frame = self.settings.kinematics_accelerometer_frame
        tree = dataclasses.replace(base.topology, timing=dict(fast.timing))
        kin = self.compute(estimate_kinematics, rec, tree, KinematicsOptions(accelerometer_frame=frame))
        self.metrics.retrain_seconds.labels(method="kinematics").observe(time.perf_counter() - t0)
        kept = self.store.kinematics_baseline(robot, base.id)
        # a geometry kept in the other frame (or before the frame was recorded: the gyros') has lever
        # arms fitted about other axes, a mm or so apart: compared with these it would read as a slide
        if kept is None or bool(kept.data.get(FRAME_KEY, False)) != frame:
            if any(k.axis_converged for k in kin.imus.values()):
                data = {**kin.to_json(), POOL_KEY: LeverPool().add(kin).to_json(), FRAME_KEY: frame}
                if kept is None:
                    self.store.save_kinematics(
                        robot, base.id, data, wall_time=self.clock(), window_end_t=window_end
                    )
                else:  # in the kept row's place, and as the newest, whose pool of the other frame goes
                    self.store.update_kinematics(
                        kept.id, data, wall_time=self.clock(), window_end_t=window_end
                    )
                    self.store.save_kinematics(
                        robot,
                        base.id,
                        {**kin.to_json(), POOL_KEY: []},
                        wall_time=self.clock(),
                        window_end_t=window_end,
                        latest=True,
                    )
                log.info(
                    "geometry baseline kept" + ("" if kept is None else " again, in the frame now set"),
                    extra={"robot": robot, "baseline_id": base.id},
                )
            return None
        pools = self.settings.pool_options
        first = dict(kept.data)
        pool = LeverPool.from_json(first.get(POOL_KEY))
        recent = LeverPool()
        if pool.n < pools.n_base:  # the baseline's pool fills first; slides are judged once it is full
            first[POOL_KEY] = pool.add(kin).to_json()
            self.store.update_kinematics(kept.id, first)
        else:
            newest = self.store.kinematics_latest(robot, base.id)
            if newest is not None and newest.id != kept.id:
                recent = LeverPool.from_json(newest.data.get(POOL_KEY))
            recent = recent.add(kin, keep=pools.n_recent)
        latest = {**kin.to_json(), POOL_KEY: recent.to_json()}
        self.store.save_kinematics(
            robot, base.id, latest, wall_time=self.clock(), window_end_t=window_end, latest=True
        )
        return stored_drift(first, latest, base.topology, pools), recent.n > 0

    @property
    def networks_on(self) -> bool:
        """True when the sensor networks run on a schedule: they are then the authority for baselines
        and structural alerts, and the fast method the screen."""
        return self.settings.network_interval_cycles > 0

    def _ask_network(self, robot: str, net: TopologyRecord | None, since: float, why: str) -> None:
        """Ask for a network retrain of ``robot``, unless the networks have already learned a window
        that ended at or after ``since`` (device time; their answer stands until the schedule's next
        retrain) or one the worker asked for is still to come (no network topology stored since).
        ``net`` is the robot's newest network topology, as the caller read it."""
        if net is not None and net.window_end_t is not None and net.window_end_t >= since:
            return
        asked = self._network_asked.get(robot)
        if asked is not None and (net is None or net.wall_time < asked):
            return
        self._network_asked[robot] = self.clock()
        log.info("network retrain asked: %s", why, extra={"robot": robot})
        self._want_network(robot)

    def _want_network(self, robot: str) -> None:
        """A network retrain of ``robot``: on the cluster when there is one, else in the next cycle."""
        if self.remote is not None:
            self.remote.want(robot, "network")
        else:
            with self._lock:
                self._requests.setdefault(robot, set()).add("network")

    def _on_change(self, robot: str, diff: Diff) -> None:
        """Ask for a network retrain of ``robot`` when the fast screen's diff holds a finding the
        previous cycle's did not (``Settings.network_on_change``): the fast method is the screen, the
        networks learn the body the finding is about. Once per new finding, not per cycle it lasts:
        a retrain costs tens of CPU seconds, the screen one."""
        seen = frozenset((f.kind, f.part) for f in diff.findings)
        new = seen - self._findings.get(robot, frozenset())
        self._findings[robot] = seen
        if not new or not self.settings.network_on_change or not self.networks_on:
            return
        log.info(
            "network retrain asked: the fast screen found a change",
            extra={"robot": robot, "findings": sorted(f"{k} {p}" for k, p in new)},
        )
        self._want_network(robot)

    def _after_onset(
        self, robot: str, rec: Recording, diff: Diff, baseline: Topology
    ) -> tuple[Diff, tuple[str, ...]]:
        """Judge each ``imu_detached`` finding on the data recorded after its onset.

        The onset of an IMU's displacement is the end of the first window (of the current run of
        cycles) whose diff placed it elsewhere than the baseline: every later sample was recorded
        after the change. A window that straddles an IMU's move holds both of its placements; the
        joint-velocity model of either link fits only part of it, so the estimate on the whole window
        follows no joint, the same answer a detached IMU gives. Only the part after the onset says
        which it is, and the window's own estimate is trusted again once it starts after the onset.
        Until then, per detached IMU, one fast estimate of the post-onset part (shared by IMUs with the
        same onset, paid only while a detachment is reported and the window straddles it):

        * no post-onset data yet, or an estimate that is not unique: the finding is held (neither
          raised nor counted as gone);
        * the IMU follows no joint there either: the detachment stands;
        * it follows another joint: the finding becomes ``imu_moved`` to that joint;
        * it follows its baseline joint again: the finding is held (the estimate of the next windows
          decides whether anything changed at all).

        Returns the diff to track and the kinds to hold.
        """
        window_end, window_start = float(rec.t[-1]), float(rec.t[0])
        displaced = {f.imu for f in diff.findings if f.kind in ("imu_detached", "imu_moved") and f.imu}
        for key in [k for k in self._onset if k[0] == robot and k[1] not in displaced]:
            del self._onset[key]
        for imu in displaced:
            self._onset.setdefault((robot, imu), window_end)
        findings: list[Finding] = []
        held = False
        estimates: dict[float, Topology | None] = {}
        for f in diff.findings:
            since = self._onset.get((robot, f.imu or ""), window_start)
            if f.kind != "imu_detached" or since <= window_start:
                findings.append(f)
                continue
            if since not in estimates:
                estimates[since] = self._estimate_after(rec, since)
            topo = estimates[since]
            if topo is None or is_ambiguous(topo) or f.imu not in topo.imu_joint:
                held = True
                continue
            now = topo.imu_joint[f.imu]
            if now is None:
                findings.append(f)
            elif now != baseline.imu_joint.get(f.imu):
                conf = float(topo.confidence.get(f"imu:{f.imu}", 1.0))
                findings.append(Finding("imu_moved", imu=f.imu, from_=f.from_, to=now, confidence=conf))
            else:
                held = True
        return Diff(findings=tuple(findings), reasons=diff.reasons), (
            "imu_detached",
            "imu_moved",
        ) if held else ()

    def _estimate_after(self, rec: Recording, since: float) -> Topology | None:
        """The fast estimate of the part of ``rec`` after ``since`` (None: too little data there)."""
        if float(rec.t[-1]) <= since:
            return None
        try:
            after = rec.window(since, np.inf)
        except RecordingError:  # the streams do not overlap yet
            return None
        if after.n_samples < self.min_samples or after.duration <= 0:
            return None
        return self.estimator(after, "fast")

    def _break_streak(self, robot: str) -> None:
        """End ``robot``'s baseline streak: its topologies, length, start, and when it first waited for
        the networks."""
        self._recent.get(robot, deque()).clear()
        for kept in (self._streak_since, self._streak_n, self._streak_start, self._streak_wall):
            kept.pop(robot, None)

    def _maybe_baseline(self, robot: str, topo: Topology, health: SignalHealth, window_end: float) -> bool:
        """Adopt ``topo`` once K consecutive cycles learned the same structure from healthy signals."""
        k = self.settings.baseline_repeat_k
        recent = self._recent.setdefault(robot, deque(maxlen=k))
        # Only a trustworthy body becomes the reference: every IMU alive, one tree that fits (unique),
        # every joint placed and moving in this window (a still joint cannot be told from a locked
        # one later).
        still = [j for j, h in health.joints.items() if not (h.encoder_moving or h.link_moving)]
        if is_ambiguous(topo):
            return False  # no information either way: the streak neither grows nor breaks
        if health.dead_imus or topo.undetermined or still or not topo.joint_parent:
            self._break_streak(robot)
            return False
        if recent and not (recent[-1].same_structure(topo) and recent[-1].undetermined == topo.undetermined):
            self._break_streak(robot)
        recent.append(topo)
        self._streak_start.setdefault(robot, window_end)
        self._streak_n[robot] = self._streak_n.get(robot, 0) + 1
        if len(recent) < k:
            return False
        net, source = None, "auto"
        if self.networks_on:
            net = self.store.latest_topology(robot, method="network")
            if net is None or is_ambiguous(net.topology) or not net.topology.same_structure(topo):
                # the networks are the authority: the streak waits (it stays complete) for a network
                # topology of the same body; asked for once per streak, then the schedule's retrains
                since = self._streak_since.setdefault(robot, window_end)
                self._streak_wall.setdefault(robot, self.clock())
                self._ask_network(robot, net, since, "a baseline needs the sensor networks' agreement")
                if not self._networks_late(robot, net):
                    return False
                # ... unless they are late: the fast body that held this long is adopted, marked so
                net, source = None, "fast-unconfirmed"
            else:
                topo = net.topology
        base_id = self.store.set_baseline(
            robot, topo, source, wall_time=self.clock(), window_end_t=window_end
        )
        if net is not None:  # the weights that learned this baseline are its weights
            self.store.adopt_network_weights(
                robot, "network", window_end_t=net.window_end_t, baseline_id=base_id
            )
        self.fingerprints_.pop(robot, None)  # learned from the next window that matches it
        self._baseline_ids[robot] = base_id  # the worker's own: nothing tracked to forget
        n = self._streak_n.get(robot, k)
        self._break_streak(robot)
        log.log(
            logging.INFO if source == "auto" else logging.WARNING,
            "baseline learned"
            if source == "auto"
            else "baseline adopted unconfirmed: the sensor networks are late",
            extra={"robot": robot, "source": source, "repeats": n},
        )
        return True
