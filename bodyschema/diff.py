"""Baseline body vs current body: typed damage findings (docs/design.md, 'Diff JSON').

A bare comparison of two learned trees over-reports: one frozen encoder makes its joint's IMUs "move"
to the parent joint and its child joints "re-parent"; one dead IMU "moves" to the base. So the diff
works from the most specific cause to the least, and every part a cause explains is *claimed* and not
reported again:

1. ``imu_dead`` — the IMU is silent, reports zeros or repeats one sample (signal health).
2. ``link_lost`` — the joint's encoder turns but no live IMU of its subtree depends on it any more
   (where no IMU health could judge the joint: all of at least two subtree IMUs lost it).
3. ``encoder_fault`` — the joint's child link turns against its parent but the encoder is flat or does
   not agree, or agrees differently than on the baseline (a constant offset; signal health).
4. ``joint_locked`` — the joint no longer moves (encoder flat, child link rigid with its parent) while
   other joints do, and it did move in the baseline.

A joint-level cause claims its whole subtree's structure changes (an upstream fault scrambles the
estimate below it), so one broken joint gives one finding.

5. ``imu_detached`` / ``imu_moved`` — one IMU follows no joint any more / follows another joint; or
   (signal health) it still follows its joint, but far more loosely than on the baseline next to the
   other IMUs of its link: an IMU hanging on a short tether turns with its link and is placed there.
6. ``joint_reparented`` — a joint hangs under another joint than in the baseline.
7. ``insufficient_excitation`` — a joint the current estimate could not decide (not a damage); parts
   that depend on it are not judged.

Identical inputs give no finding. A current estimate (or a baseline) that is not unique gives only the
findings signal health starts (1-4): where it puts a part is no evidence on its own; the answer is then
``changed`` null unless one of those is a damage, and the reasons name the parts the trees that fit
disagree on and the joints to move to decide (:func:`undetermined_reasons`). Everything here is pure.

Example
-------
>>> from bodyschema.topology import Topology
>>> base = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2", "imu2": "j2"})
>>> diff_bodies(base, base).to_json()
{'changed': False, 'findings': []}
>>> cur = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j1", "imu2": "j2"},
...                confidence={"imu:imu1": 0.9})
>>> diff_bodies(base, cur).to_json()["findings"]
[{'kind': 'imu_moved', 'imu': 'imu1', 'from': 'j2', 'to': 'j1', 'confidence': 0.9}]
"""

from __future__ import annotations

from dataclasses import dataclass

from bodyschema.findings import Diff, Finding
from bodyschema.health import SignalHealth
from bodyschema.topology import Topology

__all__ = [
    "STRUCTURAL_KINDS",
    "UNDETERMINED_HERE",
    "DiffThresholds",
    "deciding_joints",
    "diff_bodies",
    "is_ambiguous",
    "open_parts",
    "undetermined_here",
    "undetermined_reasons",
    "unplaced_reasons",
]

#: Kinds read from where the estimate places parts; an ambiguous estimate cannot make them.
STRUCTURAL_KINDS: tuple[str, ...] = ("imu_moved", "imu_detached", "joint_reparented", "link_lost")


def is_ambiguous(topo: Topology) -> bool:
    """True when several trees fit the data (not unique, or alternatives given)."""
    return not topo.unique or bool(topo.candidates)


#: How a part the data did not place is described, wherever it would otherwise be named as placed.
UNDETERMINED_HERE = "the tree is undetermined here"


def open_parts(topo: Topology) -> dict[str, str]:
    """Every part ``topo`` names but the data did not place, ``imu:NAME`` / ``joint:NAME`` -> what the
    trees that fit allow for it.

    A part is open when the trees that fit put it in different places, and an IMU the estimate puts on
    the base is open while some joint is undetermined: a joint the window did not move leaves its
    child link turning with its parent, so an IMU that did not turn may ride that link.

    >>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2", "i3": None}, undetermined=("j2",))
    >>> open_parts(a)
    {'imu:i3': 'IMU i3: on the base, or on the link of j2 (not moved enough to place)'}
    """
    trees = [topo, *topo.candidates]
    out: dict[str, str] = {}
    for j in topo.joint_parent:
        options = {t.joint_parent.get(j) for t in trees}
        if len(options) > 1 or (not topo.unique and not topo.candidates):
            out[f"joint:{j}"] = f"joint {j}: parent {' or '.join(sorted(o or 'base' for o in options))}"
    unmoved = [j for j in topo.undetermined if j in topo.joint_parent]
    for imu in topo.imu_joint:
        options = {t.imu_joint.get(imu) for t in trees}
        if len(options) > 1 or (not topo.unique and not topo.candidates):
            out[f"imu:{imu}"] = f"IMU {imu}: on {' or '.join(sorted(o or 'base' for o in options))}"
        elif options == {None} and unmoved:
            out[f"imu:{imu}"] = (
                f"IMU {imu}: on the base, or on the link of {', '.join(unmoved)} (not moved enough to place)"
            )
    return out


