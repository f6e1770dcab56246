"""From trained sensor networks to a 0/1 dependency matrix (paper Sec. III-B, III-C).

1. Transform-Invariant Jacobian (Eq. 13-14): for sampled joint configurations θ, the column norms of
   ``∂n_x/∂θ, ∂n_y/∂θ, ∂n_z/∂θ, ∂b/∂θ`` of each IMU's pose network, a (4, N) matrix per sample.
2. A statistic over the samples. ``"variance"`` is the paper's (Sec. III-C). ``"moment"`` — the second
   moment ``E[J̄²]`` — is the default: rotating a link about one fixed axis keeps the norm of that joint's
   rotation column constant, so its variance is ~0 and the paper's statistic drops an IMU's own parent
   joint (docs/design.md, 'Science notes'; measured on MuJoCo robots; the benchmark shows both).
3. The dependency feature (Eq. 16): the maximum over the four rows, normalized to unit length.
4. The threshold δ (Eq. 18) chosen by Eq. 19 over a grid: binarize the features, cluster the rows
   (log features) with a Dirichlet-process Gaussian mixture (sklearn ``BayesianGaussianMixture``),
   and score
   ``|det S| / m − λ Σ p_c log p_c`` (S: distances between cluster means, m: dispersion inside clusters,
   p_c: cluster shares). Eq. 19 alone cannot see a true 1 that drops out for all IMUs of a link, so
   among the δ giving clean clusters the one in the lowest wide empty band of log feature values
   wins (see :func:`choose_delta`).
5. Rows of one cluster are IMUs on one link: an IMU's entries near δ take its cluster's mean binary
   row, thresholded at 0.5 (the paper's "sample rows from the DPGMM, filter with 0.5") where the
   cluster clearly agrees; entries far from δ stay (:func:`cluster_vote`).

IMUs whose network barely depends on any joint (largest statistic below ``base_level`` times the median
over IMUs) sit on the base: normalizing their feature (Eq. 16) would turn noise into a unit vector.

Example
-------
>>> import numpy as np
>>> feats = np.array([[0.99, 0.01, 0.0], [0.98, 0.02, 0.01], [0.7, 0.7, 0.02], [0.5, 0.85, 0.03],
...                   [0.6, 0.55, 0.58], [0.4, 0.6, 0.7]])
>>> delta, labels = choose_delta(feats, rng=np.random.default_rng(0))
>>> (feats > delta).astype(int).tolist()
[[1, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 0], [1, 1, 1], [1, 1, 1]]
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
from sklearn.mixture import BayesianGaussianMixture

from bodyschema.network_weights import NetworkWeights
from bodyschema.recording import Recording

__all__ = [
    "STATISTICS",
    "JacobianFit",
    "NetworkDependency",
    "StableDependency",
    "choose_delta",
    "cluster_vote",
    "dependency_feature",
    "dependency_from_jacobian",
    "eq19_score",
    "invariant_jacobian",
    "jacobian_statistic",
    "network_dependency",
    "network_jacobian",
]

log = logging.getLogger(__name__)

STATISTICS = ("moment", "variance")

#: Features are clustered in log scale, clipped here: which joints an IMU depends on is a pattern of
#: ratios over a noise floor, and in linear scale a weak true dependency (0.15) sits as close to
#: "none" as to a strong one, so two links' IMUs could share a cluster.
CLUSTER_FLOOR = 0.03

#: A feature 20 times above or below δ is as sure as evidence gets: one entry far from δ must not
#: outweigh several entries that agree with each other.
EVIDENCE_CAP = float(np.log(20.0))


def invariant_jacobian(net: Any, theta: torch.Tensor) -> torch.Tensor:
    """Eq. 14 at each sample: (K, S, 4, N) column norms of the pose Jacobian of every IMU network.

    ``net`` has ``pose(theta) -> (R (K,S,3,3), b (K,S,3))``; ``theta`` is (S, N). One forward-mode pass
    per joint (N passes), batched over IMUs and samples.
    """
    from torch.func import jvp

    fused = getattr(net, "pose_jacobian_norms", None)
    if fused is not None:  # the sensor networks' one-pass form of the loop below
        return fused(theta)
    N = theta.shape[1]
    cols = []
    with torch.no_grad():
        for j in range(N):
            e = torch.zeros_like(theta)
            e[:, j] = 1.0
            (_, _), (dR, db) = jvp(net.pose, (theta,), (e,))
            rot = torch.linalg.vector_norm(dR, dim=-2)  # norms of the columns n_x, n_y, n_z: (K, S, 3)
            cols.append(torch.cat([rot, torch.linalg.vector_norm(db, dim=-1, keepdim=True)], -1))
    return torch.stack(cols, -1)  # (K, S, 4, N)


def jacobian_statistic(jbar: np.ndarray, statistic: str = "moment") -> np.ndarray:
    """Reduce (K, S, 4, N) over samples: ``"moment"`` E[J̄²] (default) or the paper's ``"variance"``."""
    if statistic == "moment":
        return np.mean(jbar**2, axis=1)
    if statistic == "variance":
        return np.var(jbar, axis=1)
    raise ValueError(f"unknown statistic {statistic!r}; choose one of {STATISTICS}")


