"""The sensor networks' word on what the fast screen finds (the worker's steps 3 to 5).

With the networks on a schedule (``network_interval_cycles`` > 0) they are the authority for baselines
and structural alerts and the fast method is the screen: :class:`NetworkAsks` asks them for a retrain
when the screen needs their answer, :func:`confirm` turns their newest topology into the tracker's
evidence on each structural finding.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable

from bodyschema.diff import STRUCTURAL_KINDS
from bodyschema.findings import Diff, Finding
from bodyschema.topology import Topology
from bodyschema.verdict import decided_parts, part_answer
from service.alerts import Evidence
from service.monitor.state import RobotState
from service.settings import Settings
from service.store import TopologyRecord

__all__ = ["NetworkAsks", "confirm"]

log = logging.getLogger("service.worker")


class NetworkAsks:
    """When the worker asks for a network retrain of a robot; ``want(robot)`` asks (on the cluster
    when there is one, else in the next cycle)."""

    def __init__(self, settings: Settings, clock: Callable[[], float], want: Callable[[str], None]) -> None:
        self.settings = settings
        self.clock = clock
        self.want = want

    @property
    def networks_on(self) -> bool:
        """True when the sensor networks run on a schedule (module doc)."""
        return self.settings.network_interval_cycles > 0

    def ask(self, robot: str, state: RobotState, net: TopologyRecord | None, since: float, why: str) -> None:
        """Ask for a network retrain of ``robot``, unless the networks have already learned a window
        that ended at or after ``since`` (device time; their answer stands until the schedule's next
        retrain) or one the worker asked for is still to come (no network topology stored since).
        ``net`` is the robot's newest network topology, as the caller read it."""
        if net is not None and net.window_end_t is not None and net.window_end_t >= since:
            return
        asked = state.network_asked
        if asked is not None and (net is None or net.wall_time < asked):
            return
        state.network_asked = self.clock()
        log.info("network retrain asked: %s", why, extra={"robot": robot})
        self.want(robot)

    def on_change(self, robot: str, state: RobotState, diff: Diff) -> None:
        """Ask for a network retrain of ``robot`` when the fast screen's diff holds a finding the
        previous cycle's did not (``Settings.network_on_change``): the networks learn the body the
        finding is about. Once per new finding, not per cycle it lasts: a retrain costs tens of CPU
        seconds, the screen one."""
        seen = frozenset((f.kind, f.part) for f in diff.findings)
        new = seen - state.findings
        state.findings = seen
        if not new or not self.settings.network_on_change or not self.networks_on:
            return
        log.info(
            "network retrain asked: the fast screen found a change",
            extra={"robot": robot, "findings": sorted(f"{k} {p}" for k, p in new)},
        )
        self.want(robot)


def confirm(
    robot: str,
    state: RobotState,
    diff: Diff,
    baseline: Topology,
    window_end: float,
    net: TopologyRecord | None,
    evidence: Evidence,
    asks: NetworkAsks,
) -> tuple[Diff, Evidence]:
    """The diff and the tracker's evidence after the sensor networks' word on its structural
    findings; ``net`` is the robot's newest network topology.

    A structural finding of the fast screen on a part is *confirmed* when ``net``, from a window
    that ended at or after the end of the first window that showed the finding
    (``state.first_seen``), also differs from the baseline structurally on that part (the kind the
    screen gives is kept: its post-onset judgement, :func:`service.monitor.onset.after_onset`, tells a
    move from a detachment, which a network window straddling the change cannot); *withdrawn*
    (dropped from the diff, its alert resolved with the reason) when that topology shows the part as
    in the baseline; and *waiting* while there is no such topology yet, with a retrain asked for: its
    alert is pending until the networks answer or the confirmation timeout passes
    (:class:`~service.alerts.Evidence`).
    """
    structural = [f for f in diff.findings if f.kind in STRUCTURAL_KINDS]
    seen = {(f.kind, f.part) for f in structural}
    state.first_seen = {k: t for k, t in state.first_seen.items() if k in seen}
    if not structural:
        return diff, evidence
    answers = _network_answers(net)
    keep: list[Finding] = []
    waiting: set[tuple[str, str]] = set()
    confirmed: set[tuple[str, str]] = set()
    withdrawn: dict[tuple[str, str], str] = {}
    for f in diff.findings:
        if f.kind not in STRUCTURAL_KINDS:
            keep.append(f)
            continue
        key = (f.kind, f.part)
        since = state.first_seen.setdefault(key, window_end)
        if net is None or answers is None or net.window_end_t is None or net.window_end_t < since:
            keep.append(f)
            waiting.add(key)
            asks.ask(robot, state, net, since, f"to confirm {f.kind} {f.part}")
            continue
        if f.part not in answers:  # the networks answered but left this part open: unconfirmed
            keep.append(f)
            waiting.add(key)
            continue
        said, before = answers[f.part], part_answer(baseline, f.part)
        if said == before:
            withdrawn[key] = (
                f"the sensor networks' topology {net.id} (window ending at t = {net.window_end_t:.1f} s) "
                f"shows no change of {f.part}"
            )
            log.info(
                "finding withdrawn: the sensor networks see no change there",
                extra={"robot": robot, "kind": f.kind, "part": f.part, "network_topology": net.id},
            )
        elif f.to is None or said == f.to:
            keep.append(f)
            confirmed.add(key)
        else:  # both see a change, each to another place: where to is undetermined, not confirmed
            keep.append(_where_to_undetermined(f, said, net.id))
            waiting.add(key)
    return Diff(findings=tuple(keep), reasons=diff.reasons), dataclasses.replace(
        evidence,
        waiting=frozenset(waiting),
        confirmed=frozenset(confirmed),
        withdrawn=withdrawn,
        why="the sensor networks",
    )


def _network_answers(net: TopologyRecord | None) -> dict[str, str | None] | None:
    """The parts the networks' topology ``net`` decides, with its answer for each (None: no network
    topology). Every tree it lists must agree on a part, at a confidence above one half
    (:func:`bodyschema.verdict.decided_parts`): an ambiguous answer still decides what all its trees
    share."""
    if net is None:
        return None
    topo = net.topology
    return {p: part_answer(topo, p) for p, d in decided_parts(topo).items() if d}


def _where_to_undetermined(f: Finding, said: str | None, net_id: int) -> Finding:
    """``f`` without the new place the sensor networks contradict (they put the part on ``said``):
    the change stands, where the part went is undetermined."""
    note = (
        f"the fast screen puts it under {f.to}, the sensor networks' topology {net_id} under {said}: "
        f"where it went is undetermined; move {f.to} and {said} apart to decide"
    )
    return dataclasses.replace(f, to=None, detail=f"{f.detail}; {note}" if f.detail else note)