def undetermined_here(topo: Topology, parts: list[str]) -> str:
    """The reason to give for ``parts`` (keys of :func:`open_parts`) instead of placing them: ``""``
    when the data placed all of them.

    >>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
    >>> b = Topology({"j1": None, "j2": None}, {"i1": "j1", "i2": "j2"})
    >>> amb = Topology(a.joint_parent, a.imu_joint, unique=False, candidates=(b,))
    >>> print(undetermined_here(amb, ["imu:i2", "joint:j2"]))  # doctest: +NORMALIZE_WHITESPACE
    the tree is undetermined here (joint j2: parent base or j1; 2 trees fit the data);
    to decide, move j1, j2 each on its own
    """
    open_ = open_parts(topo)
    named = [open_[p] for p in parts if p in open_]
    if not named:
        return ""
    count = 1 + len(topo.candidates)
    fit = f"{count} trees fit the data" if topo.candidates else "the data leave it open"
    move = deciding_joints(topo)
    tail = f"; to decide, move {', '.join(move)} each on its own" if move else ""
    return f"{UNDETERMINED_HERE} ({'; '.join(named)}; {fit}){tail}"


def undetermined_reasons(topo: Topology) -> tuple[str, ...]:
    """Why ``topo`` cannot back a "no change": how many trees fit, where they differ, what would decide.

    Empty when the tree is unique. The parts named are those whose parent differs between the
    candidate trees; the motion that decides between them moves each joint involved on its own.

    >>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
    >>> b = Topology({"j1": None, "j2": None}, {"i1": "j1", "i2": "j2"})
    >>> amb = Topology(a.joint_parent, a.imu_joint, unique=False, candidates=(b,))
    >>> for r in undetermined_reasons(amb):
    ...     print(r)
    2 trees fit the data; they differ in joint j2 (parent base or j1)
    to decide, move each of these joints on its own with the others still: j1, j2
    >>> undetermined_reasons(a)
    ()
    """
    if not is_ambiguous(topo):
        return ()
    trees = [topo, *topo.candidates]
    count = f"{len(trees)} trees fit the data" if topo.candidates else "more than one tree fits the data"
    parts: list[str] = []
    for j in topo.joint_parent:
        options = {t.joint_parent.get(j) for t in trees}
        if len(options) > 1:
            parts.append(f"joint {j} (parent {' or '.join(sorted(o or 'base' for o in options))})")
    for imu in topo.imu_joint:
        options = {t.imu_joint.get(imu) for t in trees}
        if len(options) > 1:
            parts.append(f"IMU {imu} (on {' or '.join(sorted(o or 'base' for o in options))})")
    head = count + (f"; they differ in {', '.join(parts)}" if parts else "")
    reasons = [head]
    names = deciding_joints(topo)
    if names:
        reasons.append(
            f"to decide, move each of these joints on its own with the others still: {', '.join(names)}"
        )
    return tuple(reasons)


def deciding_joints(topo: Topology) -> tuple[str, ...]:
    """Joints to move, each on its own with the others still, to decide what the data left open.

    Every joint whose parent differs between the trees that fit, the joints those parents could be,
    the joints an IMU could ride, and the joints without enough excitation; in the topology's joint
    order.

    >>> a = Topology({"j1": None, "j2": "j1", "j3": None}, {"i1": "j1", "i2": "j2"}, undetermined=("j3",))
    >>> deciding_joints(a)
    ('j3',)
    """
    trees = [topo, *topo.candidates]
    involved: set[str] = set(topo.undetermined)
    for j in topo.joint_parent:
        options = {t.joint_parent.get(j) for t in trees}
        if len(options) > 1:
            involved.add(j)
            involved.update(o for o in options if o)
    for imu in topo.imu_joint:
        options = {t.imu_joint.get(imu) for t in trees}
        if len(options) > 1:
            involved.update(o for o in options if o)
    return tuple(j for j in topo.joint_parent if j in involved)


