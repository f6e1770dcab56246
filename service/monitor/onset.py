"""A displaced IMU judged on the data recorded after its displacement (the worker's step 5).

An IMU moved to another link while the window straddles the move fits neither link and reads as
``imu_detached``; only the part of the window after the move says whether it moved or came loose.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bodyschema.diff import is_ambiguous
from bodyschema.findings import Diff, Finding
from bodyschema.recording import Recording, RecordingError
from bodyschema.topology import Topology
from service.monitor.state import RobotState

__all__ = ["DISPLACED", "after_onset", "estimate_after"]

#: The kinds that place an IMU elsewhere than the baseline, held while the part after the onset
#: cannot tell them apart.
DISPLACED = ("imu_detached", "imu_moved")

#: ``(recording, since) -> Topology | None``: the fast estimate of the part after ``since``.
After = Callable[[Recording, float], "Topology | None"]


def estimate_after(
    rec: Recording, since: float, min_samples: int, estimate: Callable[[Recording], Topology]
) -> Topology | None:
    """``estimate`` of the part of ``rec`` after ``since`` (None: too little data there)."""
    if float(rec.t[-1]) <= since:
        return None
    try:
        after = rec.window(since, np.inf)
    except RecordingError:  # the streams do not overlap yet
        return None
    if after.n_samples < min_samples or after.duration <= 0:
        return None
    return estimate(after)


def after_onset(
    state: RobotState, rec: Recording, diff: Diff, baseline: Topology, after: After
) -> tuple[Diff, tuple[str, ...]]:
    """Judge each ``imu_detached`` finding on the data recorded after its onset.

    The onset of an IMU's displacement is the end of the first window (of the current run of
    cycles) whose diff placed it elsewhere than the baseline (``state.onset``): every later sample was
    recorded after the change. A window that straddles an IMU's move holds both of its placements; the
    joint-velocity model of either link fits only part of it, so the estimate on the whole window
    follows no joint, the same answer a detached IMU gives. Only the part after the onset says
    which it is, and the window's own estimate is trusted again once it starts after the onset.
    Until then, per detached IMU, one estimate of the post-onset part (``after``, shared by IMUs with
    the same onset, paid only while a detachment is reported and the window straddles it):

    * no post-onset data yet, or an estimate that is not unique: the finding is held (neither
      raised nor counted as gone);
    * the IMU follows no joint there either: the detachment stands;
    * it follows another joint: the finding becomes ``imu_moved`` to that joint;
    * it follows its baseline joint again: the finding is held (the estimate of the next windows
      decides whether anything changed at all).

    Returns the diff to track and the kinds to hold.
    """
    window_end, window_start = float(rec.t[-1]), float(rec.t[0])
    displaced = {f.imu for f in diff.findings if f.kind in DISPLACED and f.imu}
    state.onset = {imu: t for imu, t in state.onset.items() if imu in displaced}
    for imu in displaced:
        state.onset.setdefault(imu, window_end)
    findings: list[Finding] = []
    held = False
    estimates: dict[float, Topology | None] = {}
    for f in diff.findings:
        since = state.onset.get(f.imu or "", window_start)
        if f.kind != "imu_detached" or since <= window_start:
            findings.append(f)
            continue
        if since not in estimates:
            estimates[since] = after(rec, since)
        judged = _judged(f, estimates[since], baseline)
        if judged is None:
            held = True
        else:
            findings.append(judged)
    return Diff(findings=tuple(findings), reasons=diff.reasons), DISPLACED if held else ()


def _judged(f: Finding, topo: Topology | None, baseline: Topology) -> Finding | None:
    """The detachment ``f`` as the post-onset estimate ``topo`` sees it; None: held."""
    if topo is None or is_ambiguous(topo) or f.imu not in topo.imu_joint:
        return None
    now = topo.imu_joint[f.imu]
    if now is None:
        return f
    if now != baseline.imu_joint.get(f.imu):
        conf = float(topo.confidence.get(f"imu:{f.imu}", 1.0))
        return Finding("imu_moved", imu=f.imu, from_=f.from_, to=now, confidence=conf)
    return None
