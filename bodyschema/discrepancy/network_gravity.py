"""The robot gravity case: sensor networks without gravity (paper Eq. 11) against with it (Eq. 24).

The paper's sensor networks first predict the accelerometer as ``α = Rᵀ b̈`` (Eq. 11), which is right
only without gravity; Eq. 24 adds the world gravity, ``α = Rᵀ (b̈ − g)``. On a robot recording (gravity
present) :func:`gravity_case` trains both forms with the same seed and shows what the discrepancy
analyzer makes of the difference:

1. **Residuals.** Measured minus predicted readings of every IMU under each form (in-sample: both forms
   see the same data with the same capacity; the gap is what the missing term costs).
2. **Cause.** The held-out effect selection (:func:`~bodyschema.discrepancy.selection.analyze`) runs
   on the Eq. 11 residual of each analysed IMU, against two gravity-free references:

   * ``network`` — each Eq. 11 pose network with its learned biases (:func:`network_reference`:
     orientation ``R(θ)``, rate ``vee(RᵀṘ)``, acceleration ``b̈`` in the network's own world frame).
     The selection names ``gravity``, but its fitted magnitude falls short of the recording's: trained
     without the term, the networks bend ``b̈`` and their biases towards gravity (a sinusoidal joint has
     ``θ̈ ∝ −θ``, so ``J θ̈`` can mimic a configuration-dependent signal), and the vector lies in the
     network's arbitrary world frame (Prop. 1); its direction is compared through the sensor frame with
     the Eq. 24 network's own estimate.
   * ``kinematics`` (when the caller passes the robot's reference motions, e.g. from its MuJoCo model) —
     Eq. 11's accelerometer model on the true kinematics, ``α = Rᵀ b̈``: the residual is then gravity
     and the IMU's own errors alone, and the fitted vector is compared with the recording's gravity
     in magnitude and direction (same world frame).

   An IMU whose orientation never changes relative to gravity (a link turning about the vertical)
   cannot tell gravity from a constant bias: nothing gravity-like is named there.
3. **Topology.** Each form's networks go through the Transform-Invariant Jacobian, the dependency
   matrix and the out-tree (:mod:`bodyschema.dependency`, :mod:`bodyschema.estimate`), the same steps as
   ``estimate_topology(method="network")`` but on the networks trained here, so each form is trained
   once. :func:`topology_accuracy` compares a result with the recording's ground truth; it is the only
   place that reads ``truth_*``.

Example
-------
>>> acc = topology_accuracy(
...     {"a": None, "b": "a"}, {"i0": "a", "i1": "a"}, {"a": None, "b": "a"}, {"i0": "a", "i1": "b"})
>>> acc["exact"], acc["joint_parent"], acc["imu_joint"]
(False, 1.0, 0.5)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from bodyschema.discrepancy.report import DiscrepancyReport
from bodyschema.discrepancy.selection import analyze
from bodyschema.recording import Recording
from bodyschema.rigid_motion import ReferenceMotion, lowpass
from bodyschema.topology import Topology

__all__ = [
    "FORMS",
    "CauseAnalysis",
    "FormResult",
    "GravityCase",
    "gravity_case",
    "network_readings",
    "network_reference",
    "topology_accuracy",
]

#: The two loss forms: the paper's equation numbers.
FORMS: tuple[str, ...] = ("eq11", "eq24")


@dataclass
class FormResult:
    """One loss form's networks on the recording: residuals, final loss, dependency and topology."""

    form: str
    acc_rms: float
    gyro_rms: float
    acc_rms_imu: list[float]
    gyro_rms_imu: list[float]
    loss: list[float]
    dependency: np.ndarray
    topology: Topology
    accuracy: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "form": self.form,
            "acc_rms": self.acc_rms,
            "gyro_rms": self.gyro_rms,
            "acc_rms_imu": self.acc_rms_imu,
            "gyro_rms_imu": self.gyro_rms_imu,
            "final_loss": self.loss[-1] if self.loss else None,
            "dependency": self.dependency.astype(int).tolist(),
            "joint_parent": self.topology.joint_parent,
            "imu_joint": self.topology.imu_joint,
            "accuracy": self.accuracy,
        }