def unplaced_reasons(topo: Topology) -> tuple[str, ...]:
    """Why joints the window did not move keep even a unique ``topo`` from backing a "no change".

    Such a joint's child link moves like its parent link within noise, so the estimate is exact only on
    the tree with that joint contracted: nothing is known of the joint itself.

    >>> t = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"}, undetermined=("j2",))
    >>> unplaced_reasons(t)[0].split(";")[0]
    'the window does not move joint j2 enough to place it'
    """
    unplaced = [j for j in topo.undetermined if j in topo.joint_parent]
    if not unplaced:
        return ()
    many = len(unplaced) > 1
    return (
        f"the window does not move joint{'s' if many else ''} {', '.join(unplaced)} enough to place "
        f"{'them' if many else 'it'}; to decide, move each on its own with the others still",
    )


@dataclass(frozen=True)
class DiffThresholds:
    """``excitation_rad_s``: a baseline joint slower than this never "moved", so it cannot lock.
    ``min_link_imus``: live IMUs a subtree needs before losing all of them reads as ``link_lost``
    (fewer and it reads as ``imu_detached``) unless the encoder shows the joint still turning.
    ``min_confidence``: IMU/joint changes the estimator is less sure of are not reported."""

    excitation_rad_s: float = 0.05
    min_link_imus: int = 2
    min_confidence: float = 0.0


def _order(topo: Topology) -> list[str]:
    """Joints root first (breadth-first), so a cause high in the tree is found before its effects."""
    out: list[str] = []
    frontier = topo.children(None)
    while frontier:
        out.extend(frontier)
        frontier = [c for j in frontier for c in topo.children(j)]
    return out


def _depends(topo: Topology, imu: str, joint: str) -> bool:
    """Whether ``imu`` (per ``topo``) moves with ``joint``: the joint is on its path to the base."""
    j = topo.imu_joint.get(imu)
    if j is None or j not in topo.joint_parent:
        return False
    return joint in topo.ancestors(j)


class _Claims:
    """The comparison under way: findings so far and the IMUs and joints a found cause explains."""

    def __init__(self, baseline: Topology, current: Topology, thresholds: DiffThresholds) -> None:
        self.baseline = baseline
        self.current = current
        self.th = thresholds
        self.findings: list[Finding] = []
        self.imus: set[str] = set()
        self.joints: set[str] = set()
        self.order = _order(baseline)
        # An estimate that is not unique (several trees fit the data) says nothing reliable about where
        # a part hangs: only the signal-level findings are made from it. A baseline that is not unique
        # gives nothing to compare a placement with either.
        self.structural = not is_ambiguous(current) and not is_ambiguous(baseline)
        # joints the baseline window did not move: hung on the base as placeholders there, so where they
        # and the IMUs on their links hang now cannot be compared with it
        self.base_unplaced = {j for j in baseline.undetermined if j in baseline.joint_parent}

    def conf(self, key: str) -> float:
        """The current estimate's confidence in part ``key`` (``imu:NAME``, ``joint:NAME``), 1 if unstated."""
        return float(self.current.confidence.get(key, 1.0))

    def lost_below(self, j: str) -> tuple[list[str], list[str]]:
        """Live (unclaimed) baseline IMUs of ``j``'s subtree, and those no longer depending on ``j``."""
        sub = set(self.baseline.subtree(j))
        live = [i for i, jj in self.baseline.imu_joint.items() if jj in sub and i not in self.imus]
        return live, [i for i in live if not _depends(self.current, i, j)]

    def claim_subtree(self, j: str) -> None:
        """A cause at ``j`` explains the subtree's structure changes: every joint below ``j`` and every
        IMU below it that lost its dependency on ``j`` (an IMU that still depends on ``j`` but moved
        within the subtree is judged on its own)."""
        self.joints.update(self.baseline.subtree(j))
        self.imus.update(self.lost_below(j)[1])
        self.imus.update(i for i, jj in self.baseline.imu_joint.items() if jj == j)

    def link_lost(self, j: str, n_live: int) -> None:
        """Report that the ``n_live`` live IMUs below ``j`` no longer follow it, and claim the subtree."""
        self.findings.append(
            Finding(
                "link_lost",
                joint=j,
                from_=self.baseline.joint_parent[j],
                detail=f"{n_live} IMUs no longer follow {j}",
            )
        )
        self.claim_subtree(j)


