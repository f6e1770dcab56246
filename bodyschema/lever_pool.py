"""Slides of an IMU on its link, from lever arms pooled over many estimates.

One window's lever arm (:mod:`bodyschema.kinematics`) scatters between healthy windows by more than a
slide worth reporting, about as its reported std says, with errors that move with the motion
(docs/kinematics.md, "Geometry drift", has the measured scatter). The error is the motion's, so it
averages out over windows of other motion, and a slide is permanent: the lever arms of ``n_base``
estimates under the baseline (:class:`LeverPool`) are compared with those of the newest estimates.

**The error model.** Each estimate's lever arm is the IMU's true one plus an error ``e`` with a
covariance ``S`` the motion sets (the same for every window of one robot's motion), estimated by the
scatter of the baseline pool (``n_b`` estimates, ``ν = n_b - 1`` degrees of freedom). Consecutive
windows' errors are correlated when the motion changes slowly: an AR(1) with the lag-one correlation
``ρ`` of the baseline pool's errors. The mean of ``k`` consecutive errors then has the variance
``v(k) S``, ``v(k) = (1 + 2 Σⱼ (1 - j/k) ρʲ) / k`` (``κ / k`` for large ``k``, ``κ = (1 + ρ) / (1 -
ρ)``; 1 for one estimate, a prediction), and the degrees of freedom shrink to ``n_b / κ - 1``. The
lever arm lies in the plane perpendicular to its joint's axis, and so does every slide it can show
(one along the axis moves nothing a recording sees): the test is in that plane, the baseline's axis
given, ``p = 2`` (``p = 3`` without an axis). The change of the mean ``d = r̄_recent - r̄_base`` of
``k`` recent estimates there has covariance ``Σ = S (v(n_b) + v(k))`` (a small ridge added), and
Hotelling's ``T² = dᵀ Σ⁻¹ d`` follows ``ν p / (ν - p + 1) F(p, ν - p + 1)``. A slide is reported when
``T²`` exceeds that distribution's quantile and ``|d|`` exceeds ``floor_m``: ``alpha`` is the false
alarm rate of one comparison on a healthy robot, the floor a change too small to matter.

**A step, looked for at every age.** A slide is a step: the newest ``k`` estimates are compared with
the baseline's pool for every ``k`` from 2 to ``n_recent``, so a large slide shows in the first
windows after it and a small one once enough windows after it are averaged. Each look leaves out the
one of its ``k`` estimates farthest from the pool's mean (one window's outlier is no slide). The look
at the full recent pool is tested at ``alpha / 2``, the shorter looks share the other half
(Bonferroni), so a comparison's false alarm rate stays at most ``alpha``. With ``n_recent = 1`` the
one look is the newest estimate as it is: a prediction, whose covariance is one window's own.

**How many estimates.** The smallest slide found is set by ``S (v(n_b) + v(k))`` and by the limit,
which falls towards the χ² quantile as ``ν`` grows; both ask for a large baseline pool, whose price is
time (the default pools, and how long slides take to be found: docs/kinematics.md, "Geometry drift",
and ``bodyhealth bench drift``). Comparing two estimates by their stated stds
(:func:`~bodyschema.kinematic_drift.kinematic_findings`) instead takes each window's error to be its
noise, which on some links the motion exceeds several times; the pool's scatter holds it.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> arm = np.array([0.2, 0.0, 0.0])
>>> def estimates(n, shift=0.0):
...     return [{"imu1": arm + [0.0, shift, 0.0] + rng.normal(0, 0.003, 3)} for _ in range(n)]
>>> base, healthy = LeverPool(tuple(estimates(80))), LeverPool(tuple(estimates(40)))
>>> pooled_shifts(base, healthy, {"imu1": "j1"}, axes={"imu1": np.array([0.0, 0.0, 1.0])})
()
>>> slid = LeverPool(tuple(estimates(40, shift=0.006)))
>>> [(f.kind, f.imu) for f in pooled_shifts(base, slid, {"imu1": "j1"})]
[('imu_shifted', 'imu1')]
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats
from scipy.linalg import null_space

from bodyschema.findings import Finding
from bodyschema.kinematic_drift import DriftOptions, kinematic_findings
from bodyschema.kinematics import Kinematics
from bodyschema.topology import Topology

__all__ = ["POOL_KEY", "LeverPool", "PoolOptions", "pooled_shifts", "stored_drift"]

#: The key of a kept geometry's JSON that holds its pool (:meth:`LeverPool.to_json`).
POOL_KEY = "lever_arm_pool"

#: Lever arms kept to this many metres (0.01 mm) in the JSON.
_DIGITS = 5


@dataclass(frozen=True)
class PoolOptions:
    """How many estimates each pool holds and how sure a slide must be (module docstring).

    ``min_share``: an IMU is compared when its lever arm converged in at least this share of each
    pool's estimates; ``ridge_m``: the std added along every direction (without an axis, the scatter
    along it is nil and would make ``Σ`` singular)."""

    n_base: int = 80
    n_recent: int = 40
    alpha: float = 1e-5
    floor_m: float = 0.002
    min_share: float = 0.5
    ridge_m: float = 0.0003


@dataclass(frozen=True)
class LeverPool:
    """The lever arms (m, IMU frame) of consecutive geometry estimates: one ``{imu: lever arm}`` per
    estimate, holding the IMUs whose lever arm converged in it."""

    estimates: tuple[Mapping[str, np.ndarray], ...] = ()

    @property
    def n(self) -> int:
        return len(self.estimates)

    def add(self, kin: Kinematics, keep: int | None = None) -> LeverPool:
        """This pool with ``kin``'s converged lever arms appended; with ``keep``, only the newest
        ``keep`` estimates."""
        arms = {
            name: np.asarray(k.lever_arm, dtype=float)
            for name, k in kin.imus.items()
            if k.converged and k.lever_arm is not None and k.joint is not None
        }
        kept = (*self.estimates, arms)
        return LeverPool(kept[-keep:] if keep else kept)

    def arms(self, imu: str) -> np.ndarray:
        """The lever arms of ``imu`` in this pool, oldest first, shape (k, 3)."""
        return np.array([e[imu] for e in self.estimates if imu in e]).reshape(-1, 3)

    def to_json(self) -> list[dict[str, list[float]]]:
        return [{k: [round(float(x), _DIGITS) for x in v] for k, v in e.items()} for e in self.estimates]

    @classmethod
    def from_json(cls, data: Any) -> LeverPool:
        """Read back :meth:`to_json`; None or a missing key (a row kept before pools were) is empty."""
        if not data:
            return cls()
        return cls(tuple({k: np.asarray(v, dtype=float) for k, v in e.items()} for e in data))


def _rho(arms: np.ndarray) -> float:
    """The lag-one correlation ``ρ`` of consecutive errors, clipped to ``0 ≤ ρ ≤ 0.9`` (a negative
    estimate is noise: independent windows are the floor)."""
    e = arms - arms.mean(axis=0)
    den = float(np.sum(e * e))
    rho = float(np.sum(e[1:] * e[:-1])) / den if den > 0 else 0.0
    return min(max(rho, 0.0), 0.9)


def _mean_variances(k_max: int, rho: float) -> np.ndarray:
    """The variance of the mean of ``k`` consecutive AR(1) errors of unit variance, lag-one
    correlation ``rho``, for each ``k`` from 1 to ``k_max``: ``(1 + 2 Σⱼ₌₁ᵏ⁻¹ (1 - j/k) ρʲ) / k``;
    ``κ / k`` for large ``k``, 1 for one. All at once (running sums of ``ρʲ`` and ``j ρʲ``): a
    comparison looks at every ``k`` up to ``n_recent``.

    >>> np.round(_mean_variances(3, 0.5), 4).tolist()  # 1, (1 + ρ) / 2, (3 + 4ρ + 2ρ²) / 9
    [1.0, 0.75, 0.6111]
    """
    j = np.arange(1.0, max(k_max, 1))
    powers = rho**j
    below = np.concatenate(([0.0], np.cumsum(powers)))  # Σ ρʲ over j < k
    weighted = np.concatenate(([0.0], np.cumsum(j * powers)))  # Σ j ρʲ over j < k
    k = np.arange(1.0, k_max + 1)
    return (1.0 + 2.0 * (below[:k_max] - weighted[:k_max] / k)) / k


def _mean_variance(k: int, rho: float) -> float:
    """:func:`_mean_variances` of one ``k``."""
    return float(_mean_variances(k, rho)[-1])


def _limit(nu: float, alpha: float, p: int = 3) -> float:
    """The ``1 - alpha`` quantile of Hotelling's ``T²`` with ``p`` dimensions and ``nu`` degrees of
    freedom of the covariance."""
    return nu * p / (nu - p + 1) * float(stats.f.isf(alpha, p, nu - p + 1))


def _in_plane(arms: np.ndarray, plane: np.ndarray | None) -> np.ndarray:
    """Lever arms (k, 3) in the coordinates of ``plane`` (3, 2, orthonormal); None: as they are."""
    return arms if plane is None else arms @ plane


@dataclass(frozen=True)
class _Base:
    """One IMU's baseline pool as the test reads it: in the plane perpendicular to its axis (``plane``,
    None: all three directions), its mean, covariance ``S`` (plus the ridge), the lag-one correlation
    ``ρ`` of its errors and the degrees of freedom ``ν``."""

    plane: np.ndarray | None
    n: int
    mean: np.ndarray
    cov: np.ndarray
    rho: float
    nu: float
    mean_variance: float  # of the pool's mean, per unit of one window's (:func:`_mean_variance`)

    @classmethod
    def of(cls, arms: np.ndarray, o: PoolOptions, axis: np.ndarray | None) -> _Base:
        plane = None if axis is None else null_space(np.asarray(axis, dtype=float).reshape(1, 3))
        x = _in_plane(arms, plane)
        p = x.shape[1]
        rho = _rho(x)
        kappa = (1.0 + rho) / (1.0 - rho)
        cov = np.cov(x.T).reshape(p, p) + o.ridge_m**2 * np.eye(p)
        n = x.shape[0]
        return cls(plane, n, x.mean(axis=0), cov, rho, max(n / kappa - 1.0, p + 1.0), _mean_variance(n, rho))

    def distances(self, x: np.ndarray) -> np.ndarray:
        """Each of ``x``'s (k, p) squared distance from the pool's mean, in the pool's metric; ``x`` in
        the plane's coordinates (:func:`_in_plane`)."""
        return self._metric(x - self.mean)

    def _metric(self, e: np.ndarray) -> np.ndarray:
        """``e S⁻¹ eᵀ`` of each row of ``e`` (m, p), in one solve."""
        return np.einsum("ij,ij->i", e, np.linalg.solve(self.cov, e.T).T)

    def t2(self, recent: np.ndarray) -> tuple[float, np.ndarray]:
        """``T²`` of the mean of ``recent`` (k, 3) against the pool's, and the change; each mean's
        variance that of ``k`` (``n``) consecutive AR(1) errors, so one recent estimate is a
        prediction: its own error is one window's, ``S``."""
        x = _in_plane(recent, self.plane)
        d = x.mean(axis=0) - self.mean
        return float(self.t2s(d[None], np.array([x.shape[0]]))[0]), d

    def t2s(self, d: np.ndarray, k: np.ndarray) -> np.ndarray:
        """``T²`` of each change ``d`` (m, p) of a mean of ``k`` (m,) recent estimates from the pool's:
        every look of a comparison in one solve."""
        scale = self.mean_variance + _mean_variances(int(k.max()), self.rho)[k - 1]
        return self._metric(d) / scale