@dataclass
class CauseAnalysis:
    """The effect selection on the Eq. 11 residual against one reference, over the analysed IMUs.

    ``causes``: the effects named on at least half of the IMUs, most frequent first, each with how many
    IMUs named it, the median held-out gain, and for ``gravity`` the fitted magnitude (median and range)
    and direction check. ``named``: the effects named per IMU; ``reports``: the analyzer's reports.
    """

    reference: str
    causes: list[dict[str, Any]]
    named: dict[str, list[str]]
    reports: dict[str, DiscrepancyReport] = field(default_factory=dict, repr=False)

    def cause(self, effect: str) -> dict[str, Any] | None:
        return next((c for c in self.causes if c["effect"] == effect), None)

    def to_json(self) -> dict[str, Any]:
        return {"reference": self.reference, "causes": self.causes, "named_per_imu": self.named}


@dataclass
class GravityCase:
    """What :func:`gravity_case` found (``to_json`` is the ``gravity_case`` block of the sim2real JSON)."""

    forms: dict[str, FormResult]
    imus: list[str]
    analyses: dict[str, CauseAnalysis]
    gravity: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)
    #: ``t`` and (T, 3) accelerometer residuals of one IMU (``settings["trace_imu"]``, the worst under
    #: Eq. 11): ``eq11``, ``eq24``, and ``eq11_fitted`` (Eq. 11 plus the effects the analysis named).
    traces: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def analysis(self) -> CauseAnalysis:
        """The analysis on the exact kinematics when there is one, else on the networks."""
        return self.analyses.get("kinematics") or self.analyses["network"]

    def cause(self, effect: str) -> dict[str, Any] | None:
        return self.analysis.cause(effect)

    def to_json(self) -> dict[str, Any]:
        eq11, eq24 = self.forms["eq11"], self.forms["eq24"]
        return {
            "forms": {k: v.to_json() for k, v in self.forms.items()},
            "residual_gain": {
                "acc": 1.0 - eq24.acc_rms**2 / max(eq11.acc_rms**2, 1e-300),
                "gyro": 1.0 - eq24.gyro_rms**2 / max(eq11.gyro_rms**2, 1e-300),
            },
            "causes": self.analysis.causes,
            "analyses": {k: v.to_json() for k, v in self.analyses.items()},
            "imus_analysed": self.imus,
            "recording_gravity": [float(x) for x in self.gravity],
            "settings": self.settings,
        }


# ----------------------------------------------------------------------------------------- networks
def network_readings(
    net: Any, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, gravity: np.ndarray | None, batch: int = 4096
) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro, acc)`` (T, K, 3): what trained sensor networks predict, biases included.

    ``net`` is a :class:`~bodyschema.networks.SensorNetworks`; ``gravity`` None is the Eq. 11 form.
    """
    g = None if gravity is None else torch.as_tensor(np.asarray(gravity), dtype=torch.float32)
    ws, accs = [], []
    with torch.no_grad():
        for s in range(0, q.shape[0], batch):
            args = [torch.as_tensor(x[s : s + batch], dtype=torch.float32) for x in (q, qd, qdd)]
            w, a = net.predict(*args, g)
            ws.append(w.transpose(0, 1).numpy())
            accs.append(a.transpose(0, 1).numpy())
    return np.concatenate(ws).astype(np.float64), np.concatenate(accs).astype(np.float64)


def _poses(net: Any, q: np.ndarray, batch: int = 4096) -> np.ndarray:
    """(T, K, 3, 3) sensor-to-network-world rotations."""
    out = []
    with torch.no_grad():
        for s in range(0, q.shape[0], batch):
            R, _ = net.pose(torch.as_tensor(q[s : s + batch], dtype=torch.float32))
            out.append(R.transpose(0, 1).numpy())
    return np.concatenate(out).astype(np.float64)


def _biases(net: Any) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) learned gyro and accelerometer biases."""
    return (
        net.gyro_bias.detach().numpy()[:, 0].astype(np.float64),
        net.acc_bias.detach().numpy()[:, 0].astype(np.float64),
    )


