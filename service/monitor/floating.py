"""Floating-base robots in the worker: one IMU on a base that no encoder moves.

The fixed-base path (learn a topology, diff it against the baseline) has nothing to place on a walking
robot: its single IMU rides the base, and after the velocity jumps of every foot strike are dropped a
window keeps a handful of samples (``need at least 50 samples``). Such a robot takes this path:

* **Which robots.** A window the floating-base rule marks floating
  (:func:`bodyschema.stance_chains.floating_base_rule`: a ``floating_base`` flag or foot forces). The
  store keeps ``t``, ``q``, ``acc`` and ``gyro`` only, so a window read back from it carries neither;
  a robot with exactly one IMU whose joints jump in velocity in so many samples that fewer than
  ``min_samples``, or less than half of the window, are left after
  :func:`~bodyschema.impacts.drop_impacts` is then taken as floating too. A fixed-base arm's jumps
  are its rare stops; when most samples sit beside one, the jumps are the motion itself (a contact
  at every step: the iCub's 10 s windows keep 0 to 40 %, the Go1's 90 %), and the fixed-base fit
  cannot apply. A robot with one IMU that keeps its samples (point feet strike softly: the Go1) is
  taken as floating when the fixed-base fit of ``baseline_repeat_k`` cycles in a row hangs the IMU on
  no joint and decides nothing (several trees fit) while the IMU turns faster than
  :attr:`~bodyschema.health.HealthThresholds.motion_rad_s` RMS: on a fixed base the root does not
  turn, so a turning IMU on it rides a base that moves without an encoder. The decision sticks to the
  robot until the worker restarts, so a window that happens to keep enough samples does not flip it
  back.
* **Baseline.** :func:`bodyschema.floating_health.floating_baseline` on one healthy window
  ``baseline_repeat_k`` times as long as the judged ones, taken once that much device time is stored.
  One window, not K equal results: the floating checks' tolerances are extremes of the baseline (the
  longest hold of each encoder while the body moves, each joint's whole travel, the IMU's longest
  repeated reading), and extremes learned on K windows' worth of motion bound what any one later
  window of the same motion shows; K windows apart would each give smaller ones and need a rule to
  merge them. The baseline is kept in the store (:mod:`service.store.floating`, with the rule that
  took the robot as floating) and read back the first time a restarted worker meets the robot, so
  judging goes on at once, without the fixed-base cycles that found the rule nor the baseline's
  device time again. A stored baseline of other joints or IMUs than the window's, or one this
  version cannot read, is left to its history and a new one is learned.
* **Judging.** Every later full window: :func:`~bodyschema.floating_health.floating_diff` → findings →
  the worker's tracker (pending, then active after ``alert_hysteresis_m`` cycles) → alerts in the
  store, like the fixed path's findings.
* **Status.** What the robot's checks cannot decide is said, not raised: the wait entry names the
  rule that applied, the baseline's state, and the checks left undetermined (encoder offsets and a
  turned IMU need a stance chain: no foot forces in the frames, or point feet, which fix no
  rotation). A fixed-base robot whose window is too short after dropping impacts gets an
  ``undetermined: ...`` skip instead of an estimator error.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bodyschema.diff import is_ambiguous
from bodyschema.findings import Diff
from bodyschema.floating_health import FloatingBaseline, FloatingOptions, floating_baseline, floating_diff
from bodyschema.floating_json import baseline_from_json, baseline_to_json
from bodyschema.health import HealthThresholds
from bodyschema.impacts import drop_impacts
from bodyschema.recording import Recording, RecordingError
from bodyschema.stance_chains import floating_base_rule
from bodyschema.topology import Topology
from service.alert_path import Waits
from service.alerts import AlertTracker, Evidence, Transition
from service.monitor.state import full_window
from service.settings import Settings
from service.store import Store

__all__ = ["CycleResult", "FloatingBase", "FloatingRobot"]

log = logging.getLogger("service.worker")


@dataclass
class FloatingRobot:
    """What the worker keeps for one floating-base robot: the rule that marked it, since when (wall
    time), and the baseline once learned (with the device time its window ended)."""

    rule: str
    since: float
    baseline: FloatingBaseline | None = None
    baseline_end: float | None = None
    baseline_at: float | None = None


class CycleResult(Protocol):
    """The fields of the worker's :class:`~service.worker_alerts.CycleResult` this path fills (a
    protocol: :mod:`service.worker_alerts` imports the monitor steps, not the other way round)."""

    skipped: str
    baseline_set: bool
    diff: Diff | None
    pending: list[Transition]
    transitions: list[Transition]


def _turning_root(rec: Recording, fit: Topology) -> float | None:
    """The single IMU's RMS rate (rad/s) when ``fit`` hangs it on no joint, decides nothing, and the
    IMU turns faster than a link must to count as turning (None otherwise)."""
    if rec.n_imus != 1 or fit.imu_joint.get(rec.imu_names[0], "") is not None or not is_ambiguous(fit):
        return None
    g = rec.gyro[:, 0]
    rms = float(np.sqrt(np.mean(np.sum((g - g.mean(axis=0)) ** 2, axis=1))))
    return rms if rms > HealthThresholds().motion_rad_s else None


def _undetermined(base: FloatingBaseline) -> str:
    """The checks the baseline leaves undetermined, and why ('' when every check runs)."""
    if base.chains or base.tilt is not None:
        return ""
    if base.force_threshold is None:
        why = "the frames carry no foot forces, so no contact phase and no stance chain"
    else:
        why = "no stance chain on the baseline (point feet fix no rotation, or no single-limb stance)"
    return f"encoder offsets and a turned IMU undetermined: {why}"


class FloatingBase:
    """The floating-base path of the worker's cycle (module doc).

    ``store_alerts`` and ``write_waits`` are the worker's own (the same alert path and status record
    as the fixed path); ``tracker`` is its alert tracker.
    """

    def __init__(
        self,
        store: Store,
        settings: Settings,
        tracker: AlertTracker,
        clock: Callable[[], float],
        store_alerts: Callable[[str, list[Transition]], None],
        write_waits: Callable[[str, Waits], None],
        min_samples: int = 50,
        options: FloatingOptions | None = None,
    ) -> None:
        self.store = store
        self.settings = settings
        self.tracker = tracker
        self.clock = clock
        self.store_alerts = store_alerts
        self.write_waits = write_waits
        self.min_samples = min_samples
        self.options = options or FloatingOptions()
        self.robots: dict[str, FloatingRobot] = {}
        #: per robot, the cycles in a row whose fixed-base fit left its one IMU turning on the root
        self.root_streak: dict[str, tuple[int, int]] = {}  # (newest fast topology's id, streak)
        #: robots whose stored floating baseline was looked for since the worker started
        self.looked_up: set[str] = set()

    @staticmethod
    def learn_window(compute: Callable[..., Recording], rec: Recording) -> Recording | None:
        """:func:`~bodyschema.impacts.drop_impacts` of ``rec`` through the worker's ``compute``; None
        when it leaves no sample (a walking robot's joints jump in velocity at every contact: a short
        window can lose all of them)."""
        try:
            return compute(drop_impacts, rec)
        except RecordingError:
            return None

    # ------------------------------------------------------------------------------ the rule
    def rule(self, robot: str, rec: Recording, learn: Recording | None) -> str | None:
        """Why ``robot`` is taken as floating-base (None: it is not), from its window ``rec`` and the
        same window with impacts dropped, ``learn`` (module doc)."""
        known = self.robots.get(robot)
        if known is None and robot not in self.looked_up:
            self.looked_up.add(robot)
            known = self._restore(robot, rec)
        if (
            known is not None
            and known.baseline is not None
            and (known.baseline.joint_names != rec.joint_names or known.baseline.imu_names != rec.imu_names)
        ):
            del self.robots[robot]  # other parts: judged again from scratch
            known = None
        if known is not None:
            return known.rule
        floating, why = floating_base_rule(rec)
        if floating:
            return why
        kept = 0 if learn is None else learn.n_samples
        if rec.n_imus == 1 and (kept < self.min_samples or kept < 0.5 * rec.n_samples):
            return (
                f"one IMU, and velocity jumps at contacts in all but {kept} of {rec.n_samples} "
                "samples: a fixed-base topology cannot be fitted"
            )
        return self._root_rule(robot, rec)

    def _restore(self, robot: str, rec: Recording) -> FloatingRobot | None:
        """The floating baseline the store keeps for ``robot``, taken up again (None: none kept, or
        one of other parts than ``rec``'s, or one this version cannot read)."""
        stored = self.store.floating_baseline(robot)
        if stored is None or stored.data is None:
            return None
        try:
            base = baseline_from_json(stored.data)
        except ValueError as err:
            log.warning(
                "stored floating-base baseline unreadable: learning a new one",
                extra={"robot": robot, "error": str(err)},
            )
            return None
        if base.joint_names != rec.joint_names or base.imu_names != rec.imu_names:
            return None  # other parts: judged again from scratch
        fr = FloatingRobot(stored.rule, stored.wall_time, base, stored.window_end_t, stored.wall_time)
        self.robots[robot] = fr
        log.info(
            "floating-base baseline read back from the store",
            extra={"robot": robot, "baseline_id": stored.id},
        )
        return fr

    def _root_rule(self, robot: str, rec: Recording) -> str | None:
        """The rule for a one-IMU robot whose fixed-base fits keep hanging a turning IMU on no joint
        (module doc), from the newest fast topology the fixed path stored (None: not floating)."""
        newest = self.store.latest_topology(robot, method="fast") if rec.n_imus == 1 else None
        rms = None if newest is None else _turning_root(rec, newest.topology)
        seen, n = self.root_streak.get(robot, (-1, 0))
        if newest is not None and newest.id != seen:  # a new fit since the last cycle: counted once
            n = 0 if rms is None else n + 1
            self.root_streak[robot] = (newest.id, n)
        if rms is None or n < self.settings.baseline_repeat_k:
            return None
        return (
            f"the fixed-base fit of {n} cycles in a row hangs the one IMU on no joint and decides "
            f"nothing, yet it turns at {rms:.2f} rad/s RMS: a fixed base does not turn"
        )

    # ----------------------------------------------------------------------------- the cycle
    def takes(self, robot: str, rec: Recording, learn: Recording | None, res: CycleResult) -> bool:
        """Run the cycle of ``robot`` here when it is floating-base, or when its window is too short
        for the fixed-base fit (``res.skipped`` says why); False: the fixed path goes on."""
        why = self.rule(robot, rec, learn)
        if why is None:
            kept = 0 if learn is None else learn.n_samples
            if kept >= self.min_samples:
                return False
            res.skipped = (
                f"undetermined: {kept} of {rec.n_samples} samples left after dropping the "
                f"velocity jumps at impacts; the fixed-base fit needs {self.min_samples}"
            )
            return True
        fr = self.robots.get(robot)
        if fr is None:
            fr = self.robots[robot] = FloatingRobot(why, self.clock())
            log.info("floating base: the floating-base checks judge this robot", extra={"robot": robot})
        waits = Waits()
        if fr.baseline is None:
            self._learn(robot, fr, res, waits)
        else:
            self._judge(robot, fr, rec, res, waits)
        self.write_waits(robot, waits)
        return True

    def _learn(self, robot: str, fr: FloatingRobot, res: CycleResult, waits: Waits) -> None:
        """Learn the baseline once ``baseline_repeat_k`` windows of device time are stored."""
        k, window = self.settings.baseline_repeat_k, self.settings.window_seconds
        span = k * window
        rec = self.store.read_window(robot, span)
        have = 0.0 if rec is None else rec.duration
        if rec is None or have < 0.8 * span or rec.q is None:
            what = f"floating base ({fr.rule}): baseline from {span:g} s of frames ({have:.0f} s so far)"
            waits.add(what, fr.since)
            res.skipped = f"undetermined: {what}"
            return
        fr.baseline = floating_baseline(rec, self.options)
        fr.baseline_end, fr.baseline_at = float(rec.t[-1]), self.clock()
        self.store.save_floating_baseline(
            robot,
            baseline_to_json(fr.baseline),
            rule=fr.rule,
            wall_time=fr.baseline_at,
            window_end_t=fr.baseline_end,
        )
        res.baseline_set = True
        self._say(fr, waits)
        log.info(
            "floating-base baseline learned",
            extra={"robot": robot, "seconds": round(have, 1), "undetermined": _undetermined(fr.baseline)},
        )

    def _judge(self, robot: str, fr: FloatingRobot, rec: Recording, res: CycleResult, waits: Waits) -> None:
        """``rec`` against the baseline, the findings through the tracker into the store."""
        assert fr.baseline is not None
        self._say(fr, waits)
        if not full_window(rec, self.settings.window_seconds):
            res.skipped = f"undetermined: the window holds {rec.duration:.1f} s of frames"
            return
        try:
            res.diff = floating_diff(fr.baseline, rec, self.options)
        except ValueError as err:  # the robot's parts changed under the baseline
            res.skipped = f"undetermined: {err}"
            return
        changes = self.tracker.update(robot, res.diff.findings, evidence=Evidence(now=self.clock()))
        res.pending = [t for t in changes if t.state == "pending"]
        res.transitions = [t for t in changes if t.state != "pending"]
        self.store_alerts(robot, changes)

    @staticmethod
    def _say(fr: FloatingRobot, waits: Waits) -> None:
        """The status line of a robot with a floating baseline: the rule and what stays undetermined."""
        assert fr.baseline is not None and fr.baseline_at is not None
        gap = _undetermined(fr.baseline)
        what = f"floating base ({fr.rule}): judged by the floating-base checks, not a fixed-base topology"
        waits.add(what + (f"; {gap}" if gap else ""), fr.baseline_at)