def _limits(pool: _Base, o: PoolOptions) -> tuple[float, float]:
    """The ``T²`` limits of the look at the full recent pool (``alpha / 2``) and of each look at fewer
    of its newest estimates (the other half, split over the ``n_recent - 2`` looks from 2 to
    ``n_recent - 1``); one look only: all of ``alpha``."""
    p = len(pool.mean)
    if o.n_recent <= 2:
        return (_limit(pool.nu, o.alpha, p),) * 2
    return _limit(pool.nu, o.alpha / 2, p), _limit(pool.nu, o.alpha / 2 / (o.n_recent - 2), p)


def _looks(pool: _Base, b: np.ndarray, o: PoolOptions) -> list[tuple[float, np.ndarray, float, int]]:
    """``(T², change, limit, k)`` of each look at the newest ``k`` lever arms ``b`` (module docstring):
    each without the one farthest from the pool's mean, so one window's outlier moves none."""
    full, part = _limits(pool, o)
    if o.n_recent == 1:
        return [(*pool.t2(b[-1:]), full, 1)]
    m = b.shape[0]
    if m < 2:
        return []
    # every look at once (a pool is judged for every k up to n_recent, for every IMU, in each
    # comparison): the newest k's sum less its farthest, their means' change, and their T²
    x = _in_plane(b, pool.plane)
    far = pool.distances(x)
    ks = np.arange(2, m + 1)
    drop = np.array([m - k + int(np.argmax(far[-k:])) for k in ks])
    newest = np.cumsum(x[::-1], axis=0)[ks - 1]
    d = (newest - x[drop]) / (ks - 1)[:, None] - pool.mean
    t2 = pool.t2s(d, ks - 1)
    return [
        (float(t), dk, full if k == o.n_recent else part, int(k)) for t, dk, k in zip(t2, d, ks, strict=True)
    ]


