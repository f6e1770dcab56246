"""Which joints hold a floating base to the ground: the stance chain of each contact phase, from data.

A foot that stands flat does not turn, so the base's angular velocity is the stance leg's chain
rotation with its sign flipped. In the base IMU's frame, for joints ``1..J`` from the base outward with
unit axes ``a_j`` (at zero angles):

    w_imu = -sum_j R_1(q_1) ... R_{j-1}(q_{j-1}) a_j qd_j + b

(``R_i`` the rotation by ``q_i`` about ``a_i``, ``b`` the gyro bias): linear in the joint rates with
configuration-dependent coefficients, and *exact* for the true chain. Correlation cannot name that
chain: a gait drives every joint with one phase, so on the iCub walking log the left leg's rates, the
right leg's and the arms-and-torso's each explain 91 % of the base gyro's variance by linear
regression. The exact model has no such freedom (two parameters per joint, unit axes), so each
candidate chain is fitted on half of the phase's stance runs (whole steps) and scored on the others.

**Error model.** Gyro and encoder rates are compared in one band (``cutoff_hz``; central differences
of quantized positions carry ``quantum/sqrt(12)`` white noise per joint, differentiated: the
:func:`bodyschema.floating_base.quantization_floor` of each chain, plus the gyro's white noise). Residuals
low-passed at ``cutoff_hz`` hold ``2 cutoff / rate`` independent values per sample, which sets the
degrees of freedom of the test. A candidate is *as good as the best* unless its held-out residual
power exceeds the best's by more than the F quantile at ``p_false``; the model error beyond the
floor (foot roll, compliance) is reported as ``floor_ratio``.

**The answer.** A phase gets a chain when every candidate as good as the best contains one smallest
candidate (that chain), and that chain fits significantly better than no chain at all (the base not
turning); otherwise it is *undetermined*, with the competitors that fit as well and the motion that
would decide. Candidates: a *limb* is a run of consecutive columns whose joint names share their first
token (logs list a limb's joints together, from the body outward: ``l_hip_pitch .. l_ankle_roll``,
``FR_hip .. FR_calf``); the candidates are each moving limb and each run of two or three adjacent
limbs. No URDF is read.

**Contact phases** come from the recording's foot forces (every time-long extra whose name holds
``force``: one foot per column) through :func:`bodyschema.contacts.force_contacts` (threshold from the
swing samples' spread at a false-contact rate of 1e-3). Without foot forces the phases cannot be cut;
the whole recording is then tested as one phase.

**Floating base** (:func:`floating_base_rule`): the recording says so (``extra["floating_base"]``),
else it carries foot forces (a fixed-base arm has no feet).

Example: a two-joint leg turning the base, and an unrelated arm moving with the same phase.

>>> import numpy as np
>>> t = np.arange(3000) * 0.01
>>> rng = np.random.default_rng(0)
>>> q = np.c_[0.3 * np.sin(t), 0.2 * np.sin(1.7 * t + 1), 0.3 * np.sin(t + 0.2), 0.1 * np.sin(1.7 * t)]
>>> qd = np.gradient(q, t, axis=0)
>>> w = -(qd[:, :1] * [1.0, 0, 0] + qd[:, 1:2] * np.c_[np.zeros_like(t), np.cos(q[:, 0]), np.sin(q[:, 0])])
>>> f = np.where((t % 4) < 3, 300.0, 0.0) + rng.normal(0, 3, t.size)
>>> gyro = (w + rng.normal(0, 1e-3, w.shape))[:, None, :]
>>> rec = Recording(t=t, joint_names=("leg_a", "leg_b", "arm_a", "arm_b"), q=q, imu_names=("base",),
...                 acc=np.zeros((t.size, 1, 3)) + [0, 0, 9.81], gyro=gyro, extra={"foot_force": f})
>>> res = stance_chains(rec)
>>> [c.joints for c in res.chains]
[('leg_a', 'leg_b')]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import f as f_dist

from bodyschema.contacts import force_contacts
from bodyschema.floating_base import quantization_floor
from bodyschema.forward_kinematics import axis_rotations
from bodyschema.recording import Recording
from bodyschema.rigid_motion import lowpass

__all__ = [
    "ChainFit",
    "ChainOptions",
    "PhaseAnswer",
    "StanceResult",
    "candidate_chains",
    "chain_rates",
    "encoder_steps",
    "fit_chain",
    "floating_base_rule",
    "foot_forces",
    "limbs",
    "stance_chains",
]

#: MPU-6050 gyro noise density (docs/design.md, 'Facts the error models use'): 0.005 deg/s/sqrt(Hz).
GYRO_DENSITY = np.radians(0.005)


@dataclass(frozen=True)
class ChainOptions:
    """``cutoff_hz``: the common band of gyro and encoder rates. ``p_false``: the chance that an
    equally good competitor reads as significantly worse (and the contact threshold's false-contact
    rate). ``min_phase_s``: stance seconds a phase needs before it is judged. ``gyro_density``:
    rad/s/sqrt(Hz). ``quantum``: encoder step (rad; None: the smallest step the data show).
    ``max_limbs``: adjacent limbs joined into one candidate. ``max_fit_samples``: the fit and test
    samples kept (evenly thinned beyond the band's Nyquist rate)."""

    cutoff_hz: float = 4.0
    p_false: float = 1e-3
    min_phase_s: float = 2.0
    gyro_density: float = float(GYRO_DENSITY)
    quantum: float | None = None
    max_limbs: int = 2
    max_fit_samples: int = 150


@dataclass(frozen=True)
class ChainFit:
    """One candidate chain on one phase: held-out residual RMS (rad/s), degrees of freedom, axes."""

    joints: tuple[str, ...]
    columns: tuple[int, ...]
    rms: float
    dof: float
    axes: np.ndarray
    bias: np.ndarray


@dataclass(frozen=True)
class PhaseAnswer:
    """A contact phase's answer: ``joints`` (a chain) or ``reason`` (undetermined)."""

    phase: str
    phase_fraction: float
    joints: tuple[str, ...] = ()
    confidence: float = 0.0
    reason: str = ""
    decide: str = ""
    fits: tuple[tuple[str, float], ...] = ()
    floor_ratio: float | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"phase": self.phase, "phase_fraction": round(self.phase_fraction, 4)}
        if self.joints:
            out.update(joints=list(self.joints), confidence=round(self.confidence, 4))
        else:
            out.update(reason=self.reason, decide=self.decide)
        out["fits"] = {name: round(rms, 5) for name, rms in self.fits}
        if self.floor_ratio is not None:
            out["floor_ratio"] = round(self.floor_ratio, 2)
        return out