def network_reference(
    t: np.ndarray,
    R: np.ndarray,
    gyro_pred: np.ndarray,
    acc_pred: np.ndarray,
    gyro_bias: np.ndarray,
    acc_bias: np.ndarray,
    cutoff: float | None = 10.0,
) -> ReferenceMotion:
    """One Eq. 11 pose network as the analyzer's (gravity-free) reference motion.

    ``R`` (T, 3, 3) the network's pose, ``gyro_pred``/``acc_pred`` (T, 3) its predicted readings with its
    learned biases ``gyro_bias``/``acc_bias`` (3,) — subtract the biases from the measurement before the
    analysis so the analyzer starts from exactly the network's prediction. The rate is the prediction
    less its bias; the acceleration ``b̈ = R (α − bias)`` in the network's world frame; both low-passed
    at ``cutoff`` like every reference.
    """
    rate = float(1.0 / np.median(np.diff(t)))
    omega = gyro_pred - gyro_bias
    acc_world = np.einsum("tij,tj->ti", R, acc_pred - acc_bias)
    return ReferenceMotion(t, R, lowpass(omega, rate, cutoff), lowpass(acc_world, rate, cutoff), np.zeros(3))


# ----------------------------------------------------------------------------------------- topology
def topology_accuracy(
    joint_parent: Mapping[str, str | None],
    imu_joint: Mapping[str, str | None],
    truth_parent: Mapping[str, str | None],
    truth_imu: Mapping[str, str | None],
) -> dict[str, Any]:
    """Exactness and the fractions of correct joint parents and IMU joints (IMUs in ``truth_imu`` only)."""
    jp = [joint_parent.get(j) == p for j, p in truth_parent.items()]
    ij = [imu_joint.get(i) == j for i, j in truth_imu.items()]
    return {
        "exact": bool(all(jp) and all(ij)),
        "joint_parent": float(np.mean(jp)) if jp else 1.0,
        "imu_joint": float(np.mean(ij)) if ij else 1.0,
    }


def _topology(
    rec: Recording, net: Any, loss: list[float], samples: int, seed: int
) -> tuple[np.ndarray, Topology]:
    """Dependency matrix and topology of trained networks: the steps of ``network_dependency`` and
    ``estimate_topology(method="network")`` after training (Jacobian at ``samples`` recorded
    configurations drawn with ``seed``, second-moment statistic, δ by Eq. 19, out-tree)."""
    from bodyschema.dependency import dependency_from_jacobian, invariant_jacobian
    from bodyschema.estimate import topology_from_dependency
    from bodyschema.fast import insufficient_excitation

    assert rec.q is not None and rec.qd is not None
    rng = np.random.default_rng(seed)
    S = min(samples, rec.n_samples)
    pick = np.sort(rng.choice(rec.n_samples, size=S, replace=False))
    theta = torch.as_tensor(rec.q[pick], dtype=torch.float32)
    jbar = invariant_jacobian(net, theta).numpy().astype(np.float64)
    und = insufficient_excitation(rec.qd, rec.gyro)
    res = dependency_from_jacobian(jbar, "moment", und, rng=np.random.default_rng(seed + 1), loss=loss)
    excitation = np.sqrt(np.mean(rec.qd**2, axis=0))
    topo = topology_from_dependency(
        res.dependency,
        rec.imu_names,
        rec.joint_names,
        undetermined=[rec.joint_names[j] for j in res.undetermined],
        imu_confidence=dict(zip(rec.imu_names, res.imu_confidence.tolist(), strict=True)),
        joint_confidence=dict(zip(rec.joint_names, res.joint_confidence.tolist(), strict=True)),
        method="network",
        excitation=dict(zip(rec.joint_names, excitation.tolist(), strict=True)),
    )
    return res.dependency, topo


# ----------------------------------------------------------------------------------------- the case
def _rms(x: np.ndarray, axis: tuple[int, ...] | int | None = None) -> np.ndarray:
    return np.sqrt(np.mean(x**2, axis=axis))


