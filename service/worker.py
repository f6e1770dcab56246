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
   see :func:`service.monitor.onset.after_onset`), so a move raises ``imu_moved`` and a detachment
   ``imu_detached``, and never the one before the other. With the sensor networks on, a structural
   finding (:data:`~bodyschema.diff.STRUCTURAL_KINDS`) of the fast screen is only counted once the
   newest network topology, learned from a window that ended at or after the cycle that first saw it,
   also shows a structural change of that part; until then its kind is held (neither raised nor
   cleared) and a network retrain is asked for; a network topology that shows no change there drops
   it (:func:`service.monitor.confirmation.confirm`). Every ``kinematics_interval_cycles`` cycles
   (staggered per robot; sooner once its data ran N intervals, when cycles overrun), when the diff
   holds no finding, the robot's geometry is estimated
   (:func:`bodyschema.kinematics.estimate_kinematics`: joint axes, IMU lever arms): the first estimate
   under a baseline is kept as its geometry (:mod:`service.store.kinematics`), later ones are compared
   with it (:func:`bodyschema.lever_pool.stored_drift`: the two estimates' axes, turns and dead
   bands; lever arms against those of the first ``kinematics_pool_base`` estimates pooled: the mean
   of the newest ``k`` for every ``k`` up to ``kinematics_pool_recent``, down to slides smaller than
   one window's scatter) and their ``imu_rotated``,
   ``imu_shifted``, ``axis_changed`` and ``backlash`` findings join the diff; in the cycles between,
   those kinds are held (:mod:`service.monitor.drift`);
6. a heartbeat to the store, which ``/readyz`` checks.

The sensor-network methods run in another process when the worker is given a
:class:`~service.retrain.RemoteRetrains` (the service's default: a Dask cluster, docs/service.md
"Training on Dask"): the cycle only marks them wanted, submits them, and stores the results of those
that finished since the last cycle; it never waits for one. Without it they run here, in the cycle.

The steps live in :mod:`service.monitor` (one module each) and in :mod:`service.worker_alerts`; what the
worker remembers per robot is one :class:`~service.monitor.state.RobotState`, whose ``reset`` says what a
new baseline, a new device-clock epoch and a restart forget. This module is the loop and the wiring.

The worker runs in its own thread so the API and the ingest pipeline never wait for it; a failing robot
is logged and counted, and the others go on. :meth:`Worker.run_cycle` runs one cycle synchronously
(tests, the offline tools).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from bodyschema.diff import diff_bodies, is_ambiguous
from bodyschema.findings import Finding
from bodyschema.health import BaselineFingerprints, baseline_fingerprints, signal_health
from bodyschema.recording import Recording
from bodyschema.timing import LagHint, measured_lag
from bodyschema.topology import Topology
from service.alert_path import Waits, queue_entries
from service.alerts import AlertTracker
from service.estimation import default_estimator
from service.metrics import Metrics
from service.monitor.baseline import BaselineAdoption
from service.monitor.confirmation import NetworkAsks
from service.monitor.drift import FRAME_KEY, GeometryDrift
from service.monitor.floating import FloatingBase
from service.monitor.onset import estimate_after
from service.monitor.state import RobotState, full_window
from service.retrain import RemoteRetrains
from service.settings import Settings, get_settings
from service.store import Store, TopologyRecord, UnknownRobot
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
            default_estimator,
            imu_delay=self.settings.imu_filter_delay,
            heldout_check=self.settings.network_heldout_check,
        )
        self.metrics = metrics or Metrics()
        self.clock = clock
        self.min_samples = min_samples
        self.tracker = AlertTracker(m=self.settings.alert_hysteresis_m)
        self.cycles = 0
        #: Per robot, everything the worker remembers between cycles (:mod:`service.monitor.state`).
        self._states: dict[str, RobotState] = {}
        self.asks = NetworkAsks(self.settings, clock, self._want_network)
        self.adoption = BaselineAdoption(store, self.settings, clock, self.asks)
        self.geometry = GeometryDrift(store, self.settings, self.metrics, self.compute, clock, self.state)
        self.floating = FloatingBase(
            store, self.settings, self.tracker, clock, self._store_alerts, self._write_waits, min_samples
        )
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

    def state(self, robot: str) -> RobotState:
        """What the worker keeps for ``robot`` (a new state for a robot it has not seen)."""
        st = self._states.get(robot)
        if st is None:
            st = self._states.setdefault(robot, RobotState())
        return st

    @property
    def fingerprints_(self) -> dict[str, BaselineFingerprints]:
        """Per robot, the fingerprints learned on its baseline (``RobotState.fingerprints``)."""
        return {r: st.fingerprints for r, st in self._states.items() if st.fingerprints is not None}

    @fingerprints_.setter
    def fingerprints_(self, value: dict[str, BaselineFingerprints]) -> None:
        for robot in {*self._states, *value}:
            self.state(robot).fingerprints = value.get(robot)

    @property
    def _requests(self) -> dict[str, set[str]]:
        """Per robot, the methods asked for and not yet run."""
        with self._lock:
            return {r: set(st.requests) for r, st in self._states.items() if st.requests}

    # ------------------------------------------------------------------------------- control
    def start(self) -> None:
        """Run cycles every ``worker_interval_seconds`` in a daemon thread."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._started = True
        self._thread = threading.Thread(target=self._loop, name="bodyhealth-worker", daemon=True)
        self._thread.start()

    def request_stop(self) -> None:
        """Ask the thread to stop after the current robot, without waiting for it."""
        self._stop.set()
        self._wake.set()

    def stop(self, timeout: float = 30.0) -> None:
        """Ask the thread to stop after the current robot and wait for it."""
        self.request_stop()
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

    @property
    def networks_on(self) -> bool:
        """True when the sensor networks run on a schedule: they are then the authority for baselines
        and structural alerts, and the fast method the screen."""
        return self.asks.networks_on

    def request(self, robot: str, method: str) -> None:
        """Run ``method`` for ``robot`` in the next cycle (on demand retrain), and wake the thread."""
        with self._lock:
            self.state(robot).requests.add(method)
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
        self.state(robot).reset("approval")
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
                self.state(a.robot).reset("restart")
        except Exception:
            log.exception("could not restore open alerts")

    def _baseline_seen(self, robot: str, st: RobotState, base: TopologyRecord | None) -> None:
        """Forget what was tracked for ``robot`` against a baseline that is no longer current (an
        operator approved another since the last cycle): its alerts were resolved with it."""
        bid = None if base is None else base.id
        if st.baseline_known and st.baseline_id != bid:
            self.tracker.forget(robot)
            st.reset("baseline")
            log.info("new baseline seen: tracking starts over", extra={"robot": robot, "baseline_id": bid})
        st.baseline_id, st.baseline_known = bid, True

    def _epoch_seen(self, robot: str, epoch: int) -> None:
        """Forget the device times remembered for ``robot`` when its clock went back (a new epoch,
        :mod:`service.store.frames`; what it forgets: :mod:`service.monitor.state`). Alerts stay; the
        first full window of the new epoch confirms or resolves them."""
        st = self.state(robot)
        if st.epoch is not None and st.epoch != epoch:
            st.reset("epoch")
            self.tracker.rejudge(robot)
            log.info(
                "device clock went back: analysing the new epoch", extra={"robot": robot, "epoch": epoch}
            )
        st.epoch = epoch

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
                    if self._stop.is_set():  # its estimate was ended by the stop: nothing went wrong
                        log.debug("robot's cycle ended by the stop", extra={"robot": info.name})
                        break
                    self.metrics.cycle_errors.inc()
                    log.exception("worker cycle failed for robot", extra={"robot": info.name})
            self._count_alerts([info.name for info in robots])
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

    def _count_alerts(self, robots: list[str]) -> None:
        """Each robot's active alerts into the metrics."""
        for robot in robots:
            try:
                n = len(self.store.alerts(robot, active=True))
            except UnknownRobot:
                continue
            self.metrics.alerts_active.labels(robot=robot).set(n)

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

    def _want_network(self, robot: str) -> None:
        """A network retrain of ``robot``: on the cluster when there is one, else in the next cycle."""
        if self.remote is not None:
            self.remote.want(robot, "network")
        else:
            with self._lock:
                self.state(robot).requests.add("network")

    def _idle(self, robot: str, last_frame_t: float | None) -> bool:
        """True when ``robot``'s last frame has not moved for more than ``window_seconds`` of wall time
        and nothing was asked for it. Its window is then the one already judged: estimating it again
        costs a full estimate per cycle and learns nothing, so the robot waits, alerts as they stand,
        until frames arrive (its ``last_frame_t`` moves) or a retrain is requested."""
        now = self.clock()
        st = self.state(robot)
        seen = st.activity
        if seen is None or seen[0] != last_frame_t:
            st.activity = (last_frame_t, now)
            return False
        with self._lock:
            if st.requests:
                return False
        return now - seen[1] > self.settings.window_seconds

    def _methods(self, robot: str) -> list[str]:
        methods = ["fast"]
        n = self.settings.network_interval_cycles
        if n and self.cycles % n == 0:
            methods.append("network")
        with self._lock:
            st = self.state(robot)
            asked, st.requests = st.requests, set()
            for m in sorted(asked):
                if m not in methods:
                    methods.append(m)
        return methods

    def _learn(self, robot: str, st: RobotState, learn: Recording, res: CycleResult) -> Topology | None:
        """Step 3: every method of this cycle on ``learn`` (the cluster's only marked wanted), each
        result stored; the fast topology, whose lag centres the next window's search."""
        window_end = float(learn.t[-1])
        if st.lag is None:  # after a restart: the newest stored fast topology's
            st.lag = self.store.last_lag(robot)
        hint = LagHint.centre(st.lag)
        fast: Topology | None = None
        for method in self._methods(robot):
            if method != "fast" and self.remote is not None:
                self.remote.want(robot, method)  # submitted at the end of the cycle, stored when done
                continue
            t0 = time.perf_counter()
            topo = hint.estimate(lambda r, m=method: self.estimator(r, m), learn)
            self.metrics.retrain_seconds.labels(method=method).observe(time.perf_counter() - t0)
            self.store.save_topology(robot, topo, self.clock(), window_end)
            res.methods.append(method)
            if method == "fast":
                fast = topo
        if fast is not None and (lag := measured_lag(fast)) is not None:
            st.lag = lag
        return fast

    def _robot_cycle(self, robot: str, expected_imus: list[str]) -> CycleResult:
        res = CycleResult(robot)
        rec = self.store.read_window(robot, self.settings.window_seconds)
        if rec is None or rec.n_samples < self.min_samples or rec.q is None:
            res.skipped = "not enough data in the window"
            return res
        st = self.state(robot)
        base = self.store.baseline(robot)
        self._baseline_seen(robot, st, base)
        window_end = float(rec.t[-1])
        # velocity jumps at stops read as contradictions to the estimators
        learn = self.floating.learn_window(self.compute, rec)  # None: no sample left
        if self.floating.takes(robot, rec, learn, res):  # floating base, or too short for a fixed fit
            return res
        fast = self._learn(robot, st, learn, res)
        if fast is None:
            return res
        fp = st.fingerprints
        res.health = self.compute(
            signal_health,
            rec,
            base.topology if base is not None else None,
            expected_imus,
            current=fast,
            fingerprints=fp.joints if fp else None,
            imu_fingerprints=fp.imus if fp else None,
        )
        res.topology = fast
        if fast.excitation:
            self.store.set_excitation(robot, fast.excitation)
        waits = Waits(queue=queue_entries(self.remote, robot, self.clock()))
        full = full_window(rec, self.settings.window_seconds)
        if base is None:
            res.baseline_set = full and self.adoption.offer(robot, st, fast, res.health, window_end)
            if not res.baseline_set and (wait := self.adoption.waiting(st)) is not None:
                waits.add(*wait)
            self._write_waits(robot, waits)
            return res
        res.diff = diff_bodies(base.topology, fast, res.health)
        self.asks.on_change(robot, st, res.diff)
        if st.fingerprints is None and not res.diff.findings and self.geometry.one_motion(rec):
            # learned only on a window like those it is held against: one fitted on the first seconds
            # of a new clock epoch misses the encoder relation, and later full windows read shifted
            st.fingerprints = self.compute(baseline_fingerprints, rec, base.topology, current=fast)
        self._judge_alerts(robot, res, (rec, learn), base, waits, full and not is_ambiguous(fast))
        self._write_waits(robot, waits)
        return res

    def _estimate_after(self, rec: Recording, since: float) -> Topology | None:
        """The fast estimate of the part of ``rec`` after ``since`` (None: too little data there)."""
        return estimate_after(rec, since, self.min_samples, lambda r: self.estimator(r, "fast"))
