"""Excitation design: the joint motion that decides the tree and the IMUs' geometry in the least time.

The fast estimator (:mod:`bodyschema.fast_core`) decides which joints move an IMU by regressing its gyro
on the joints' rates, ``ω = Rᵀ Σ_{j ∈ anc} a_j q̇_j``: its columns are the ancestor joints' velocity
histories. The decision is quick when those columns are well separated (the column-normalised regressor
has a small condition number) and each is well above the gyro noise (``min_excitation_snr``). So a plan
here is:

* a **finite Fourier series** per joint (Swevers, Ganseman, Tukel, De Schutter, Van Brussel, IEEE T-RA
  1997): joint j's displacement is ``Σ_h a_jh/ω_jh sin(ω_jh t + φ_jh)``, every joint on frequencies of
  its own in ``band``, with the phases, weights and frequency assignment searched to minimise the
  worst condition number over the decisive regressors (each IMU's ancestor set, and every pair of
  excited joints, since the fast method tries every joint on every link) on the shortest prefix of
  the motion that can reach ``target_cond``;
* or **staggered single-joint segments** (Mittendorfer and Cheng: one joint at a time, the others
  still), chosen instead when one pass over the joints is shorter than the Fourier prefix: disjoint
  supports give exactly orthogonal columns;

then each joint's amplitude is the largest its position, velocity and acceleration limits allow (the
condition number of the normalised regressor does not depend on it), under a raised-cosine window that
starts and ends the plan at rest at the start pose. Joints not excited are held still. The search has a
bounded budget (``max_evaluations`` cost evaluations on a ``eval_rate`` grid), so planning cost does
not depend on luck.

The tree is decided within that prefix; the **geometry** (:mod:`bodyschema.kinematics`) needs more. An
IMU's lever arm ``r`` is read from the centripetal term of its accelerometer, ``[ω]×[ω]× r`` (for a
root joint ``-q̇² r``), beside gravity turning with the joint, ``G0 + G1 cos q + G2 sin q``. What
informs ``r`` is the part of ``q̇²`` those three do not explain. For a single sinusoid ``q̇²`` is a
function of ``q`` (``ω²(A² − q²)``, nearly ``cos q`` over a small swing): almost nothing is left, and
one joint at a time (each segment a sinusoid bump) leaves nothing. Hence, with ``shape`` ``cubic``
(the default), once the prefix that decides the tree has ended at rest, each joint follows for the rest
of the plan a fundamental and its third harmonic at equal velocity weights in antiphase:
``d ∝ sin θ − sin 3θ / 3 = (4/3) sin³ θ``, ``θ = ω_j (t − delay_j)``. It dwells at the centre and at
both ends, so at most positions the joint passes both slowly and fast: the unexplained share of ``q̇²``
is about 1.5 times that of the free series (more than twice the information per second) and the RMS
speed 0.58 of the limit instead of about 0.4 at the same peak. Its fundamentals lie in
``fundamental`` (its acceleration, about ``4ω`` times the velocity amplitude, stays within the
limit there), spread over the joints; each joint starts at rest at the centre (``d``, ``v`` and ``a``
are all zero at ``θ = 0``) after a searched delay and stops at its last return to the centre, so the
cubic needs no window. Each part is scaled to the limits on its own (they follow each other in time).

Example
-------
>>> import numpy as np
>>> lim = JointLimits(("a", "b"), np.array([-1.0, -2.0]), np.array([1.0, 2.0]), np.ones(2), np.full(2, 4.0))
>>> plan = plan_excitation(lim, np.zeros(2), 20.0)
>>> plan.method, plan.q.shape, bool(check_limits(plan, lim) == [])
('staggered', (2001, 2), True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = [
    "ExcitationPlan",
    "JointLimits",
    "PlanOptions",
    "check_limits",
    "cubic_motion",
    "finite_differences",
    "fit_to_limits",
    "groups_from_topology",
    "maximal_groups",
    "plan_excitation",
    "regressor_cost",
    "staggered_motion",
    "undecided_joints",
]


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits: position ``lower``/``upper`` (rad; ±inf for a continuous joint), ``velocity``
    (rad/s) and ``acceleration`` (rad/s²), both finite and > 0."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.names)
        for f in ("lower", "upper", "velocity", "acceleration"):
            a = np.asarray(getattr(self, f), dtype=np.float64)
            if a.shape != (n,):
                raise ValueError(f"limits: {f} has shape {a.shape}, expected ({n},)")
            object.__setattr__(self, f, a)
        if not (np.isfinite(self.velocity).all() and (self.velocity > 0).all()):
            raise ValueError("limits: every velocity limit must be finite and > 0")
        if not (np.isfinite(self.acceleration).all() and (self.acceleration > 0).all()):
            raise ValueError("limits: every acceleration limit must be finite and > 0")
        if (self.lower >= self.upper).any():
            bad = [self.names[i] for i in np.flatnonzero(self.lower >= self.upper)]
            raise ValueError(f"limits: lower >= upper for {', '.join(bad)}")

    def subset(self, names: Sequence[str]) -> JointLimits:
        """The limits of ``names`` (all must be known), in that order."""
        idx = [self.names.index(n) for n in names]
        return JointLimits(
            tuple(names), self.lower[idx], self.upper[idx], self.velocity[idx], self.acceleration[idx]
        )


@dataclass(frozen=True)
class PlanOptions:
    """Settings of :func:`plan_excitation` (validated once, here)."""

    #: Sample rate of the written plan, Hz.
    rate: float = 100.0
    #: Frequency band of the Fourier series, Hz: well below a servo's bandwidth (the simulators' 4 Hz)
    #: and the fast estimator's comparison band, above the drift of a slow sweep.
    band: tuple[float, float] = (0.2, 1.0)
    #: ``cubic`` (see the module docstring) or ``free``: ``harmonics`` frequencies of its own per
    #: joint in ``band``, under a raised-cosine window.
    shape: str = "cubic"
    #: Harmonics per joint (``free``).
    harmonics: int = 2
    #: The cubic's fundamentals, Hz: its third harmonic stays in ``band`` and at 0.9 rad/s its
    #: acceleration (about 4ω times the peak velocity / 1.54) stays under 4 rad/s².
    fundamental: tuple[float, float] = (0.15, 0.25)
    #: Latest start of a joint's cubic, s (the search picks each joint's in [0, this]).
    max_delay: float = 1.0
    #: Fraction of each limit the plan may use (the rest is left for tracking error).
    margin: float = 0.9
    #: Raised-cosine ramp from rest at the start and back to rest at the end, s.
    ramp: float = 1.0
    #: Single-joint segment length, s (one out-and-back of one joint).
    segment: float = 2.0
    #: The worst normalised condition number accepted as "decides".
    target_cond: float = 3.0
    #: Prefix windows tried, s: multiples of this up to the plan's length.
    window_step: float = 5.0
    #: Grid the cost is evaluated on, Hz (the regressor's columns are band-limited below ``band[1]``).
    eval_rate: float = 8.0
    #: Random starts per window, then single-joint phase moves: the whole search's budget.
    candidates: int = 24
    max_evaluations: int = 600
    #: Half-range assumed about the start for a joint without position limits, rad.
    free_range: float = 1.5
    seed: int = 0

    def __post_init__(self) -> None:
        bad = [
            f.name
            for f in fields(self)
            if f.name not in ("band", "fundamental", "seed", "shape") and not getattr(self, f.name) > 0
        ]
        if not 0 < self.band[0] < self.band[1]:
            bad.append("band")
        if not 0 < self.fundamental[0] <= self.fundamental[1]:
            bad.append("fundamental")
        if self.shape not in ("cubic", "free"):
            bad.append("shape")
        if self.margin > 1 or self.target_cond < 1:
            bad.append("margin/target_cond")
        if bad:
            raise ValueError(f"PlanOptions: {', '.join(bad)} out of range")


@dataclass(frozen=True)
class ExcitationPlan:
    """A joint trajectory sampled at ``rate``: ``q`` (T, N) rad for ``joint_names`` at times ``t``.

    ``excited`` are the joints moved; ``method`` ``fourier``, ``staggered`` or ``none``; ``decide_s``
    the prefix (s) at which the worst normalised condition number (``cond``) reaches the target;
    ``evaluations`` the cost evaluations the search spent; ``reason`` says why a plan is empty.
    """

    joint_names: tuple[str, ...]
    rate: float
    t: np.ndarray
    q: np.ndarray
    excited: tuple[str, ...]
    method: str
    decide_s: float | None
    cond: float
    evaluations: int = 0
    reason: str = ""
    rms_velocity: dict[str, float] = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0

    def to_json(self, samples: bool = True) -> dict[str, Any]:
        """JSON: joints, rate, samples (rows of positions, rad), and the plan's figures."""
        out: dict[str, Any] = {
            "joints": list(self.joint_names),
            "rate": self.rate,
            "seconds": self.seconds,
            "excited": list(self.excited),
            "method": self.method,
            "decide_s": self.decide_s,
            "cond": self.cond if math.isfinite(self.cond) else None,
            "rms_velocity": self.rms_velocity,
            "reason": self.reason,
        }
        if samples:
            out["samples"] = np.round(self.q, 6).tolist()
        return out