def diff_bodies(
    baseline: Topology,
    current: Topology,
    health: SignalHealth | None = None,
    thresholds: DiffThresholds | None = None,
) -> Diff:
    """Typed findings that turn ``baseline`` into ``current`` (see the module doc for the order).

    ``health`` (from :func:`bodyschema.health.signal_health` on the current window, with the baseline
    as layout) adds the signal-level findings; without it only structure is compared and a missing IMU
    counts as dead.
    """
    st = _Claims(baseline, current, thresholds or DiffThresholds())
    _dead_imus(st, health)
    judged: set[str] = set()
    if health is not None:
        judged = _joint_causes(st, health)
    elif current.excitation:
        _locked_by_excitation(st)
    # 7 (first half). undecidable joints: nothing that hangs on them is judged
    undecided = [j for j in current.undetermined if j in baseline.joint_parent and j not in st.joints]
    _lost_links(st, undecided, judged)
    _undecided_joints(st, undecided)
    _single_imus(st, undecided)
    if health is not None:
        _loose_imus(st, health, undecided)
    _reparented_joints(st, undecided)
    reasons = undetermined_reasons(current) + unplaced_reasons(current)
    # the baseline itself not decided (several trees, or joints it did not move): no placement can be
    # said unchanged against it
    reasons += tuple(f"baseline: {r}" for r in undetermined_reasons(baseline) + unplaced_reasons(baseline))
    return Diff(findings=tuple(st.findings), reasons=reasons)


def _dead_imus(st: _Claims, health: SignalHealth | None) -> None:
    """1. IMUs that health calls dead, or that the current estimate lacks."""
    for imu, joint in st.baseline.imu_joint.items():
        h = health.imus.get(imu) if health is not None else None
        if h is not None and h.dead:
            st.findings.append(Finding("imu_dead", imu=imu, from_=joint, detail=h.state))
            st.imus.add(imu)
        elif imu not in st.current.imu_joint:
            st.findings.append(Finding("imu_dead", imu=imu, from_=joint, detail="silent"))
            st.imus.add(imu)


_ENCODER_DETAIL = {
    "frozen_encoder": "encoder flat while its link turns",
    "wrong_encoder": "encoder disagrees with its link's motion",
    "shifted_encoder": "encoder reads shifted against the baseline",
}


def _joint_causes(st: _Claims, health: SignalHealth) -> set[str]:
    """2.-4. joint-level causes from signal health, root first; returns the joints whose links' IMUs
    health judged (no structure-only verdict on them)."""
    judged: set[str] = set()
    moving = set(health.moving_joints)
    for j in st.order:
        jh = health.joints.get(j)
        if jh is None or j in st.joints:
            continue
        if jh.state not in ("moving", "flat"):
            judged.add(j)  # the IMUs on its link were judged: no structure-only verdict on it
        live, lost = st.lost_below(j)
        # The encoder already disagrees with the link here; the estimate's placement (even an
        # ambiguous one) only has to confirm that nothing below follows the joint.
        all_lost = bool(live) and len(lost) == len(live)
        if jh.state in ("wrong_encoder", "unfollowed") and all_lost:
            st.link_lost(j, len(live))  # the encoder turns, but nothing below follows it: the link broke off
        elif jh.state in _ENCODER_DETAIL:
            if jh.explained is None or jh.state == "shifted_encoder":
                c = 1.0
            else:
                c = max(0.5, 1.0 - jh.explained)
            detail = _ENCODER_DETAIL[jh.state]
            st.findings.append(Finding("encoder_fault", joint=j, confidence=c, detail=detail))
            st.claim_subtree(j)
        elif jh.state in ("still", "flat"):
            base_exc = st.baseline.excitation.get(j)
            was_moving = base_exc is None or base_exc > st.th.excitation_rad_s
            if was_moving and moving - {j}:
                detail = f"encoder {jh.excitation:.3f} rad/s while others move"
                st.findings.append(Finding("joint_locked", joint=j, detail=detail))
                st.claim_subtree(j)
    return judged


