"""The monitoring worker's alert path: the sensor networks' word on the fast screen's findings, the
tracker's transitions into the store, and what the worker waits on for each robot
(:mod:`service.alert_path`).

Kept apart from :mod:`service.worker` (the loop and the wiring) as a mixin of
:class:`service.worker.Worker`, whose steps (:mod:`service.monitor`) and per-robot state it uses: the
sections are the module doc's step 5 there.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from bodyschema.diff import STRUCTURAL_KINDS, is_ambiguous
from bodyschema.findings import ALERT_KINDS, KINEMATIC_KINDS, Diff
from bodyschema.health import SignalHealth
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.alert_path import Waits, baseline_verdict, confirm_timeout
from service.alerts import AlertTracker, Evidence, Transition
from service.monitor.confirmation import NetworkAsks, confirm
from service.monitor.drift import GeometryDrift
from service.monitor.onset import after_onset
from service.monitor.state import RobotState
from service.settings import Settings
from service.store import Store, TopologyRecord

__all__ = ["AlertPath", "CycleResult"]

log = logging.getLogger("service.worker")


@dataclass
class CycleResult:
    """What one cycle did for one robot (returned by :meth:`Worker.run_cycle`, also logged)."""

    robot: str
    skipped: str = ""
    topology: Topology | None = None
    methods: list[str] = field(default_factory=list)
    health: SignalHealth | None = None
    diff: Diff | None = None
    baseline_set: bool = False
    transitions: list[Transition] = field(default_factory=list)
    #: findings seen for the first time this cycle: stored as pending alerts
    pending: list[Transition] = field(default_factory=list)
    #: the cycle compared the robot's geometry with its baseline's (the drift findings are in ``diff``)
    drift_judged: bool = False
    #: ... and its lever arms too: the baseline's pool was full (:mod:`service.monitor.drift`)
    slides_judged: bool = False


class AlertPath:
    """Step 5 of a worker cycle for one robot (module doc); mixed into :class:`~service.worker.Worker`."""

    store: Store
    settings: Settings
    tracker: AlertTracker
    asks: NetworkAsks
    geometry: GeometryDrift
    cycles: int
    clock: Callable[[], float]

    def state(self, robot: str) -> RobotState:
        """What the worker keeps for ``robot`` (:meth:`service.worker.Worker.state`)."""
        raise NotImplementedError

    def _estimate_after(self, rec: Recording, since: float) -> Topology | None:
        """The fast estimate of ``rec`` after ``since`` (:meth:`service.worker.Worker._estimate_after`)."""
        raise NotImplementedError

    def _judge_alerts(
        self,
        robot: str,
        res: CycleResult,
        windows: tuple[Recording, Recording],
        base: TopologyRecord,
        waits: Waits,
        full: bool,
    ) -> None:
        """``res.diff`` (against ``base``) through the onset, the networks' confirmation and the
        geometry into the tracker, and its transitions into the store (module doc, 5). ``windows``: the
        raw window and the one with impacts dropped; ``full``: a full window with a unique estimate
        (restored alerts are judged again on the first)."""
        rec, learn = windows
        assert res.diff is not None and res.topology is not None
        st = self.state(robot)
        hold: tuple[str, ...] = STRUCTURAL_KINDS if is_ambiguous(res.topology) else ()
        if not hold:
            res.diff, hold = after_onset(st, learn, res.diff, base.topology, self._estimate_after)
        evidence = Evidence(now=self.clock(), rejudge=full and st.rejudge)
        if self.asks.networks_on:
            evidence = self._networks_word(robot, st, res, base, waits, evidence, float(rec.t[-1]))
        drift = self.geometry.judge(robot, self.cycles, rec, res.topology, base, res.diff)
        if drift is None:
            hold = tuple(sorted({*hold, *KINEMATIC_KINDS}))
        else:
            found, res.slides_judged = drift
            res.drift_judged = True
            res.diff = Diff(findings=(*res.diff.findings, *found), reasons=res.diff.reasons)
        findings = res.diff.findings
        if not self.geometry.one_motion(rec):
            # a short window (the first ones of a new clock epoch after a restart) or one with a hole:
            # its findings rest on less than the thresholds were derived for, so nothing is raised or
            # resolved on it; the next full window judges
            findings, hold = (), tuple(sorted(ALERT_KINDS))
        changes = self.tracker.update(robot, findings, hold=hold, evidence=evidence)
        if evidence.rejudge:
            st.rejudge = False
        since = self.tracker.since(robot)
        active = {(k, p) for _, k, p in self.tracker.active(robot)}
        for kind, part in sorted(evidence.waiting - active):
            t = since.get((kind, part), evidence.now)
            waits.add(f"network confirmation of {kind} {part}", t, t + evidence.timeout)
        if changes:
            now_base = self.store.baseline(robot)
            if now_base is None or now_base.id != base.id:  # approved during this cycle: judged next
                self.tracker.forget(robot)
                return
        res.pending = [t for t in changes if t.state == "pending"]
        res.transitions = [t for t in changes if t.state != "pending"]
        self._store_alerts(robot, changes)

    def _networks_word(
        self,
        robot: str,
        st: RobotState,
        res: CycleResult,
        base: TopologyRecord,
        waits: Waits,
        evidence: Evidence,
        window_end: float,
    ) -> Evidence:
        """The sensor networks' newest topology on the baseline (a wait when it is in doubt) and on
        ``res.diff``'s structural findings (:func:`~service.monitor.confirmation.confirm`)."""
        assert res.diff is not None
        net = self.store.latest_topology(robot, method="network")
        changed = {f.part for f in res.diff.findings if f.kind in STRUCTURAL_KINDS}
        verdict, why = baseline_verdict(base, net, changed)
        if verdict == "contradicted":  # the fast screen sees the baseline, the networks another body
            waits.add(f"baseline: an operator's approval ({why})", base.wall_time)
        elif verdict == "unconfirmed":
            waits.add(
                "baseline: the sensor networks' answer on the fast-unconfirmed baseline", base.wall_time
            )
        res.diff, evidence = confirm(robot, st, res.diff, base.topology, window_end, net, evidence, self.asks)
        return dataclasses.replace(evidence, timeout=confirm_timeout(self.settings, waits.queue))

    def _store_alerts(self, robot: str, changes: list[Transition]) -> None:
        """Write the tracker's transitions to the store, each logged."""
        now = self.clock()
        for tr in changes:
            rec_ = self.store.upsert_alert(
                robot,
                tr.kind,
                tr.part,
                tr.finding.to_json(),
                tr.state,
                now,
                confirmed=tr.confirmed,
                note=tr.note,
            )
            log.log(
                logging.INFO if tr.state == "pending" else logging.WARNING,
                "alert %s",
                tr.state,
                extra={
                    "robot": robot,
                    "kind": tr.kind,
                    "part": tr.part,
                    "alert_id": rec_.id,
                    "confirmed": tr.confirmed,
                    "note": tr.note,
                    "finding": tr.finding.to_json(),
                },
            )

    def _write_waits(self, robot: str, waits: Waits) -> None:
        """Store what ``robot`` waits on when it changed since it was last written."""
        data = waits.to_json()
        st = self.state(robot)
        if st.waits_written == data:
            return
        self.store.set_waiting(robot, {**data, "at": round(self.clock(), 3)})
        st.waits_written = data
