"""One entry point for every topology estimator: recording in, :class:`~bodyschema.topology.Topology` out.

Methods (``METHODS``):

* ``fast`` — gyro regression tests (:mod:`bodyschema.fast`); about a second, the service's default.
* ``network`` — the paper's SE(3) sensor networks (:mod:`bodyschema.networks`) with the Jacobian
  *second moment* statistic (:mod:`bodyschema.dependency`; docs/design.md, 'Science notes', says why).
* ``network-paper`` — the same networks with the paper's *variance* statistic (Sec. III-C).
* ``mlp`` — the MLP regressor baseline of Sec. IV-D (:mod:`bodyschema.mlp_baseline`).

Every method ends in a 0/1 dependency matrix (IMU rows, joint columns); :func:`topology_from_dependency`
merges IMUs with equal rows onto one link, corrects a matrix that is no out-tree (MILP + trellis, paper
III-H), completes a partial one (links without IMUs, III-F/G) and converts the result. Estimators never
read the ``truth_*`` fields of the recording.

Example
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> T = 2000; t = np.arange(T) / 100
>>> q = np.stack([np.sin(0.9 * t), np.cos(0.6 * t + 1)], 1); qd = np.gradient(q, t, axis=0)
>>> w1 = np.stack([0 * t, 0 * t, qd[:, 0]], 1)
>>> w2 = np.stack([qd[:, 1], np.sin(q[:, 1]) * qd[:, 0], np.cos(q[:, 1]) * qd[:, 0]], 1)
>>> gyro = np.stack([w1, w2], 1) + np.random.default_rng(0).normal(scale=1e-3, size=(T, 2, 3))
>>> rec = Recording(t=t, joint_names=["a", "b"], q=q, imu_names=["i1", "i2"],
...                 acc=np.zeros((T, 2, 3)), gyro=gyro)
>>> topo = estimate_topology(rec)
>>> topo.joint_parent, topo.imu_joint, topo.unique
({'a': None, 'b': 'a'}, {'i1': 'a', 'i2': 'b'}, True)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from bodyschema.completion import complete
from bodyschema.conditions import check_p_minus
from bodyschema.convert import tree_to_topology
from bodyschema.depmatrix import DependencyMatrix
from bodyschema.fast import FastFit, FastOptions, fast_fit, fast_options, fit_path
from bodyschema.network_options import NetworkOptions, split_network_options
from bodyschema.outtree import OutTree
from bodyschema.recording import Recording
from bodyschema.topology import Topology

if TYPE_CHECKING:
    from bodyschema.network_weights import NetworkWeights

__all__ = ["METHODS", "TopologyFit", "estimate_topology", "fit_topology", "topology_from_dependency"]

METHODS: tuple[str, ...] = ("fast", "network", "network-paper", "mlp")

#: At most this many alternative answers are listed for a robot whose answer is not unique.
MAX_CANDIDATES = 24


class TopologyFit(NamedTuple):
    """What :func:`fit_topology` returns: the topology and, for the sensor-network methods, the trained
    networks' weights (to start the next training of the same robot from)."""

    topology: Topology
    weights: NetworkWeights | None


def estimate_topology(
    rec: Recording,
    method: str = "fast",
    *,
    timer: Callable[[], float] | None = None,
    imu_delay: float | None = None,
    network: NetworkOptions | None = None,
    **kw: Any,
) -> Topology:
    """Learn the joint tree and IMU placement of ``rec`` with ``method`` (see :data:`METHODS`).

    ``network`` is how the sensor networks train (:class:`~bodyschema.network_options.NetworkOptions`);
    its fields may also be given by name (``epochs=``, ``seed=``), replacing those in ``network``.
    Other keyword arguments go to the method's estimator (``options=`` a
    :class:`~bodyschema.fast.FastOptions` and any of its fields, ``fit_ratio=``, for ``fast``).
    ``timer`` is the caller's clock (the service passes
    ``time.process_time``: CPU time, all threads); ``seconds`` in the result is what it measured around
    the estimate, 0 without one. This package reads no clock itself, and nothing in the estimate
    depends on it.

    A recording on the fast estimator's timed path (positions without velocities the robot measured,
    on the encoders' own stamps ``t_q`` or on one clock: :func:`bodyschema.fast.fit_path`,
    docs/recording-format.md) goes through :func:`bodyschema.fast.fast_fit` first: it estimates the
    IMU's lag behind the encoders, reported in ``timing``; the network methods train on the streams
    aligned by it (:func:`bodyschema.timing.aligned_recording`). ``imu_delay`` (s) is the stated
    group delay of the IMU's on-chip filter: ``timing["skew_ms"]`` is the lag less it, for every
    method (a recording that states its filter, ``extra["sensing"]``, gives it itself).

    The sensor-network methods take ``warm_start=`` (:class:`bodyschema.networks.NetworkWeights`);
    :func:`fit_topology` also returns the weights trained.
    """
    return fit_topology(rec, method, timer=timer, imu_delay=imu_delay, network=network, **kw).topology