def dependency_feature(stat: np.ndarray, base_level: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 16: max over the 4 rows, normalized per IMU -> ``(features (K, N), on_base (K,))``."""
    d = stat.max(axis=1)
    peak = d.max(axis=1)
    on_base = peak < base_level * max(float(np.median(peak)), 1e-30)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    feats = np.where(norm > 0, d / np.where(norm > 0, norm, 1.0), 0.0)
    feats[on_base] = 0.0
    return feats, on_base


def _cluster(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """DPGMM cluster labels of the rows of ``x`` (labels renumbered 0..C-1)."""
    K = x.shape[0]
    if K == 1:
        return np.zeros(1, dtype=int)
    n_comp = int(min(K, 2 * x.shape[1] + 2))
    gm = BayesianGaussianMixture(
        n_components=n_comp,
        weight_concentration_prior_type="dirichlet_process",
        weight_concentration_prior=10.0,  # favour splitting: split clusters are merged back by row
        covariance_type="spherical",
        reg_covar=1e-4,
        covariance_prior=1e-3,  # expect tight clusters: IMUs of one link have nearly equal rows
        max_iter=300,
        n_init=3,
        init_params="k-means++",
        random_state=int(rng.integers(2**31 - 1)),
    )
    labels = gm.fit_predict(x + rng.normal(scale=1e-6, size=x.shape))
    _, labels = np.unique(labels, return_inverse=True)
    return labels


def eq19_score(x: np.ndarray, labels: np.ndarray, lam: float = 0.1) -> float:
    """Eq. 19 for binarized rows ``x`` and cluster ``labels``: ``|det S| / m − λ Σ p log p``."""
    # clusters whose binarized rows coincide are one link (the paper's duplicate-row merge), so an
    # over-split link does not zero det S
    means = {c: x[labels == c].mean(axis=0) for c in np.unique(labels)}
    merged: dict[bytes, int] = {}
    relabel = labels.copy()
    for c, mu in means.items():
        key = np.round(mu, 9).tobytes()
        relabel[labels == c] = merged.setdefault(key, int(c))
    labels = relabel
    cs = np.unique(labels)
    mus = np.stack([x[labels == c].mean(axis=0) for c in cs])
    S = np.linalg.norm(mus[:, None, :] - mus[None, :, :], axis=-1)
    m = sum(float(np.sum((x[labels == c] - mus[i]) ** 2)) for i, c in enumerate(cs))
    p = np.array([np.mean(labels == c) for c in cs])
    det = abs(float(np.linalg.det(S))) if len(cs) > 1 else 0.0
    return det / (m + 1e-6) - lam * float(np.sum(p * np.log(p)))


def choose_delta(
    feats: np.ndarray,
    grid: np.ndarray | None = None,
    lam: float = 0.1,
    rng: np.random.Generator | None = None,
) -> tuple[float, np.ndarray]:
    """δ by Eq. 19 over ``grid`` (default 0.02..0.9); returns ``(δ, DPGMM cluster labels)``.

    The rows are clustered once, on the continuous features (IMUs on one link have similar rows).
    Each δ is scored on the binarized rows with those clusters: a δ that splits a cluster's members
    into different binary rows raises the dispersion m, one that makes two clusters' rows equal makes
    ``det S`` vanish. Among the near-best δ the one with the widest margin to every feature wins.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    grid = np.linspace(0.02, 0.9, 89) if grid is None else np.asarray(grid)
    moving = feats.any(axis=1)
    labels_full = np.full(len(feats), -1)
    if moving.sum() == 0:
        return float(grid[len(grid) // 2]), labels_full
    x_all = feats[moving]
    labels = _cluster(np.log(np.maximum(x_all, CLUSTER_FLOOR)), rng)
    labels_full[moving] = labels
    # a δ between the same two feature values binarizes alike: score each distinct binarization once
    seen: dict[bytes, float] = {}
    scores = np.empty(len(grid))
    for i, d in enumerate(grid):
        xb = x_all > d
        key = xb.tobytes()
        if key not in seen:
            seen[key] = eq19_score(xb.astype(float), labels, lam)
        scores[i] = seen[key]
    # Eq. 19 rewards clean clusters (m = 0) that are distinct (det S != 0) but, among those, cannot see a
    # true 1 that drops out for all IMUs of a link at once; so every δ scoring like a clean clustering
    # (m = 0 puts the score at 1e6 x det S) is a candidate, and the one farthest from any feature
    # value in log scale wins: the middle of the widest empty band of ratios, a max-margin threshold.
    #
    # Two empty bands can be about as wide: noise | weak true | strong true. A joint two links up
    # moves an IMU far less than its own joint, so its normalized feature is small but shared by every
    # IMU of the link, while the noise floor is the lowest band. The lowest band at least 3/4 as wide
    # as the widest one (and spanning a factor 2 or more) wins. When no clean clustering leaves such a
    # band (the DPGMM put two links' IMUs in one cluster, so no δ makes it clean), every δ competes.
    logx = np.log(np.maximum(x_all, 1e-4))  # ratios: "no dependency" is a noise floor, not a level
    clean = np.flatnonzero(scores >= 1e3)
    for near in (clean if len(clean) else np.flatnonzero(scores >= scores.max()), np.arange(len(grid))):
        pick = _lowest_wide_band(logx, np.log(grid[near]))
        if pick is not None:
            return float(grid[near[pick]]), labels_full
    margin = np.array([np.min(np.abs(logx - np.log(g))) for g in grid])
    return float(grid[int(np.argmax(margin))]), labels_full


def _lowest_wide_band(
    logx: np.ndarray, log_deltas: np.ndarray, min_margin: float = np.log(2.0) / 2
) -> int | None:
    """Index into ascending ``log_deltas`` of the threshold in the lowest wide empty band of ``logx``
    (margin to the nearest feature at least ``min_margin`` and 3/4 of the widest), or None."""
    if len(log_deltas) == 0:
        return None
    margin = np.array([np.min(np.abs(logx - d)) for d in log_deltas])
    if margin.max() < min_margin:
        return None
    # contiguous runs of thresholds with no feature between them are one band
    between = [np.any((logx > a) & (logx < b)) for a, b in itertools.pairwise(log_deltas)]
    bands = np.split(np.arange(len(log_deltas)), np.flatnonzero(between) + 1)
    for band in bands:
        best = band[int(np.argmax(margin[band]))]
        if margin[best] >= max(0.75 * margin.max(), min_margin):
            return int(best)
    return None


@dataclass
class NetworkDependency:
    """What :func:`network_dependency` found: matrix (K, N) bool, per-IMU features, δ, confidences,
    and per-entry evidence: how far (log ratio, capped at :data:`EVIDENCE_CAP`) each feature sits
    from δ, for the correction to overrule the weakest entries first."""

    dependency: np.ndarray
    features: np.ndarray
    delta: float
    labels: np.ndarray
    undetermined: np.ndarray
    imu_confidence: np.ndarray
    joint_confidence: np.ndarray
    loss: list[float]
    evidence: np.ndarray
    #: the trained sensor networks' weights (method ``network``/``network-paper``), for a warm start
    weights: NetworkWeights | None = None
    #: True when the networks' training began from a warm start's weights
    warm: bool = False


class JacobianFit(NamedTuple):
    """What :func:`network_jacobian` returns: the Jacobian norms (K, S, rows, N), the loss per epoch,
    and the trained sensor networks' weights (None for the MLP baseline)."""

    jbar: np.ndarray
    loss: list[float]
    weights: NetworkWeights | None
    warm: bool = False


def network_jacobian(
    rec: Recording,
    kind: str = "network",
    epochs: int | None = None,
    hidden: tuple[int, ...] = (32, 32, 32),
    samples: int = 1000,
    seed: int = 0,
    gravity: bool | None = None,
    progress: bool = False,
    warm_start: NetworkWeights | None = None,
    watch: Callable[[np.ndarray, int], bool] | None = None,
    watch_stride: int = 2,
    **train_kw: Any,
) -> JacobianFit:
    """Train ``kind`` ("network": SE(3) sensor networks, "mlp": the IV-D baseline) on ``rec`` and return
    the per-sample Jacobian norms (K, S, rows, N) at ``samples`` recorded configurations, the loss and
    the networks' weights. ``warm_start`` (sensor networks only) starts from an earlier training's
    weights (:func:`bodyschema.networks.train_sensor_networks`); ``watch(jbar, epoch)``, when given,
    sees the Jacobian norms at the same configurations after every epoch of the sensor networks (and,
    on a warm start, before the first, as epoch -1) and stops training by returning True
    (:class:`StableDependency`), read at every ``watch_stride``-th of those configurations while that
    leaves at least 500 (a reading costs a Jacobian, and a warm start's readings, one per epoch, were
    as costly as its epochs).

    ``gravity`` None: the gravity-aware loss (Eq. 24) whenever the recording has gravity. ``seed``
    drives initialization, batches and the choice of θ samples.
    """
    rec = rec.derived()
    assert rec.q is not None and rec.qd is not None and rec.qdd is not None
    rng = np.random.default_rng(seed)
    S = min(samples, rec.n_samples)
    pick = np.sort(rng.choice(rec.n_samples, size=S, replace=False))
    theta = torch.as_tensor(rec.q[pick], dtype=torch.float32)
    run = _Training(hidden=hidden, epochs=epochs, seed=seed, progress=progress, train_kw=train_kw)
    if kind == "mlp":
        return _mlp_jacobian(rec, pick, theta, run)
    if kind == "network":
        watching = None if watch is None else (watch, watch_stride)
        return _sensor_network_jacobian(rec, theta, run, gravity, warm_start, watching)
    raise ValueError(f"unknown network kind {kind!r}")


@dataclass(frozen=True)
class _Training:
    """The training settings :func:`network_jacobian` hands to either kind of network."""

    hidden: tuple[int, ...]
    epochs: int | None
    seed: int
    progress: bool
    train_kw: dict[str, Any]


def _mlp_jacobian(rec: Recording, pick: np.ndarray, theta: torch.Tensor, run: _Training) -> JacobianFit:
    from bodyschema.mlp_baseline import mlp_jacobian, train_mlp

    mlp, loss = train_mlp(
        rec.q,
        rec.qd,
        rec.qdd,
        rec.gyro,
        rec.acc,
        hidden=run.hidden,
        epochs=60 if run.epochs is None else run.epochs,  # the paper's baseline keeps a fixed budget
        seed=run.seed,
        progress=run.progress,
        **run.train_kw,
    )
    jbar = mlp_jacobian(
        mlp,
        theta,
        torch.as_tensor(rec.qd[pick], dtype=torch.float32),
        torch.as_tensor(rec.qdd[pick], dtype=torch.float32),
    )
    return JacobianFit(jbar.numpy().astype(np.float64), loss, None, False)


def _sensor_network_jacobian(
    rec: Recording,
    theta: torch.Tensor,
    run: _Training,
    gravity: bool | None,
    warm_start: NetworkWeights | None,
    watching: tuple[Callable[[np.ndarray, int], bool], int] | None,
) -> JacobianFit:
    from bodyschema.networks import train_sensor_networks

    use_g = bool(np.linalg.norm(rec.gravity) > 0) if gravity is None else gravity
    on_epoch = None
    if watching is not None:
        watch, watch_stride = watching
        # fewer than 500 configurations read too noisily to settle: short windows read them all
        stride = watch_stride if len(theta) // watch_stride >= 500 else 1
        theta_w = theta[::stride].contiguous()

        def on_epoch(net: Any, epoch: int, _loss: float) -> bool:
            return watch(invariant_jacobian(net, theta_w).numpy().astype(np.float64), epoch)

    net, loss = train_sensor_networks(
        rec.q,
        rec.qd,
        rec.qdd,
        rec.gyro,
        rec.acc,
        rec.gravity if use_g else None,
        hidden=run.hidden,
        epochs=run.epochs,
        seed=run.seed,
        progress=run.progress,
        warm_start=warm_start,
        on_epoch=on_epoch,
        **run.train_kw,
    )
    jbar = invariant_jacobian(net, theta)
    return JacobianFit(jbar.numpy().astype(np.float64), loss, NetworkWeights.from_model(net), net.warm)


def cluster_vote(
    feats: np.ndarray, delta: float, labels: np.ndarray, sure_ratio: float = 2.0, majority: float = 0.75
) -> np.ndarray:
    """Binarize ``feats`` at δ, then let each cluster of IMUs (one link) vote on its uncertain entries.

    The vote repairs only entries near δ: the DPGMM clusters continuous features, and the IMUs of a
    link and of its child can land in one cluster (a wrist joint that barely changes them), where a
    vote would erase a dependency that every member of the child shows clearly. So an entry keeps its
    own value when it is more than ``sure_ratio`` times above or below δ, or when its cluster is split
    about evenly; a clear majority (``majority`` of the members) overrules the rest. Label -1: no
    cluster (kept as binarized).

    Two links in one cluster, split evenly: every entry is kept.

    >>> split = np.array([[0.9, 0.5], [0.9, 0.45], [0.9, 0.01], [0.9, 0.02]])
    >>> cluster_vote(split, 0.1, np.zeros(4, dtype=int)).astype(int).tolist()
    [[1, 1], [1, 1], [1, 0], [1, 0]]

    One link, three of four members clearly dependent: the fourth, just under δ, is overruled.

    >>> one = np.array([[0.9, 0.5], [0.9, 0.45], [0.9, 0.6], [0.9, 0.08]])
    >>> cluster_vote(one, 0.1, np.zeros(4, dtype=int)).astype(int).tolist()
    [[1, 1], [1, 1], [1, 1], [1, 1]]
    """
    xb = feats > delta
    sure = np.abs(np.log(np.maximum(feats, 1e-6) / delta)) > np.log(sure_ratio)
    dep = xb.copy()
    for c in np.unique(labels[labels >= 0]):
        members = labels == c
        share = xb[members].mean(axis=0)
        clear = (share >= majority) | (share <= 1 - majority)
        keep = sure[members] | ~clear
        dep[members] = np.where(keep, xb[members], share > 0.5)
    return dep


def dependency_from_jacobian(
    jbar: np.ndarray,
    statistic: str = "moment",
    undetermined: np.ndarray | None = None,
    lam: float = 0.1,
    rng: np.random.Generator | None = None,
    loss: list[float] | None = None,
    sure_ratio: float = 2.0,
    majority: float = 0.75,
) -> NetworkDependency:
    """Statistic, feature, δ, DPGMM merge (steps 2-5 of the module docstring) on Jacobian norms.

    Entries more than ``sure_ratio`` times above or below δ keep their own value; a cluster's vote
    decides the rest where at least ``majority`` of its members agree.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    N = jbar.shape[-1]
    und = np.zeros(N, dtype=bool) if undetermined is None else np.asarray(undetermined, dtype=bool)
    jbar = jbar.copy()
    jbar[..., und] = 0.0
    stat = jacobian_statistic(jbar, statistic)
    feats, on_base = dependency_feature(stat)
    delta, labels = choose_delta(feats, lam=lam, rng=rng)
    dep = cluster_vote(feats, delta, labels, sure_ratio=sure_ratio, majority=majority)
    dep[on_base] = False
    # confidence: how far each feature sits from δ, relative to the room on its side
    xb = feats > delta
    margin = np.where(xb, (feats - delta) / max(1 - delta, 1e-6), (delta - feats) / max(delta, 1e-6))
    margin[:, und] = 1.0
    return NetworkDependency(
        dependency=dep,
        features=feats,
        delta=delta,
        labels=labels,
        undetermined=np.flatnonzero(und),
        imu_confidence=np.clip(margin.min(axis=1) * 2, 0.0, 1.0),
        joint_confidence=np.clip(margin.min(axis=0) * 2, 0.0, 1.0),
        loss=list(loss or []),
        evidence=np.clip(np.abs(np.log(np.maximum(feats, 1e-6) / delta)), 0.0, EVIDENCE_CAP),
    )


class StableDependency:
    """Stops a warm-started training once the dependency matrix has not changed for ``epochs`` epochs.

    The networks' loss is the wrong yardstick for a warm start: weights fitted to an earlier window
    fit a new window of the same body 2-3x worse at first (other configurations), and the loss takes
    about as many epochs to come back down as a cold run takes, while what the networks are for, the
    dependency matrix read from their Jacobian, is right from the first epoch. Measured on paper-3
    (robot sensing, two 30 s windows, the Jacobian checked after every epoch): the warm run's matrix
    equals the cold run's after every one of its 20 epochs; with an IMU moved to another link between
    the windows, it differs after the first epoch and equals the cold run's from the second on. So a
    warm start stops when the matrix read after each epoch (the same statistic and clustering seed as
    the final one, at every other of its configurations) has stayed the same for ``epochs`` epochs in
    a row, the stored weights' own reading of the new window before the first epoch counting as the
    first of the row
    (healthy: the reading is the same from the start, and training stops after ``epochs`` epochs;
    changed: that reading is the old body's and the row starts at the first epoch); the warm plateau
    schedule (:func:`bodyschema.training.warm_plateau`) still bounds it. Each check costs about a
    third of an epoch. ``bodyhealth bench warmstart`` compares the answers with cold runs, healthy and
    damaged.
    """

    def __init__(
        self, statistic: str, undetermined: np.ndarray, lam: float, seed: int, epochs: int = 3
    ) -> None:
        self.statistic, self.undetermined, self.lam, self.seed = statistic, undetermined, lam, seed
        self.epochs = epochs
        self._last: np.ndarray | None = None
        self._same = 0
        #: the epoch (0-based) after which it stopped training, None while it has not
        self.stopped_at: int | None = None

    def __call__(self, jbar: np.ndarray, epoch: int) -> bool:
        dep = dependency_from_jacobian(
            jbar, self.statistic, self.undetermined, lam=self.lam, rng=np.random.default_rng(self.seed + 1)
        ).dependency
        self._same = self._same + 1 if self._last is not None and np.array_equal(dep, self._last) else 0
        self._last = dep
        if self._same >= self.epochs:
            self.stopped_at = epoch
            return True
        return False


def network_dependency(
    rec: Recording,
    method: str = "network",
    lam: float = 0.1,
    seed: int = 0,
    **kw: Any,
) -> NetworkDependency:
    """Train the method's networks on ``rec`` and extract the dependency matrix.

    ``method``: ``"network"`` (second moment), ``"network-paper"`` (variance) or ``"mlp"`` (the IV-D
    baseline with the second moment). Other keywords go to :func:`network_jacobian`.
    """
    from bodyschema.fast import insufficient_excitation

    kinds = {
        "network": ("network", "moment"),
        "network-paper": ("network", "variance"),
        "mlp": ("mlp", "moment"),
    }
    if method not in kinds:
        raise ValueError(f"unknown network method {method!r}; choose one of {sorted(kinds)}")
    kind, statistic = kinds[method]
    derived = rec.derived()
    assert derived.qd is not None
    und = insufficient_excitation(derived.qd, derived.gyro)
    if kind == "network" and kw.get("warm_start") is not None and kw.get("epochs") is None:
        kw.setdefault("watch", StableDependency(statistic, und, lam, seed))
    fit = network_jacobian(derived, kind=kind, seed=seed, **kw)
    dep = dependency_from_jacobian(
        fit.jbar, statistic, und, lam=lam, rng=np.random.default_rng(seed + 1), loss=fit.loss
    )
    return dataclasses.replace(dep, weights=fit.weights, warm=fit.warm)