# ---------------------------------------------------------------------------------------- checks
def finite_differences(q: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and acceleration of samples ``q`` (T, N) at ``rate``: what a controller interpolating
    the plan linearly sees (first differences between samples, second differences at samples)."""
    v = np.diff(q, axis=0) * rate
    a = np.diff(q, n=2, axis=0) * rate**2
    return v, a


def check_limits(plan: ExcitationPlan, limits: JointLimits, tol: float = 1e-9) -> list[str]:
    """Every limit the written plan exceeds at any sample (empty: none)."""
    lim = limits.subset(plan.joint_names)
    v, a = finite_differences(plan.q, plan.rate)
    out = []
    for j, name in enumerate(plan.joint_names):
        q = plan.q[:, j]
        if len(q) and (q.min() < lim.lower[j] - tol or q.max() > lim.upper[j] + tol):
            out.append(f"{name}: position outside [{lim.lower[j]}, {lim.upper[j]}]")
        if len(v) and np.abs(v[:, j]).max() > lim.velocity[j] * (1 + tol):
            out.append(f"{name}: velocity {np.abs(v[:, j]).max():.4g} > {lim.velocity[j]}")
        if len(a) and np.abs(a[:, j]).max() > lim.acceleration[j] * (1 + tol):
            out.append(f"{name}: acceleration {np.abs(a[:, j]).max():.4g} > {lim.acceleration[j]}")
    return out


# ------------------------------------------------------------------------------------- the cost
def maximal_groups(groups: Sequence[Sequence[int]]) -> list[np.ndarray]:
    """The groups not contained in another: a column subset's condition number is no larger than the
    whole's (singular values interlace), so only the maximal ancestor sets bound the rest."""
    sets = sorted({frozenset(int(i) for i in g) for g in groups if len(g)}, key=len, reverse=True)
    keep: list[frozenset[int]] = []
    for s in sets:
        if not any(s <= k for k in keep):
            keep.append(s)
    return [np.array(sorted(s), dtype=np.intp) for s in keep]


def regressor_cost(V: np.ndarray, groups: Sequence[np.ndarray]) -> float:
    """Worst condition number of the centred, column-normalised velocity regressor ``V`` (T, n) over
    ``groups`` (column sets) and over every pair of columns."""
    X = V - V.mean(axis=0)
    norm = np.linalg.norm(X, axis=0)
    if (norm <= 1e-12).any():
        return math.inf
    X = X / norm
    C = X.T @ X  # correlation matrix
    n = C.shape[0]
    worst = 1.0
    if n > 1:
        rho = np.abs(C[np.triu_indices(n, 1)]).max()
        worst = (1 + rho) / max(1 - rho, 1e-12)
    for g in groups:
        if len(g) > 2:
            ev = np.linalg.eigvalsh(C[np.ix_(g, g)])
            worst = max(worst, math.sqrt(ev[-1] / max(ev[0], 1e-24)))
    return float(worst)


# ------------------------------------------------------------------------------------ the shapes
Shape = tuple[np.ndarray, np.ndarray, np.ndarray]


def _window(t: np.ndarray, total: float, ramp: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raised-cosine window up over ``ramp`` s and down over the last ``ramp`` s, and its derivatives."""
    r = min(ramp, total / 2)
    w, dw, ddw = np.ones_like(t), np.zeros_like(t), np.zeros_like(t)
    for u, s in ((t / r, 1.0), ((total - t) / r, -1.0)):
        m = u < 1
        um = np.clip(u[m], 0, 1)
        w[m] *= 0.5 - 0.5 * np.cos(np.pi * um)
        dw[m] = s * 0.5 * np.pi / r * np.sin(np.pi * um)
        ddw[m] = 0.5 * (np.pi / r) ** 2 * np.cos(np.pi * um)
    return w, dw, ddw


def _fourier(
    t: np.ndarray, freq: np.ndarray, weight: np.ndarray, phase: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Displacement, velocity and acceleration (T, n) of the series with unit-scale velocity weights."""
    w = 2 * np.pi * freq  # (n, H)
    arg = t[:, None, None] * w + phase
    s, c = np.sin(arg), np.cos(arg)
    d = np.sum(weight / w * s, axis=2)
    v = np.sum(weight * c, axis=2)
    a = -np.sum(weight * w * s, axis=2)
    return d, v, a


def fit_to_limits(
    t: np.ndarray,
    shape: tuple[np.ndarray, np.ndarray, np.ndarray],
    q0: np.ndarray,
    limits: JointLimits,
    margin: float,
) -> np.ndarray:
    """Per joint, the largest gain ``k`` with ``q0 + k·d`` inside the position limits and ``k·v``,
    ``k·a`` inside ``margin`` of the velocity and acceleration limits at every time of ``t``.

    ``shape`` is (d, v, a), each (T, n): the motion's displacement and its exact derivatives. The
    written samples' differences are means of these derivatives over a sample, so they stay within."""
    d, v, a = shape
    k = np.full(d.shape[1], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(d > 0, (limits.upper - q0) / d, np.inf).min(axis=0, initial=np.inf)
        lo = np.where(d < 0, (limits.lower - q0) / d, np.inf).min(axis=0, initial=np.inf)
        vk = margin * limits.velocity / np.abs(v).max(axis=0, initial=0)
        ak = margin * limits.acceleration / np.abs(a).max(axis=0, initial=0)
    for cap in (up * margin, lo * margin, vk, ak):
        k = np.minimum(k, np.nan_to_num(cap, nan=np.inf))
    return np.where(np.isfinite(k), np.maximum(k, 0.0), 0.0)


def staggered_motion(
    t: np.ndarray, n: int, segment: float, room_sign: np.ndarray, total: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One joint at a time: joint i moves out and back, ``(1 − cos 2πu)/2`` towards ``room_sign``, in
    segments i, i+n, i+2n, … of ``segment`` s, the others still; (d, v, a) each (T, n)."""
    seg = np.floor(t / segment).astype(np.int64)
    u = t / segment - seg
    whole = (seg + 1) * segment <= total + 1e-9
    d, v, a = (np.zeros((len(t), n)) for _ in range(3))
    for i in range(n):
        m = (seg % n == i) & whole
        d[m, i] = 0.5 * (1 - np.cos(2 * np.pi * u[m]))
        v[m, i] = np.pi / segment * np.sin(2 * np.pi * u[m])
        a[m, i] = 2 * (np.pi / segment) ** 2 * np.cos(2 * np.pi * u[m])
    return d * room_sign, v * room_sign, a * room_sign


def cubic_motion(t: np.ndarray, freq: np.ndarray, delay: np.ndarray, total: float) -> Shape:
    """Joint j still until ``delay[j]``, then ``sin³(ω_j (t − delay_j))/ω_j`` (a fundamental and its
    third harmonic in antiphase) until its last return to the centre before ``total``, then still
    again; (d, v, a) each (T, n). At each start and stop the displacement, velocity and acceleration
    are all zero (θ³, θ², θ), so no window is needed: rest to rest at the start pose."""
    w = 2 * np.pi * np.asarray(freq, dtype=np.float64)
    th = (t[:, None] - delay) * w
    stop = np.floor(np.maximum(total - delay, 0.0) * w / np.pi + 1e-9) * np.pi
    inside = (th >= 0) & (th <= stop)
    s, c = np.sin(th), np.cos(th)
    d = np.where(inside, s**3 / w, 0.0)
    v = np.where(inside, 3 * s**2 * c, 0.0)
    a = np.where(inside, 3 * w * s * (2 * c**2 - s**2), 0.0)
    return d, v, a


# ----------------------------------------------------------------------------------- the search
@dataclass
class _Search:
    """The search's state: per joint frequencies, weights and phases (``cubic``: one start delay per
    joint in ``phase[:, 0]``); the cost's groups."""

    freq: np.ndarray
    weight: np.ndarray
    phase: np.ndarray
    groups: list[np.ndarray]
    rng: np.random.Generator
    cubic: bool = False
    evaluations: int = 0

    def cost(self, te: np.ndarray, total: float, ramp: float, phase: np.ndarray | None = None) -> float:
        self.evaluations += 1
        p = self.phase if phase is None else phase
        if self.cubic:
            return regressor_cost(cubic_motion(te, self.freq[:, 0], p[:, 0], total)[1], self.groups)
        d, v, _ = _fourier(te, self.freq, self.weight, p)
        w, dw, _ = _window(te, total, ramp)
        return regressor_cost(w[:, None] * v + dw[:, None] * d, self.groups)

    def draw(self, n: int, opts: PlanOptions) -> np.ndarray:
        """Random phases (n, H), or start delays (n, 1) in [0, ``max_delay``] for the cubic."""
        if self.cubic:
            return self.rng.uniform(0, opts.max_delay, (n, 1))
        return self.rng.uniform(0, 2 * np.pi, (n, self.phase.shape[1]))


def _slots(n: int, opts: PlanOptions, cubic: bool) -> np.ndarray:
    """(n, H) distinct frequencies. ``free``: in the band, joint i takes slots i, i+n, …: one low,
    one high. ``cubic``: (n, 1) fundamentals spread over ``fundamental``, handed out in a golden-ratio
    order so that joints next to each other in the joint order (often parent and child) are far
    apart."""
    if not cubic:
        h = opts.harmonics
        grid = np.linspace(opts.band[0], opts.band[1], n * h)
        return grid.reshape(h, n).T.copy()
    f = np.empty(n)
    f[np.argsort((np.arange(n) * 0.6180339887498949) % 1.0, kind="stable")] = np.linspace(
        *opts.fundamental, n
    )
    return f[:, None]


def _optimise(search: _Search, te: np.ndarray, total: float, opts: PlanOptions, budget: int) -> float:
    """Random starts, then one joint's phases at a time re-drawn, kept when the cost falls."""
    n = search.phase.shape[0]
    best = search.cost(te, total, opts.ramp)
    starts = min(opts.candidates, max(budget // 3, 1))
    for _ in range(starts):
        cand = search.draw(n, opts)
        c = search.cost(te, total, opts.ramp, cand)
        if c < best:
            best, search.phase = c, cand
    left = budget - starts - 1
    while left > 0 and best > opts.target_cond:
        j = int(search.rng.integers(n))
        cand = search.phase.copy()
        cand[j] = search.draw(1, opts)[0]
        c = search.cost(te, total, opts.ramp, cand)
        left -= 1
        if c < best:
            best, search.phase = c, cand
    return best


def _windowed(t: np.ndarray, search: _Search, total: float, ramp: float) -> Shape:
    """The free series under the raised-cosine window over [0, ``total``]: (d, v, a), still after."""
    d, v, a = _fourier(t, search.freq, search.weight, search.phase)
    w, dw, ddw = _window(t, total, ramp)
    ddw[t >= total] = 0.0
    return (
        w[:, None] * d,
        w[:, None] * v + dw[:, None] * d,
        w[:, None] * a + 2 * dw[:, None] * v + ddw[:, None] * d,
    )


def _then_cubic(
    t: np.ndarray,
    lead: float,
    seconds: float,
    search: _Search,
    start: np.ndarray,
    sub: JointLimits,
    opts: PlanOptions,
) -> tuple[Shape, str]:
    """The free series of ``search`` until ``lead`` s (ramped down to rest by then), then the cubic
    for the rest, its start delays searched on its first ``2 · window_step`` s; each part scaled to
    the limits on its own. ``search.evaluations`` counts both searches."""
    head = _windowed(t, search, lead, opts.ramp)
    tail_search = _Search(
        _slots(len(start), opts, True),
        np.ones((len(start), 1)),
        np.zeros((len(start), 1)),
        search.groups,
        search.rng,
        cubic=True,
    )
    te = np.arange(0, seconds - lead, 1 / opts.eval_rate)
    _optimise(
        tail_search, te[te < 2 * opts.window_step], seconds - lead, opts, max(opts.max_evaluations // 4, 8)
    )
    search.evaluations += tail_search.evaluations
    tail = cubic_motion(t - lead, tail_search.freq[:, 0], tail_search.phase[:, 0], seconds - lead)
    scaled = []
    for shape in (head, tail):
        k = fit_to_limits(t, shape, start, sub, opts.margin)
        scaled.append(tuple(k * x for x in shape))
    (d1, v1, a1), (d2, v2, a2) = scaled
    return (d1 + d2, v1 + v2, a1 + a2), "fourier"


def _choose(
    t: np.ndarray,
    seconds: float,
    grp: list[np.ndarray],
    start: np.ndarray,
    sub: JointLimits,
    opts: PlanOptions,
) -> tuple[Shape, str, float | None, float, int]:
    """The motion's shape (d, v, a), method, decision prefix, condition number and evaluations spent:
    the free Fourier series on the shortest prefix window reaching the target, unless one pass of
    single-joint segments is shorter; with ``shape`` ``cubic`` the series ends at rest at that prefix
    and the cubic (:func:`cubic_motion`) takes the rest of the plan. Each part is scaled to the
    limits on its own (they do not overlap in time)."""
    n = len(start)
    stagger_s = n * opts.segment  # one pass over the joints, one segment each
    te = np.arange(0, seconds, 1 / opts.eval_rate)
    search = _Search(
        _slots(n, opts, False),
        np.ones((n, opts.harmonics)),
        np.zeros((n, opts.harmonics)),
        grp,
        np.random.default_rng(opts.seed),
    )
    decide, cond = None, math.inf
    windows = [w for w in np.arange(opts.window_step, seconds + 1e-9, opts.window_step) if w < stagger_s]
    cubic = opts.shape == "cubic"
    per = max((opts.max_evaluations * 3 // 4 if cubic else opts.max_evaluations) // max(len(windows), 1), 8)
    for win in windows if n > 1 else []:
        cond = _optimise(search, te[te < win], seconds, opts, per)
        if cond <= opts.target_cond:
            decide = float(win)
            break
    if decide is None and stagger_s <= seconds:
        room = np.where(sub.upper - start >= start - sub.lower, 1.0, -1.0)
        shape = staggered_motion(t, n, opts.segment, room, seconds)
        return shape, "staggered", float(stagger_s), 1.0, search.evaluations
    # the free series holds until the prefix that decides, then ramps down to rest
    cubic_left = seconds - (decide or seconds) - opts.ramp
    if not cubic or cubic_left < opts.max_delay + 0.5 / opts.fundamental[0]:
        if decide is None:
            cond = search.cost(te, seconds, opts.ramp)
        return _windowed(t, search, seconds, opts.ramp), "fourier", decide, cond, search.evaluations
    assert decide is not None
    return (
        *_then_cubic(t, decide + opts.ramp, seconds, search, start, sub, opts),
        decide,
        cond,
        search.evaluations,
    )


def plan_excitation(
    limits: JointLimits,
    q0: np.ndarray,
    seconds: float,
    excite: Sequence[str] | None = None,
    groups: Sequence[Sequence[str]] | None = None,
    options: PlanOptions | None = None,
) -> ExcitationPlan:
    """The plan for ``seconds`` of motion from rest at ``q0`` (one per joint of ``limits``).

    ``excite`` names the joints to move (None: all; the rest are held at ``q0``); ``groups`` the
    joint sets a gyro sees together (each IMU's ancestors; None: all excited joints at once). See the
    module docstring for the method and its choice between Fourier and staggered segments.
    """
    opts = options or PlanOptions()
    if not seconds > 0:
        raise ValueError("seconds must be > 0")
    q0 = np.asarray(q0, dtype=np.float64)
    if q0.shape != (len(limits.names),):
        raise ValueError(f"start pose has {q0.shape} values for {len(limits.names)} joints")
    names = list(limits.names) if excite is None else [n for n in limits.names if n in set(excite)]
    unknown = sorted(set(excite or ()) - set(limits.names))
    if unknown:
        raise ValueError(f"no limits for joint(s) {', '.join(unknown)}")
    t = np.arange(round(seconds * opts.rate) + 1) / opts.rate
    q = np.broadcast_to(np.clip(q0, limits.lower, limits.upper), (len(t), len(q0))).copy()
    if not names:
        return ExcitationPlan(
            limits.names, opts.rate, t, q, (), "none", None, math.inf, 0, "nothing to excite"
        )
    idx = np.array([limits.names.index(n) for n in names], dtype=np.intp)
    sub = limits.subset(names)
    start = q[0, idx]
    lo = np.where(np.isfinite(sub.lower), sub.lower, start - opts.free_range)
    hi = np.where(np.isfinite(sub.upper), sub.upper, start + opts.free_range)
    sub = JointLimits(sub.names, lo, hi, sub.velocity, sub.acceleration)
    col = {n: i for i, n in enumerate(names)}
    grp = maximal_groups([[col[j] for j in g if j in col] for g in (groups or [names])])
    shape, method, decide, cond, spent = _choose(t, seconds, grp, start, sub, opts)
    k = fit_to_limits(t, shape, start, sub, opts.margin)
    q[:, idx] = start + k * shape[0]
    rms = np.sqrt(np.mean((k * shape[1]) ** 2, axis=0))
    return ExcitationPlan(
        limits.names,
        opts.rate,
        t,
        q,
        tuple(names),
        method,
        decide,
        float(cond),
        spent,
        rms_velocity={nm: float(r) for nm, r in zip(names, rms, strict=True)},
    )


# ------------------------------------------------------------------------- what a recording left open
def groups_from_topology(topo: Any) -> list[list[str]]:
    """Each IMU's ancestor joints in ``topo`` (and in every candidate tree that fits): the joint sets
    one gyro sees together."""
    out: list[list[str]] = []
    for tree in (topo, *topo.candidates):
        for joint in tree.imu_joint.values():
            if joint is not None:
                out.append(list(tree.ancestors(joint)))
    return out


def undecided_joints(topo: Any, kinematics: Any = None) -> tuple[str, ...]:
    """The joints to move so the data decide: those the topology's undetermined reasons name
    (:func:`bodyschema.diff.deciding_joints`) and the joints of IMUs whose axis or lever arm did not
    converge (``kinematics``, when given); in the topology's joint order."""
    from bodyschema.diff import deciding_joints

    need = set(deciding_joints(topo))
    if kinematics is not None:
        for imu in kinematics.imus.values():
            if imu.joint is not None and not imu.converged:
                need.add(imu.joint)
    return tuple(j for j in topo.joint_parent if j in need)