def fit_topology(
    rec: Recording,
    method: str = "fast",
    *,
    timer: Callable[[], float] | None = None,
    imu_delay: float | None = None,
    network: NetworkOptions | None = None,
    **kw: Any,
) -> TopologyFit:
    """:func:`estimate_topology`, and the trained networks' weights (None for ``fast`` and ``mlp``).

    The sensor-network methods record in ``training["warm"]`` whether training began from the
    ``warm_start=`` weights (1) or from random ones (0: none given, or of another shape).
    A sensor-network tree is tested against its rivals on held-out data
    (:func:`bodyschema.network_confidence.heldout_check`) before any part is called decided;
    ``heldout_check=False`` returns the networks' own ranking untested.
    """
    _check_input(rec, method)
    heldout = bool(kw.pop("heldout_check", True))
    start = timer() if timer is not None else 0.0
    fast_opts = _fast_options(kw) if method == "fast" else None
    rec, timed, timing = _timed(rec, method, fast_opts, imu_delay)
    rec = rec.derived()
    assert rec.qd is not None and rec.q is not None
    if method == "fast":
        found = _fast_found(rec, timed, fast_opts)
    else:
        found = _network_found(rec, method, network, kw)
    topo = topology_from_dependency(
        found.dependency,
        rec.imu_names,
        rec.joint_names,
        undetermined=found.undetermined,
        imu_confidence=found.imu_confidence,
        joint_confidence=found.joint_confidence,
        method=method,
        excitation=dict(zip(rec.joint_names, found.excitation.tolist(), strict=True)),
        evidence=found.evidence,
    )
    if heldout and method != "fast":  # the networks' ranking is sure only where held-out rivals fail
        from bodyschema.network_confidence import HeldOutOptions, heldout_check

        # the streams were aligned by the fast fit's lag, which is known as well as it measured it
        lag_unc = timing.get("lag_unc_ms")
        topo = heldout_check(rec, topo, HeldOutOptions(lag_unc=1e-3 * lag_unc) if lag_unc else None)
    topo = _with(
        topo, seconds=(timer() - start) if timer is not None else 0.0, timing=timing, training=found.training
    )
    return TopologyFit(topo, found.weights)