def pooled_shifts(
    base: LeverPool,
    recent: LeverPool,
    joints: Mapping[str, str | None],
    options: PoolOptions | None = None,
    skip: Collection[str] = (),
    axes: Mapping[str, np.ndarray | None] | None = None,
) -> tuple[Finding, ...]:
    """``imu_shifted`` for each IMU of ``joints`` (``{imu: joint}``) whose newest lever arms moved from
    the baseline pool's beyond what its scatter allows (module docstring): the newest ``k`` of
    ``recent`` for every ``k`` up to ``n_recent`` (:func:`_limits`), the surest look reported; none
    until the baseline's pool is full. IMUs in ``skip`` are left out (found turned, or
    their joint's axis bent: their lever arm moves with the turn). ``axes`` (``{imu: its joint's axis
    in its frame}``, the baseline's) puts each IMU's test in the plane perpendicular to its axis."""
    o = options or PoolOptions()
    if base.n < o.n_base or recent.n == 0:
        return ()
    out: list[Finding] = []
    for imu, joint in joints.items():
        if imu in skip or joint is None:
            continue
        a, b = base.arms(imu), recent.arms(imu)[-o.n_recent :]
        if a.shape[0] < max(o.min_share * base.n, 5) or b.shape[0] < o.min_share * min(recent.n, o.n_recent):
            continue
        pool = _Base.of(a, o, (axes or {}).get(imu))
        seen = [x for x in _looks(pool, b, o) if x[0] > x[2] and float(np.linalg.norm(x[1])) > o.floor_m]
        if not seen:
            continue
        t2, d, limit, k = max(seen, key=lambda x: x[0] / x[2])
        what = (
            f"the mean of the last {k} estimates but the farthest against {a.shape[0]} under the baseline"
            if k > 1
            else f"the newest estimate against the mean of {a.shape[0]} under the baseline"
        )
        out.append(
            Finding(
                kind="imu_shifted",
                imu=imu,
                joint=joint,
                confidence=round(1.0 - 0.5 * math.sqrt(limit / t2), 4),
                detail=(
                    f"lever arm moved {float(np.linalg.norm(d)) * 1e3:.1f} mm, {what} "
                    f"(T² {t2:.0f}, limit {limit:.0f})"
                ),
            )
        )
    return tuple(out)