def _pick_imus(rec: Recording, resid: np.ndarray, imus: Sequence[str] | None, max_imus: int) -> list[str]:
    """The IMUs to analyse: those given, else up to ``max_imus`` spread over the Eq. 11 residual ranking
    (every link is represented when IMUs are many)."""
    if imus is not None:
        unknown = [i for i in imus if i not in rec.imu_names]
        if unknown:
            raise ValueError(f"IMUs {unknown} not in the recording")
        return list(imus)
    if rec.n_imus <= max_imus:
        return list(rec.imu_names)
    order = np.argsort(-_rms(resid, axis=(0, 2)))
    take = np.unique(np.round(np.linspace(0, rec.n_imus - 1, max_imus)).astype(int))
    return [rec.imu_names[int(order[i])] for i in sorted(take)]


def gravity_case(
    rec: Recording,
    *,
    epochs: int = 40,
    hidden: tuple[int, ...] = (32, 32, 32),
    seed: int = 0,
    samples: int = 1000,
    imus: Sequence[str] | None = None,
    max_imus: int = 12,
    references: Mapping[str, ReferenceMotion] | None = None,
    cutoff: float | None = 10.0,
    n_blocks: int = 8,
    alpha: float = 0.01,
    min_gain: float = 0.005,
    **train_kw: Any,
) -> GravityCase:
    """Train Eq. 11 and Eq. 24 networks on ``rec`` (same seed), compare residuals, name the cause of the
    Eq. 11 residual, and compare each form's topology with the truth when the recording has one.

    ``rec`` needs ``q`` and gravity; ``qd``/``qdd`` are derived when absent. ``imus`` (default: up to
    ``max_imus`` of them) are analysed for the cause; ``references`` (IMU name -> reference motion with
    gravity, e.g. ``sim2real.report.robot_references``) adds the analysis on the exact
    kinematics; ``cutoff``, ``n_blocks``, ``alpha``, ``min_gain`` go
    to :func:`~bodyschema.discrepancy.selection.analyze`; other keywords to the training.
    """
    if rec.q is None:
        raise ValueError("the gravity case needs joint positions q")
    g_norm = float(np.linalg.norm(rec.gravity))
    if g_norm == 0.0:
        raise ValueError("the recording has no gravity: Eq. 11 and Eq. 24 are the same loss")
    rec = rec.derived()
    assert rec.q is not None and rec.qd is not None and rec.qdd is not None
    gravity = np.asarray(rec.gravity, dtype=np.float64)
    train = {"hidden": hidden, "epochs": epochs, "seed": seed, **train_kw}
    forms, nets, preds = _train_forms(rec, gravity, samples, train)

    # the cause of the Eq. 11 residual, per IMU, by the analyzer
    gp11, ap11 = preds["eq11"]
    chosen = _pick_imus(rec, rec.acc - ap11, imus, max_imus)
    gb, ab = _biases(nets["eq11"])
    eq11 = _Eq11(_poses(nets["eq11"], rec.q), gp11, ap11, gb, ab)
    kw = {"cutoff": cutoff, "n_blocks": n_blocks, "alpha": alpha, "min_gain": min_gain}
    analyses = {"network": _network_analysis(rec, eq11, nets["eq24"], chosen, kw)}
    if references is not None:
        analyses["kinematics"] = _kinematics_analysis(rec, references, chosen, kw)

    worst = chosen[int(np.argmax([forms["eq11"].acc_rms_imu[rec.imu_names.index(i)] for i in chosen]))]
    traces = _traces(rec, eq11, preds["eq24"], analyses["network"].reports[worst].params, worst, cutoff)
    return GravityCase(
        forms=forms,
        imus=chosen,
        analyses=analyses,
        gravity=gravity,
        settings={
            "epochs": epochs,
            "hidden": list(hidden),
            "seed": seed,
            "samples": samples,
            "cutoff_hz": cutoff,
            "n_blocks": n_blocks,
            "alpha": alpha,
            "min_gain": min_gain,
            "trace_imu": worst,
        },
        traces=traces,
    )