def _locked_by_excitation(st: _Claims) -> None:
    """Structure only: a joint whose encoder went flat while others move is locked (without IMU
    health an encoder fault reads the same)."""
    limit = st.th.excitation_rad_s
    moving = {j for j, e in st.current.excitation.items() if e > limit}
    for j in st.order:
        e = st.current.excitation.get(j)
        base_exc = st.baseline.excitation.get(j)
        if (
            j not in st.joints
            and e is not None
            and e <= limit
            and moving - {j}
            and (base_exc is None or base_exc > limit)
        ):
            st.findings.append(Finding("joint_locked", joint=j, detail=f"encoder {e:.3f} rad/s"))
            st.claim_subtree(j)


def _lost_links(st: _Claims, undecided: list[str], judged: set[str]) -> None:
    """Structure-only lost links: joints whose child link no IMU health could judge, where every live
    IMU of the subtree (at least ``min_link_imus``) stopped following the joint."""
    for j in st.order:
        if not st.structural or j in st.joints or j in undecided or j in judged:
            continue
        live, lost = st.lost_below(j)
        if live and len(lost) == len(live) and len(live) >= st.th.min_link_imus:
            st.link_lost(j, len(live))


def _undecided_joints(st: _Claims, undecided: list[str]) -> None:
    """7. joints the current estimate could not decide: reported, and their IMUs and children left
    unjudged."""
    for j in undecided:
        if j in st.joints:
            continue
        st.findings.append(
            Finding(
                "insufficient_excitation",
                joint=j,
                confidence=st.conf(f"joint:{j}"),
                detail="the window does not move this joint enough to place it",
            )
        )
        st.joints.add(j)
        st.imus.update(i for i, jj in st.baseline.imu_joint.items() if jj == j)
        st.joints.update(st.baseline.children(j))


def _single_imus(st: _Claims, undecided: list[str]) -> None:
    """5. single IMUs that follow no joint any more or another joint, unless a cause explains them."""
    for imu, b in st.baseline.imu_joint.items():
        if not st.structural or imu in st.imus or imu not in st.current.imu_joint:
            continue
        c = st.current.imu_joint[imu]
        if c == b or st.conf(f"imu:{imu}") < st.th.min_confidence:
            continue
        if c in undecided or c in st.joints or c in st.base_unplaced:
            continue
        if c is None and b is not None:
            # the estimator's confidence is in its (base) placement; report how sure "follows nothing" is
            key = f"imu:{imu}"
            sure = 1.0 if key not in st.current.confidence else min(1.0, max(0.5, 1.0 - st.conf(key)))
            st.findings.append(Finding("imu_detached", imu=imu, from_=b, confidence=sure))
        else:
            st.findings.append(Finding("imu_moved", imu=imu, from_=b, to=c, confidence=st.conf(f"imu:{imu}")))


def _loose_imus(st: _Claims, health: SignalHealth, undecided: list[str]) -> None:
    """5 (second half). IMUs that health finds loose on their baseline link, unless a cause explains
    them or the diff already placed them elsewhere."""
    placed = {f.imu for f in st.findings if f.imu}
    for imu, growth in sorted(health.loose.items()):
        b = st.baseline.imu_joint.get(imu)
        if b is None or imu in st.imus or imu in placed or b in undecided or b in st.joints:
            continue
        detail = f"follows {b} loosely: residual {growth:.1f}x its share on the baseline"
        st.findings.append(Finding("imu_detached", imu=imu, from_=b, detail=detail))
        st.imus.add(imu)


def _reparented_joints(st: _Claims, undecided: list[str]) -> None:
    """6. joints that hang under another joint than in the baseline, unless a cause explains them."""
    for j in st.order:
        if not st.structural or j in st.joints or j not in st.current.joint_parent:
            continue
        b, c = st.baseline.joint_parent[j], st.current.joint_parent[j]
        if b == c or st.conf(f"joint:{j}") < st.th.min_confidence:
            continue
        if c in st.joints or c in undecided or j in st.base_unplaced or c in st.base_unplaced:
            continue
        conf = st.conf(f"joint:{j}")
        st.findings.append(Finding("joint_reparented", joint=j, from_=b, to=c, confidence=conf))