def stored_drift(
    baseline: Mapping[str, Any],
    latest: Mapping[str, Any],
    topology: Topology,
    options: PoolOptions | None = None,
) -> tuple[Finding, ...]:
    """The drift from a robot's kept geometry baseline to its newest estimate, both as kept (kinematics
    JSON, each with its :data:`POOL_KEY`): :func:`~bodyschema.kinematic_drift.kinematic_findings` of the
    two estimates without their lever arms (turns, bends, dead bands), then the slides of the IMUs those
    left alone (a turned IMU, or one on a joint whose axis bent, moves its lever arm with the turn):
    the newest ``k`` estimates of the recent pool against the baseline's, for every ``k`` up to
    ``n_recent`` (:func:`pooled_shifts`, each in the plane perpendicular to the baseline's axis; module
    docstring). Until the baseline's pool is full no slide is judged. The worker's
    alerts and the API's drift both come from here, on the same stored rows."""
    then, now = Kinematics.from_json(dict(baseline), topology), Kinematics.from_json(dict(latest), topology)
    found = kinematic_findings(then, now, DriftOptions(lever_arms=False))
    bent = {f.joint for f in found if f.kind == "axis_changed"}
    skip = {f.imu for f in found if f.imu is not None} | {
        imu for imu, k in then.imus.items() if k.joint in bent
    }
    joints = {imu: k.joint for imu, k in then.imus.items()}
    axes = {imu: k.axis for imu, k in then.imus.items()}
    pools = LeverPool.from_json(baseline.get(POOL_KEY)), LeverPool.from_json(latest.get(POOL_KEY))
    return (*found, *pooled_shifts(*pools, joints, options, skip, axes))