def _check_input(rec: Recording, method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if rec.q is None:
        raise ValueError("topology estimation needs joint positions q (this recording has none)")
    if rec.n_joints == 0 or rec.n_imus == 0:
        raise ValueError("topology estimation needs at least one joint and one IMU")


def _timed(
    rec: Recording, method: str, fast_opts: FastOptions | None, imu_delay: float | None
) -> tuple[Recording, FastFit | None, dict[str, float]]:
    """The recording the method reads, the fast estimator's timed fit (None off the timed path) and its
    timing figures.

    Positions without velocities the robot measured, on one clock or two: the fast estimator's timed
    path finds the IMU's lag behind the encoders (and answers directly); the networks then train on the
    streams aligned by that lag.
    """
    if fit_path(rec) != "timed":
        return rec, None, {}
    opts = fast_opts or FastOptions()
    if imu_delay is not None:
        opts = replace(opts, imu_delay=imu_delay)
    timed = fast_fit(rec, opts)
    timing = {
        "lag_ms": float(timed.lag_ms or 0.0),
        "skew_ms": float(timed.skew_ms or 0.0),
        **({} if timed.drift_ppm is None else {"drift_ppm": float(timed.drift_ppm)}),
        **({} if timed.lag_unc_ms is None else {"lag_unc_ms": float(timed.lag_unc_ms)}),
        "band_hz": float(timed.band_hz or 0.0),
        "at_s": float(timed.lag_time or 0.0),
    }
    if method != "fast":
        from bodyschema.timing import aligned_recording, timed_view

        rec = aligned_recording(
            timed_view(rec), 1e-3 * timing["lag_ms"], 1e-6 * timing.get("drift_ppm", 0.0), timing["at_s"]
        )
    return rec, timed, timing


@dataclass(frozen=True)
class _Found:
    """What one method found in a recording, before it becomes a topology."""

    dependency: np.ndarray
    evidence: np.ndarray | None
    undetermined: list[str]
    imu_confidence: dict[str, float]
    joint_confidence: dict[str, float]
    excitation: np.ndarray
    training: dict[str, float] = field(default_factory=dict)
    weights: NetworkWeights | None = None


def _fast_found(rec: Recording, timed: FastFit | None, fast_opts: FastOptions | None) -> _Found:
    fit = timed if timed is not None else fast_fit(rec, fast_opts)
    excitation = np.sqrt(np.mean(rec.qd**2, axis=0))
    if timed is not None:
        excitation = fit.excitation  # in the comparison band: what the tests could see
    return _Found(
        dependency=fit.dependency,
        evidence=None,
        undetermined=[rec.joint_names[j] for j in fit.undetermined],
        imu_confidence=dict(zip(rec.imu_names, fit.imu_confidence.tolist(), strict=True)),
        joint_confidence=dict(zip(rec.joint_names, fit.joint_confidence.tolist(), strict=True)),
        excitation=excitation,
    )


def _network_found(rec: Recording, method: str, network: NetworkOptions | None, kw: dict[str, Any]) -> _Found:
    from bodyschema.dependency import network_dependency

    excitation = np.sqrt(np.mean(rec.qd**2, axis=0))
    if method == "mlp":
        # the MLP baseline has defaults of its own: it is given the keywords as they came, and trains
        # a fixed budget (the paper's), never to a flat loss
        kw.pop("warm_start", None)
        res = network_dependency(rec, method=method, **{**(network.keywords() if network else {}), **kw})
        training = {"epochs": float(len(res.loss)), "converged": 0.0}
    else:
        opts = split_network_options(kw, network)
        res = network_dependency(rec, method=method, **opts.keywords(), **kw)
        bound = opts.epochs or opts.max_epochs
        training = {
            "epochs": float(len(res.loss)),
            "converged": float(opts.epochs is None and len(res.loss) < bound),
            "warm": float(res.warm),
        }
    if res.loss and np.isfinite(res.loss[-1]):  # JSON (and PostgreSQL's JSON) has no NaN
        training["loss"] = float(res.loss[-1])
    return _Found(
        dependency=res.dependency,
        evidence=res.evidence,
        undetermined=[rec.joint_names[j] for j in res.undetermined],
        imu_confidence=dict(zip(rec.imu_names, res.imu_confidence.tolist(), strict=True)),
        joint_confidence=dict(zip(rec.joint_names, res.joint_confidence.tolist(), strict=True)),
        excitation=excitation,
        training=training,
        weights=res.weights,
    )


def _with(topo: Topology, **changes: Any) -> Topology:
    return replace(topo, **changes)


def _fast_options(kw: dict[str, Any]) -> FastOptions:
    """The fast method's settings from ``estimate_topology``'s keywords: ``options=`` (a
    :class:`~bodyschema.fast.FastOptions`) and any of its fields by name."""
    return fast_options(kw.pop("options", None), **kw)


def topology_from_dependency(
    dependency: np.ndarray,
    imu_names: Sequence[str],
    joint_names: Sequence[str],
    undetermined: Sequence[str] = (),
    imu_confidence: Mapping[str, float] | None = None,
    joint_confidence: Mapping[str, float] | None = None,
    method: str = "",
    excitation: Mapping[str, float] | None = None,
    max_candidates: int = MAX_CANDIDATES,
    evidence: np.ndarray | None = None,
) -> Topology:
    """Turn a 0/1 IMU x joint dependency matrix into a topology (merge, correct, complete, convert).

    ``undetermined`` joints are left out of the matrix and hung on the base as placeholders (their
    child links are indistinguishable from their parents' in the data). When the matrix is no valid
    partial dependency matrix it is corrected first (nearest out-tree matrices, paper III-H) and every
    joint's confidence is scaled by how many entries had to change. ``unique`` is False when several
    trees explain the data; ``candidates`` then lists up to ``max_candidates`` of them and each joint's
    confidence is scaled by the share of candidates that agree with the chosen parent.

    ``evidence`` (same shape as ``dependency``, >= 0) says how strongly the data back each entry; when
    noise has split a link's IMUs over more rows than there are joints, the stray row joins the row
    that overrules the least evidence of its IMUs. None counts every entry alike (Hamming distance).
    """
    dependency = np.asarray(dependency, dtype=bool)
    imu_names = list(imu_names)
    joint_names = list(joint_names)
    evidence = _checked_evidence(dependency, evidence, imu_names, joint_names)
    undetermined = [j for j in joint_names if j in set(undetermined)]
    keep = [k for k, j in enumerate(joint_names) if j not in set(undetermined)]
    cols = [joint_names[k] for k in keep]
    imu_conf = {f"imu:{k}": float(v) for k, v in (imu_confidence or {}).items()}
    joint_conf = dict(joint_confidence or {})

    trees: list[OutTree]
    unique = True
    imu_nodes: dict[str, str | None]
    if not cols:
        trees = [OutTree({})]
        imu_nodes = {i: None for i in imu_names}
    else:
        D = DependencyMatrix(dependency[:, keep], imu_names, cols)
        trees, unique, imu_nodes, scale = _trees(D, evidence[:, keep], max_candidates)
        if scale is not None:
            joint_conf = {j: c * scale for j, c in joint_conf.items()}
            imu_conf = {k: c * scale for k, c in imu_conf.items()}

    def full(tree: OutTree, **fields: Any) -> Topology:
        topo = tree_to_topology(tree, imu_nodes)
        jp = {j: (topo.joint_parent.get(j) if j in topo.joint_parent else None) for j in joint_names}
        return Topology(joint_parent=jp, imu_joint={i: topo.imu_joint[i] for i in imu_names}, **fields)

    best = full(trees[0])
    candidates = tuple(full(t) for t in trees[1:]) if not unique else ()
    conf = _confidence(best, candidates, undetermined, imu_conf, joint_conf)
    return Topology(
        joint_parent=best.joint_parent,
        imu_joint=best.imu_joint,
        unique=unique,
        confidence=conf,
        method=method,
        undetermined=tuple(undetermined),
        candidates=candidates,
        excitation=dict(excitation or {}),
    )


def _checked_evidence(
    dependency: np.ndarray, evidence: np.ndarray | None, imu_names: list[str], joint_names: list[str]
) -> np.ndarray:
    """``evidence`` as floats (ones when None), after checking both matrices' shapes against the names."""
    if dependency.shape != (len(imu_names), len(joint_names)):
        expected = (len(imu_names), len(joint_names))
        raise ValueError(f"dependency has shape {dependency.shape}, expected {expected}")
    evidence = np.ones(dependency.shape) if evidence is None else np.asarray(evidence, dtype=float)
    if evidence.shape != dependency.shape or not np.all(evidence >= 0):
        raise ValueError(f"evidence must be non-negative with shape {dependency.shape}")
    return evidence


def _trees(
    D: DependencyMatrix, evidence: np.ndarray, max_candidates: int
) -> tuple[list[OutTree], bool, dict[str, str | None], float | None]:
    """The trees that explain ``D`` (the chosen one first), whether it is the only one, each IMU's node,
    and the confidence scale a correction costs (None when ``D`` needed none)."""
    merged = D.merge_rows()
    imu_nodes = merged.imu_nodes()
    M = merged.matrix
    corrected = 0
    if not check_p_minus(M).ok:
        weight = dict(zip(D.rows, evidence, strict=True))
        M, imu_nodes, corrected = _correct(M, merged.groups, imu_nodes, weight)
    comp = complete(M)
    unique = comp.unique
    trees = [comp.tree()]
    if not unique:
        alts = [t for t in comp.trees(limit=max_candidates) if t.joint_parent != trees[0].joint_parent]
        trees += alts[: max_candidates - 1]
    scale = max(0.0, 1.0 - corrected / max(M.values.size, 1) * 10) if corrected else None
    return trees, unique, imu_nodes, scale


def _confidence(
    best: Topology,
    candidates: tuple[Topology, ...],
    undetermined: list[str],
    imu_conf: dict[str, float],
    joint_conf: dict[str, float],
) -> dict[str, float]:
    """Each part's confidence: undetermined joints 0, the rest scaled by the share of candidates that
    agree with the chosen tree on it."""
    conf: dict[str, float] = dict(imu_conf)
    for j in best.joint_parent:
        c = float(joint_conf.get(j, 1.0))
        if j in undetermined:
            c = 0.0
        elif candidates:
            agree = sum(1 for t in (best, *candidates) if t.joint_parent[j] == best.joint_parent[j])
            c *= agree / (1 + len(candidates))
        conf[f"joint:{j}"] = c
    if candidates:
        for i in best.imu_joint:
            agree = sum(1 for t in (best, *candidates) if t.imu_joint[i] == best.imu_joint[i])
            conf[f"imu:{i}"] = conf.get(f"imu:{i}", 1.0) * agree / (1 + len(candidates))
    return conf


def _correct(
    M: DependencyMatrix,
    groups: Mapping[str, Sequence[str]],
    imu_nodes: dict[str, str | None],
    evidence: Mapping[str, np.ndarray],
) -> tuple[DependencyMatrix, dict[str, str | None], int]:
    """Nearest valid matrix to a noisy one (paper III-H), with the IMU -> node map carried along.

    A matrix with more distinct rows than joints (noise split one link in two) is first reduced: the row
    with the fewest IMUs is merged into the row that overrules the least ``evidence`` of its IMUs (per
    IMU, one weight per column) until K <= N. Returns the matrix, the IMU -> row map and how many
    entries or rows had to change.
    """
    from bodyschema.correction import correct

    rows = list(M.rows)
    vals = M.values.copy()
    mapping = dict(imu_nodes)
    size = {r: len(groups.get(r, (r,))) for r in rows}
    weight = {r: np.zeros(M.shape[1]) for r in rows}
    for imu, node in mapping.items():
        if node in weight:
            weight[node] = weight[node] + evidence[imu]
    while len(rows) > M.shape[1]:
        # the row carried by the fewest IMUs is the likeliest noise: merge it into the row that
        # contradicts the least of its evidence (ties go to the row with more IMUs)
        drop = min(range(len(rows)), key=lambda i: size[rows[i]])
        dist = (vals != vals[drop]) @ weight[rows[drop]]
        keep = min((i for i in range(len(rows)) if i != drop), key=lambda i: (dist[i], -size[rows[i]]))
        size[rows[keep]] += size[rows[drop]]
        weight[rows[keep]] = weight[rows[keep]] + weight[rows[drop]]
        for imu, node in mapping.items():
            if node == rows[drop]:
                mapping[imu] = rows[keep]
        rows.pop(drop)
        vals = np.delete(vals, drop, axis=0)
    Mr = DependencyMatrix(vals, rows, M.cols)
    merged_away = M.shape[0] - len(rows)
    if check_p_minus(Mr).ok:
        return Mr, mapping, merged_away
    res = correct(Mr)
    best = res.candidates[0].reorder(rows, list(Mr.cols))
    # corrected rows may coincide (two rows were one link) or vanish (a row was the base): merge again
    again = best.merge_rows()
    node_of = {m: rep for rep, members in again.groups.items() for m in members}
    node_of.update({b: None for b in again.base_rows})
    mapping = {imu: (None if node is None else node_of[node]) for imu, node in mapping.items()}
    return again.matrix, mapping, merged_away + int(res.distance)