@dataclass(frozen=True)
class StanceResult:
    """Every phase's answer, the floating-base rule that applied, and where the contacts came from."""

    floating_base: bool
    rule: str
    contacts: str
    phases: tuple[PhaseAnswer, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def chains(self) -> tuple[PhaseAnswer, ...]:
        return tuple(p for p in self.phases if p.joints)

    @property
    def undetermined(self) -> tuple[PhaseAnswer, ...]:
        return tuple(p for p in self.phases if not p.joints)

    def to_json(self) -> dict[str, Any]:
        return {
            "floating_base": self.floating_base,
            "rule": self.rule,
            "contacts": self.contacts,
            "chains": [p.to_json() for p in self.chains],
            "undetermined": [p.to_json() for p in self.undetermined],
            **self.info,
        }


def foot_forces(rec: Recording) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """(T, F) foot forces from every extra whose name holds ``force`` and that runs along ``t``."""
    cols, names = [], []
    for key in sorted(rec.extra):
        v = np.asarray(rec.extra[key])
        if "force" not in key.lower() or v.dtype.kind not in "fiu" or v.shape[:1] != rec.t.shape:
            continue
        v = v.reshape(v.shape[0], -1).astype(float)
        for i in range(v.shape[1]):
            cols.append(v[:, i])
            names.append(key if v.shape[1] == 1 else f"{key}[{i}]")
    return (np.stack(cols, axis=1), tuple(names)) if cols else (None, ())


def floating_base_rule(rec: Recording) -> tuple[bool, str]:
    """Whether ``rec`` is of a floating-base robot, and the rule that said so (module docstring)."""
    flag = rec.extra.get("floating_base")
    if flag is not None:
        return bool(np.asarray(flag).reshape(-1)[0]), "the recording's floating_base flag"
    forces, names = foot_forces(rec)
    if forces is not None:
        return True, f"the recording carries foot forces ({', '.join(names)})"
    return False, "no floating_base flag and no foot forces"


def limbs(joint_names: tuple[str, ...]) -> list[tuple[int, ...]]:
    """Runs of consecutive columns whose names share their first ``_``-token.

    >>> limbs(("neck_a", "l_hip", "l_knee", "r_hip", "FR_hip", "FR_calf"))
    [(0,), (1, 2), (3,), (4, 5)]
    """
    out: list[list[int]] = []
    prev = None
    for i, n in enumerate(joint_names):
        tok = n.split("_")[0]
        if tok != prev or not out:
            out.append([])
        out[-1].append(i)
        prev = tok
    return [tuple(x) for x in out]


def candidate_chains(
    joint_names: tuple[str, ...], moving: np.ndarray, max_limbs: int
) -> list[tuple[int, ...]]:
    """Each limb with a moving joint, and each run of up to ``max_limbs`` adjacent limbs (only the
    moving joints kept)."""
    groups = limbs(joint_names)
    out: list[tuple[int, ...]] = []
    for n in range(1, max_limbs + 1):
        for s in range(len(groups) - n + 1):
            cols = tuple(c for g in groups[s : s + n] for c in g if moving[c])
            if cols and all(any(moving[c] for c in g) for g in groups[s : s + n]) and cols not in out:
                out.append(cols)
    return out


def chain_rates(axes: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """(T, 3) angular velocity of a chain's tip relative to its start, in the start frame: joints
    in order, unit ``axes`` (J, 3) at zero angles, angles ``q`` and rates ``qd`` (T, J)."""
    R = np.tile(np.eye(3), (q.shape[0], 1, 1))
    out = np.zeros((q.shape[0], 3))
    for j, a in enumerate(axes):
        a = a / max(float(np.linalg.norm(a)), 1e-12)
        out += (R @ a) * qd[:, j, None]
        R = R @ axis_rotations(a, q[:, j])
    return out


#: The chain fit that tells candidate chains apart stops when a step changes its cost or parameters by
#: under this share: at 1 % the residuals agree to 0.5 %, far inside the F quantile the chains are told
#: apart by. (Stopping after a fixed number of steps instead left some fits mid-descent, so that a 1e-13
#: change of the input, or another machine's rounding, moved a stance phase's answer.)
FIT_TOL = 1e-2
#: The fit of a chain the health checks model runs to convergence: its axes turn the stance foot's
#: gravity in the tilt check, and a fit stopped at 1 % of the cost leaves them anywhere along the
#: cost's flat valley, wherever the last step landed. Stopped at :data:`FIT_TOL`, a relative change of
#: 1e-13 in the gyro moved the iCub's tilt T² from 586 to 218; run to this tolerance it moves by 1e-6.
MODEL_TOL = 1e-10


def fit_chain(
    q: np.ndarray, qd: np.ndarray, w: np.ndarray, tol: float = FIT_TOL
) -> tuple[np.ndarray, np.ndarray]:
    """Axes (J, 3) and gyro bias (3,) of ``w ≈ -chain_rates(axes, q, qd) + bias`` by least squares,
    started from the constant-axis linear fit, run until a step changes the cost or the parameters
    by under ``tol`` (:data:`FIT_TOL` to compare chains, :data:`MODEL_TOL` for a model)."""
    X = np.c_[qd, np.ones(len(qd))]
    B, *_ = np.linalg.lstsq(X, w, rcond=None)
    A0 = -B[:-1]
    A0 = A0 / np.maximum(np.linalg.norm(A0, axis=1, keepdims=True), 1e-6)
    J = qd.shape[1]

    def res(p: np.ndarray) -> np.ndarray:
        return (p[-3:] - chain_rates(p[:-3].reshape(J, 3), q, qd) - w).ravel()

    # the evaluation cap only guards against a fit that cannot converge; a tight fit needs about
    # ten times the loose one's steps
    nfev = 50 if tol >= FIT_TOL else 1000
    sol = least_squares(res, np.r_[A0.ravel(), B[-1]], max_nfev=nfev, ftol=tol, xtol=tol, gtol=tol)
    axes = sol.x[:-3].reshape(J, 3)
    return axes / np.linalg.norm(axes, axis=1, keepdims=True), sol.x[-3:]


def _band(rec: Recording, opts: ChainOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(q, qd, gyro (T, 3) of the first IMU) in the common band, and the rate."""
    rate = rec.sample_rate
    t = rec.encoder_t
    q = rec.q if rec.t_q is None else rec.synced().q
    t = rec.t if rec.t_q is None else rec.synced().t
    qd = lowpass(np.gradient(q, t, axis=0), rate, opts.cutoff_hz)
    w = lowpass(
        rec.gyro[: q.shape[0], 0] if rec.t_q is None else rec.synced().gyro[:, 0], rate, opts.cutoff_hz
    )
    return q, qd, w, rate


def encoder_steps(q: np.ndarray, given: float | None = None) -> np.ndarray:
    """Per joint encoder step: ``given``, else the smallest non-zero step the column shows (0 for a
    column that never moves)."""
    if given is not None:
        return np.full(q.shape[1], given)
    out = np.empty(q.shape[1])
    for j in range(q.shape[1]):
        d = np.abs(np.diff(q[:, j]))
        d = d[d > 1e-12]
        out[j] = float(d.min()) if d.size else 0.0
    return out


def _split(idx: np.ndarray, keep: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Fit and held-out samples: the phase's runs (steps) alternated, each side thinned to ``keep``."""
    runs = np.cumsum(np.r_[1, np.diff(idx) > 1])
    if runs.max() < 2:
        return None
    a, b = idx[runs % 2 == 0], idx[runs % 2 == 1]
    thin = lambda x: x[:: max(1, x.size // keep)]  # noqa: E731
    return thin(a), thin(b)


def _phase_fits(
    rec: Recording,
    cands: list[tuple[int, ...]],
    idx: np.ndarray,
    band: tuple,
    opts: ChainOptions,
    tol: float = FIT_TOL,
) -> tuple[list[ChainFit], float, float] | None:
    """Every candidate's held-out fit on ``idx`` (run to ``tol``), the no-chain residual and the
    per-sample dof."""
    q, qd, w, rate = band
    split = _split(idx, opts.max_fit_samples)
    if split is None:
        return None
    tr, te = split
    per = min(1.0, 2 * opts.cutoff_hz / rate * max(1.0, idx.size / max(te.size + tr.size, 1)))
    dof = max(te.size * per * 3, 3.0)
    fits = []
    for cols in cands:
        c = list(cols)
        axes, bias = fit_chain(q[tr][:, c], qd[tr][:, c], w[tr], tol)
        r = bias - chain_rates(axes, q[te][:, c], qd[te][:, c]) - w[te]
        names = tuple(rec.joint_names[i] for i in cols)
        fits.append(ChainFit(names, cols, float(np.sqrt(np.mean(r**2))), dof, axes, bias))
    none = float(np.sqrt(np.mean((w[te] - w[tr].mean(axis=0)) ** 2)))
    return fits, none, dof


def _answer(
    phase: str,
    frac: float,
    fits: list[ChainFit],
    none: float,
    dof: float,
    floor: dict[tuple, float],
    opts: ChainOptions,
    limb_sets: list[tuple[int, ...]],
) -> PhaseAnswer:
    """The chain test of one phase (module docstring)."""
    crit = float(f_dist.isf(opts.p_false, dof, dof))
    fits = sorted(fits, key=lambda f: f.rms)
    best = fits[0]
    table = tuple((" ".join(f.joints), f.rms) for f in fits)
    good = [f for f in fits if (f.rms / best.rms) ** 2 <= crit]
    smallest = min(good, key=lambda f: len(f.columns))
    fr = best.rms / max(floor[best.columns], 1e-12)
    if (none / best.rms) ** 2 <= crit:
        return PhaseAnswer(
            phase, frac, reason=f"no chain explains the base's rotation better than no rotation at all "
            f"(best {best.rms:.4f} rad/s, none {none:.4f}): feet that fix no rotation (point feet) or a "
            "base that does not turn", decide="stand on one flat foot and turn the base with that leg",
            fits=table, floor_ratio=fr,
        )  # fmt: skip
    single = any(set(smallest.columns) <= set(g) for g in limb_sets)
    # every chain that fits as well holds the smallest one: it is the chain, or a loop through it
    nested = all(set(smallest.columns) <= set(f.columns) for f in good)
    if single and nested:
        rivals = [f for f in fits if not set(smallest.columns) <= set(f.columns)]
        p = float(f_dist.sf((rivals[0].rms / smallest.rms) ** 2, dof, dof)) if rivals else 0.0
        return PhaseAnswer(
            phase, frac, joints=smallest.joints, confidence=1.0 - p, fits=table,
            floor_ratio=smallest.rms / max(floor[smallest.columns], 1e-12),
        )  # fmt: skip
    names = "; ".join(" ".join(f.joints) for f in good[:4])
    if not single and nested:
        return PhaseAnswer(
            phase, frac, reason="the chain that fits best joins several limbs "
            f"({' '.join(smallest.joints)}): "
            "no single limb holds the base alone (more than one foot down closes a loop)",
            decide="stand on one foot", fits=table, floor_ratio=fr,
        )  # fmt: skip
    return PhaseAnswer(
        phase, frac, reason=f"{len(good)} disjoint chains fit the base's rotation equally well on held-out "
        f"steps (within the F quantile {crit:.2f} at p={opts.p_false:g}): {names}; the gait moves them "
        "with one phase", decide="move one leg while standing on the other with the rest still",
        fits=table, floor_ratio=fr,
    )  # fmt: skip


def stance_chains(rec: Recording, opts: ChainOptions | None = None) -> StanceResult:
    """The stance chain (or why none can be named) of every contact phase of ``rec``."""
    opts = opts or ChainOptions()
    floating, rule = floating_base_rule(rec)
    if not floating or rec.q is None or rec.n_imus < 1:
        return StanceResult(floating, rule, "none")
    band = _band(rec, opts)
    q, qd, _, rate = band
    quantum = encoder_steps(q, opts.quantum)
    qfloor = quantization_floor(1.0, rate, opts.cutoff_hz, 0.0, 1)["gyro_std"]
    gyro_floor = opts.gyro_density * np.sqrt(opts.cutoff_hz)
    moving = qd.std(axis=0) > 3 * qfloor * np.maximum(quantum, 1e-12)
    cands = candidate_chains(rec.joint_names, moving, opts.max_limbs)
    floor = {c: float(np.sqrt(gyro_floor**2 + np.sum((qfloor * quantum[list(c)]) ** 2))) for c in cands}
    forces, names = foot_forces(rec)
    T = q.shape[0]
    if forces is None:
        patterns = np.zeros((T, 1), dtype=bool)
        phases = {"unknown contacts": np.arange(T)}
        source = "none in the recording: the whole recording is one phase"
    else:
        down = force_contacts(forces[:T], rate, p_false=opts.p_false).down
        patterns = down
        phases = {}
        for key in {tuple(r) for r in down.tolist()}:
            if any(key):
                label = " + ".join(n for n, d in zip(names, key, strict=True) if d) + " down"
                phases[label] = np.flatnonzero(np.all(down == np.array(key), axis=1))
        source = f"foot forces {', '.join(names)} (false-contact rate {opts.p_false:g})"
    answers = []
    for label, idx in sorted(phases.items()):
        frac = idx.size / T
        if idx.size / rate < opts.min_phase_s:
            continue
        got = _phase_fits(rec, cands, idx, band, opts) if cands else None
        if got is None:
            answers.append(
                PhaseAnswer(label, frac, reason="fewer than two stance runs", decide="take more steps")
            )
            continue
        answers.append(_answer(label, frac, *got, floor, opts, limbs(rec.joint_names)))
    info = {
        "candidates": [" ".join(rec.joint_names[i] for i in c) for c in cands],
        "patterns": int(patterns.shape[1]),
    }
    return StanceResult(True, rule, source, tuple(answers), info)
