"""The monitoring worker's alert path: the sensor networks' word on the fast screen's findings, the
tracker's transitions into the store, and what the worker waits on for each robot
(:mod:`service.alert_path`).

Kept apart from :mod:`service.worker` (the cycle, baselines and geometry) as a mixin of
:class:`service.worker.Worker`, whose state it uses: the sections are the module doc's step 5 there.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.diff import STRUCTURAL_KINDS, diff_bodies, is_ambiguous
from bodyschema.findings import KINEMATIC_KINDS, Diff, Finding
from bodyschema.health import SignalHealth
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.alert_path import Waits, baseline_verdict, confirm_timeout
from service.alerts import AlertTracker, Evidence, Transition
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
    #: ... and its lever arms too: the baseline's pool was full (:meth:`Worker._drift`)
    slides_judged: bool = False


class AlertPath:
    """Step 5 of a worker cycle for one robot (module doc); mixed into :class:`~service.worker.Worker`."""

    store: Store
    settings: Settings
    tracker: AlertTracker
    _first_seen: dict[tuple[str, str, str], float]
    _rejudge: set[str]
    _streak_n: dict[str, int]
    _streak_start: dict[str, float]
    _waits_written: dict[str, dict[str, Any]]
    clock: Callable[[], float]

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
        fast, window_end = res.topology, float(rec.t[-1])
        hold: tuple[str, ...] = STRUCTURAL_KINDS if is_ambiguous(fast) else ()
        if not hold:
            res.diff, held = self._after_onset(robot, learn, res.diff, base.topology)
            hold = held
        evidence = Evidence(now=self.clock(), rejudge=full and robot in self._rejudge)
        if self.networks_on:
            net = self.store.latest_topology(robot, method="network")
            changed = any(f.kind in STRUCTURAL_KINDS for f in res.diff.findings)
            verdict, why = baseline_verdict(base, net, changed)
            if verdict == "contradicted":  # the fast screen sees the baseline, the networks another body
                waits.add(f"baseline: an operator's approval ({why})", base.wall_time)
            elif verdict == "unconfirmed":
                waits.add(
                    "baseline: the sensor networks' answer on the fast-unconfirmed baseline", base.wall_time
                )
            res.diff, evidence = self._confirmed(robot, res.diff, base.topology, window_end, net, evidence)
            evidence = dataclasses.replace(evidence, timeout=confirm_timeout(self.settings, waits.queue))
        drift = self._drift(robot, rec, fast, base, res.diff, window_end)
        if drift is None:
            hold = tuple(sorted({*hold, *KINEMATIC_KINDS}))
        else:
            found, res.slides_judged = drift
            res.drift_judged = True
            res.diff = Diff(findings=(*res.diff.findings, *found), reasons=res.diff.reasons)
        changes = self.tracker.update(robot, res.diff.findings, hold=hold, evidence=evidence)
        if evidence.rejudge:
            self._rejudge.discard(robot)
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
        if self._waits_written.get(robot) == data:
            return
        self.store.set_waiting(robot, {**data, "at": round(self.clock(), 3)})
        self._waits_written[robot] = data

    def _confirmed(
        self,
        robot: str,
        diff: Diff,
        baseline: Topology,
        window_end: float,
        net: TopologyRecord | None,
        evidence: Evidence,
    ) -> tuple[Diff, Evidence]:
        """The diff and the tracker's evidence after the sensor networks' word on its structural
        findings (module doc, 5); ``net`` is the robot's newest network topology.

        A structural finding of the fast screen on a part is *confirmed* when ``net``, from a window
        that ended at or after the end of the first window that showed the finding, also differs from
        the baseline structurally on that part (the kind the screen gives is kept: its post-onset
        judgement, :meth:`_after_onset`, tells a move from a detachment, which a network window
        straddling the change cannot); *withdrawn* (dropped from the diff, its alert resolved with the
        reason) when that topology shows the part as in the baseline; and *waiting* while there is no
        such topology yet, with a retrain asked for: its alert is pending until the networks answer or
        the confirmation timeout passes (:class:`~service.alerts.Evidence`).
        """
        structural = [f for f in diff.findings if f.kind in STRUCTURAL_KINDS]
        seen = {(f.kind, f.part) for f in structural}
        for key in [k for k in self._first_seen if k[0] == robot and (k[1], k[2]) not in seen]:
            del self._first_seen[key]
        if not structural:
            return diff, evidence
        net_parts: set[str] | None = None
        if net is not None and not is_ambiguous(net.topology):
            net_diff = diff_bodies(baseline, net.topology)
            net_parts = {f.part for f in net_diff.findings if f.kind in STRUCTURAL_KINDS}
        keep: list[Finding] = []
        waiting: set[tuple[str, str]] = set()
        confirmed: set[tuple[str, str]] = set()
        withdrawn: dict[tuple[str, str], str] = {}
        for f in diff.findings:
            if f.kind not in STRUCTURAL_KINDS:
                keep.append(f)
                continue
            since = self._first_seen.setdefault((robot, f.kind, f.part), window_end)
            if net is None or net_parts is None or net.window_end_t is None or net.window_end_t < since:
                keep.append(f)
                waiting.add((f.kind, f.part))
                self._ask_network(robot, net, since, f"to confirm {f.kind} {f.part}")
            elif f.part in net_parts:
                keep.append(f)
                confirmed.add((f.kind, f.part))
            else:
                withdrawn[(f.kind, f.part)] = (
                    f"the sensor networks' topology {net.id} (window ending at t = {net.window_end_t:.1f} s) "
                    f"shows no change of {f.part}"
                )
                log.info(
                    "finding withdrawn: the sensor networks see no change there",
                    extra={"robot": robot, "kind": f.kind, "part": f.part, "network_topology": net.id},
                )
        return Diff(findings=tuple(keep), reasons=diff.reasons), dataclasses.replace(
            evidence,
            waiting=frozenset(waiting),
            confirmed=frozenset(confirmed),
            withdrawn=withdrawn,
            why="the sensor networks",
        )

    def _networks_late(self, robot: str, net: TopologyRecord | None) -> bool:
        """True when the fast screen's body held ``baseline_unconfirmed_cycles`` cycles and the sensor
        networks have not answered on a window that ended after it first held (a network answer from
        after it that disagrees is not late: it is the authority's word, and the streak waits)."""
        need = self.settings.baseline_unconfirmed_cycles
        if not need or self._streak_n.get(robot, 0) < need:
            return False
        start = self._streak_start.get(robot, np.inf)
        answered = (
            net is not None
            and not is_ambiguous(net.topology)
            and net.window_end_t is not None
            and net.window_end_t >= start
        )
        return not answered