def _train_forms(
    rec: Recording, gravity: np.ndarray, samples: int, train: dict[str, Any]
) -> tuple[dict[str, FormResult], dict[str, Any], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Each form's networks trained on ``rec`` (same seed): its result, the networks and their readings."""
    from bodyschema.networks import train_sensor_networks

    assert rec.q is not None and rec.qd is not None and rec.qdd is not None
    forms: dict[str, FormResult] = {}
    nets: dict[str, Any] = {}
    preds: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    truth = (rec.truth_parent_map, rec.truth_imu_map)  # read for the comparison only
    for form in FORMS:
        g = None if form == "eq11" else gravity
        net, loss = train_sensor_networks(rec.q, rec.qd, rec.qdd, rec.gyro, rec.acc, g, **train)
        gp, ap = network_readings(net, rec.q, rec.qd, rec.qdd, g)
        ra, rg = rec.acc - ap, rec.gyro - gp
        dep, topo = _topology(rec, net, loss, samples, train["seed"])
        acc = {}
        if truth[0] is not None and truth[1] is not None:
            acc = topology_accuracy(topo.joint_parent, topo.imu_joint, truth[0], truth[1])
        forms[form] = FormResult(
            form=form,
            acc_rms=float(_rms(ra)),
            gyro_rms=float(_rms(rg)),
            acc_rms_imu=[float(x) for x in _rms(ra, axis=(0, 2))],
            gyro_rms_imu=[float(x) for x in _rms(rg, axis=(0, 2))],
            loss=loss,
            dependency=dep,
            topology=topo,
            accuracy=acc,
        )
        nets[form], preds[form] = net, (gp, ap)
    return forms, nets, preds


@dataclass(frozen=True)
class _Eq11:
    """The Eq. 11 networks as the analysis reads them: poses, readings and fitted biases."""

    R: np.ndarray
    gp: np.ndarray
    ap: np.ndarray
    gb: np.ndarray
    ab: np.ndarray

    def reference(self, rec: Recording, k: int, cutoff: float | None) -> ReferenceMotion:
        """IMU ``k``'s motion as the Eq. 11 networks describe it."""
        return network_reference(
            rec.t, self.R[:, k], self.gp[:, k], self.ap[:, k], self.gb[k], self.ab[k], cutoff
        )


def _network_analysis(
    rec: Recording, eq11: _Eq11, net24: Any, chosen: list[str], kw: dict[str, Any]
) -> CauseAnalysis:
    """The analyzer on the Eq. 11 networks' motion of each chosen IMU, its fitted gravity compared with
    the Eq. 24 networks'."""
    R24 = _poses(net24, rec.q)
    gdir24 = net24.gravity_dir.detach().numpy()[:, 0].astype(np.float64)
    gdir24 /= np.linalg.norm(gdir24, axis=1, keepdims=True)
    net_refs = {}
    for imu in chosen:
        k = rec.imu_names.index(imu)
        net_refs[imu] = (
            eq11.reference(rec, k, kw["cutoff"]),
            rec.gyro[:, k] - eq11.gb[k],
            rec.acc[:, k] - eq11.ab[k],
        )

    def eq24_angle(imu: str, v: np.ndarray) -> dict[str, float]:
        # the fitted vector is in the Eq. 11 network's world frame: compare it with the Eq. 24 network's
        # gravity through the sensor frame over the recording
        k = rec.imu_names.index(imu)
        s11 = np.einsum("tji,j->ti", eq11.R[:, k], v / np.linalg.norm(v))
        s24 = np.einsum("tji,j->ti", R24[:, k], gdir24[k])
        return {"angle_to_eq24_deg": _median_angle(s11, s24)}

    return _analyse("network", net_refs, chosen, eq24_angle, kw)


def _kinematics_analysis(
    rec: Recording, references: Mapping[str, ReferenceMotion], chosen: list[str], kw: dict[str, Any]
) -> CauseAnalysis:
    """The analyzer on the exact kinematics of each chosen IMU, its fitted gravity compared with the
    recording's."""
    gravity = np.asarray(rec.gravity, dtype=np.float64)
    g_norm = float(np.linalg.norm(rec.gravity))
    kin_refs = {}
    for imu in chosen:
        if imu not in references:
            raise ValueError(f"no reference motion for IMU {imu!r}")
        r = references[imu]
        k = rec.imu_names.index(imu)
        kin_refs[imu] = (
            ReferenceMotion(r.t, r.R, r.omega, r.acc_world, np.zeros(3)),
            rec.gyro[:, k],
            rec.acc[:, k],
        )

    def to_recording(imu: str, v: np.ndarray) -> dict[str, float]:
        cos = float(v @ gravity / (np.linalg.norm(v) * g_norm))
        return {"angle_to_recording_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))}

    return _analyse("kinematics", kin_refs, chosen, to_recording, kw)


def _traces(
    rec: Recording,
    eq11: _Eq11,
    pred24: tuple[np.ndarray, np.ndarray],
    params: Mapping[str, Any],
    worst: str,
    cutoff: float | None,
) -> dict[str, np.ndarray]:
    """The accelerometer residual of IMU ``worst`` under each form, and under Eq. 11 with the effects
    fitted to it."""
    k = rec.imu_names.index(worst)
    traces = {
        "t": rec.t - rec.t[0],
        "eq11": rec.acc[:, k] - eq11.ap[:, k],
        "eq24": rec.acc[:, k] - pred24[1][:, k],
    }
    fitted = {e: p for e, p in params.items() if e != "noise"}
    if fitted:
        from bodyschema.discrepancy.effects import predict

        ref = eq11.reference(rec, k, None)
        traces["eq11_fitted"] = rec.acc[:, k] - eq11.ab[k] - predict(ref, fitted)[1]
    return traces


def _median_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Median angle (degrees) between unit vectors ``a`` and ``b`` (T, 3)."""
    return float(np.median(np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))))


def _analyse(
    reference: str,
    data: Mapping[str, tuple[ReferenceMotion, np.ndarray, np.ndarray]],
    chosen: Sequence[str],
    direction: Callable[[str, np.ndarray], dict[str, float]],
    kw: Mapping[str, Any],
) -> CauseAnalysis:
    """Run the selection per IMU on ``(reference, gyro, acc)`` and pool what was named."""
    reports: dict[str, DiscrepancyReport] = {}
    named: dict[str, list[str]] = {}
    fits: dict[str, dict[str, Any]] = {}
    for imu in chosen:
        ref, gyro, acc = data[imu]
        rep = analyze(ref, gyro, acc, **kw)
        rep.meta.update({"imu": imu, "reference": f"{reference} (Eq. 11, no gravity)"})
        reports[imu] = rep
        named[imu] = [n for n in rep.names if n != "noise"]
        c = rep.cause("gravity")
        if c is not None:
            v = np.asarray(c.params["vector"], dtype=np.float64)
            fits[imu] = {
                "vector": v.tolist(),
                "norm": float(np.linalg.norm(v)),
                "gain": float(c.gain),
                **direction(imu, v),
            }
    counts: dict[str, int] = {}
    for names in named.values():
        for n in names:
            counts[n] = counts.get(n, 0) + 1
    causes: list[dict[str, Any]] = []
    for eff, n in sorted(counts.items(), key=lambda kv: -kv[1]):
        if 2 * n < len(chosen):
            continue
        gains = [c.gain for c in (reports[i].cause(eff) for i in chosen) if c is not None]
        entry: dict[str, Any] = {
            "effect": eff,
            "imus": n,
            "of": len(chosen),
            "median_gain": float(np.median(gains)),
        }
        if eff == "gravity":
            norms = [f["norm"] for f in fits.values()]
            keys = [k for k in next(iter(fits.values())) if k.startswith("angle")]
            entry["params"] = {
                "norm": float(np.median(norms)),
                "norm_range": [float(min(norms)), float(max(norms))],
                **{k: float(np.median([f[k] for f in fits.values()])) for k in keys},
                "per_imu": fits,
            }
        causes.append(entry)
    return CauseAnalysis(reference=reference, causes=causes, named=named, reports=reports)
