"""Health of a floating-base robot with one base IMU: typed findings against a baseline recording.

The fixed-base diff (:mod:`bodyschema.diff`, :mod:`bodyschema.health`) judges a joint by the IMUs on
its child link; a walking robot's single IMU rides the base, so that path sees nothing. Here every
finding comes from a check whose tolerance is a stated error model, measured on the baseline:

* ``imu_dead`` — all six axes repeat one reading for ``n`` samples or more. A live IMU repeats a
  whole row only when its logger holds one (measured share ``p`` of rows on the baseline); ``n`` is
  the run that independent holds reach with chance ``p_false`` per window (``T p^n = p_false``),
  longer than any run on the baseline, and at least ``HealthThresholds.min_samples`` (the fixed-base
  check's run).
* ``encoder_fault`` (frozen) — the encoder holds one reading while the body moves (at least half of
  the other joints the baseline moved turn faster than their quantization noise allows at
  ``p_false``) for ``still_seconds`` longer than the longest such hold on the baseline.
* ``encoder_fault`` (jump) — the reading moves further in one sample than the joint's whole travel
  on the baseline plus four encoder steps: no motion crosses a joint's range in one sample (a sign
  flip starting mid-window).
* stance-chain checks (where :mod:`bodyschema.stance_chains` names a chain on the baseline): the
  chain's exact model, fitted on the baseline, predicts the base gyro from the encoders. When the
  current residual power exceeds the baseline's held-out residual by the F quantile at ``p_false``,
  the hypotheses that would explain it are fitted — each chain joint sign-flipped, each chain joint
  offset by a constant, the IMU turned on its mount (a small rotation of its readings) — and the
  one that restores the fit most names the finding (``encoder_fault`` or ``imu_rotated``).

Nothing here reads ``injected_faults`` or any ``truth_*`` field. Pure numpy/scipy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import f as f_dist
from scipy.stats import norm

from bodyschema.findings import Diff, Finding
from bodyschema.floating_base import quantization_floor, skew
from bodyschema.health import HealthThresholds
from bodyschema.recording import Recording
from bodyschema.rigid_motion import lowpass
from bodyschema.stance_chains import (
    MODEL_TOL,
    ChainOptions,
    _phase_fits,
    chain_rates,
    encoder_steps,
    foot_forces,
    stance_chains,
)
from bodyschema.stance_tilt import TiltModel, TiltOptions, tilt_hypotheses, tilt_model, tilt_test

__all__ = ["FloatingBaseline", "FloatingOptions", "floating_baseline", "floating_diff"]


@dataclass(frozen=True)
class FloatingOptions:
    """``p_false``: chance per window and check of a false finding. ``still_seconds``: how much longer
    than the baseline's longest hold a frozen encoder must hold. ``chains``: the stance-chain options
    (band, significance)."""

    p_false: float = 1e-3
    still_seconds: float = 1.0
    chains: ChainOptions = field(default_factory=ChainOptions)
    tilt: TiltOptions = field(default_factory=TiltOptions)


@dataclass(frozen=True)
class _Chain:
    phase: str
    key: tuple[bool, ...]
    columns: tuple[int, ...]
    axes: np.ndarray
    bias: np.ndarray
    rms: float
    dof: float


@dataclass(frozen=True)
class FloatingBaseline:
    """What the checks learned from the healthy recording (per joint, per IMU, per stance chain)."""

    joint_names: tuple[str, ...]
    imu_names: tuple[str, ...]
    quantum: np.ndarray
    moving: np.ndarray
    max_jerk: np.ndarray  # the joint's travel on the baseline (rad)
    still_run_s: np.ndarray
    imu_repeat: np.ndarray
    imu_run: np.ndarray
    force_threshold: np.ndarray | None
    chains: tuple[_Chain, ...]
    tilt: TiltModel | None = None


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of every run of True."""
    f = np.r_[False, flags, False].astype(np.int8)
    d = np.diff(f)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _imu_repeats(rec: Recording, k: int) -> np.ndarray:
    both = np.concatenate([rec.acc[:, k], rec.gyro[:, k]], axis=1)
    return np.r_[False, np.all(np.diff(both, axis=0) == 0.0, axis=1)]


def _body_moving(qd: np.ndarray, floor: np.ndarray, moving: np.ndarray, p_false: float) -> np.ndarray:
    """(T, N) per joint: at least half of the *other* baseline-moving joints turn faster than their
    quantization noise allows."""
    k = float(norm.isf(p_false / 2))
    fast = (np.abs(qd) > k * np.maximum(floor, 1e-12)) & moving
    n_other = np.maximum(moving.sum() - moving.astype(int), 1)
    return (fast.sum(axis=1, keepdims=True) - fast) >= 0.5 * n_other


def _band_rates(rec: Recording, opts: FloatingOptions) -> tuple[np.ndarray, np.ndarray, float]:
    rate = rec.sample_rate
    qd = lowpass(np.gradient(rec.q, rec.encoder_t, axis=0), rate, opts.chains.cutoff_hz)
    floor1 = quantization_floor(1.0, rate, opts.chains.cutoff_hz, 0.0, 1)["gyro_std"]
    return qd, floor1, rate


def _holds(q: np.ndarray, active: np.ndarray, dt: float) -> np.ndarray:
    """(N,) longest time (s) each joint holds one reading while ``active`` (T, N)."""
    out = np.zeros(q.shape[1])
    same = np.r_[np.zeros((1, q.shape[1]), bool), np.diff(q, axis=0) == 0.0]
    for j in range(q.shape[1]):
        for s, e in _runs(same[:, j]):
            out[j] = max(out[j], float(active[s:e, j].sum()) * dt)
    return out


def floating_baseline(rec: Recording, opts: FloatingOptions | None = None) -> FloatingBaseline:
    """Learn the checks' tolerances and the stance-chain models from a healthy recording."""
    opts = opts or FloatingOptions()
    if rec.t_q is not None:
        rec = rec.synced()
    quantum = encoder_steps(rec.q)
    qd, floor1, rate = _band_rates(rec, opts)
    moving = qd.std(axis=0) > 3 * floor1 * np.maximum(quantum, 1e-12)
    active = _body_moving(qd, floor1 * quantum, moving, opts.p_false)
    still = _holds(rec.q, active, 1.0 / rate)
    jerk = np.ptp(rec.q, axis=0)
    rep = np.array([_imu_repeats(rec, k).mean() for k in range(rec.n_imus)])
    run = np.array(
        [max((e - s for s, e in _runs(_imu_repeats(rec, k))), default=0) for k in range(rec.n_imus)]
    )
    forces, _ = foot_forces(rec)
    thr = None
    chains: list[_Chain] = []
    tilt = None
    res = stance_chains(rec, opts.chains)
    if forces is not None:
        from bodyschema.contacts import force_contacts

        c = force_contacts(forces, rate, p_false=opts.chains.p_false)
        thr = c.threshold
        chains = _chain_models(rec, res, c.down, opts)
        if chains and rec.n_imus:
            legs = [(ch.key, ch.columns, ch.axes) for ch in chains]
            tilt = tilt_model(rec.q, rec.acc[:, 0], c.down, rate, legs, opts.tilt)
    return FloatingBaseline(
        rec.joint_names, rec.imu_names, quantum, moving, jerk, still, rep, run, thr, tuple(chains), tilt
    )


def _chain_models(rec: Recording, res, down: np.ndarray, opts: FloatingOptions) -> list[_Chain]:
    """The exact chain model of every phase the baseline names a single-limb chain for."""
    from bodyschema.stance_chains import _band

    band = _band(rec, opts.chains)
    out = []
    for p in res.chains:
        cols = tuple(rec.joint_names.index(j) for j in p.joints)
        key = tuple(n in p.phase.split(" down")[0].split(" + ") for n in foot_forces(rec)[1])
        idx = np.flatnonzero(np.all(down == np.array(key), axis=1))
        got = _phase_fits(rec, [cols], idx, band, opts.chains, MODEL_TOL)
        if got is None:
            continue
        fit = got[0][0]
        out.append(_Chain(p.phase, key, cols, fit.axes, fit.bias, fit.rms, fit.dof))
    return out


def _dead_imus(cur: Recording, base: FloatingBaseline, opts: FloatingOptions) -> list[Finding]:
    out = []
    for k, name in enumerate(cur.imu_names):
        p = float(np.clip(base.imu_repeat[k] if k < len(base.imu_repeat) else 0.0, 1e-6, 0.5))
        n_model = int(np.ceil(np.log(opts.p_false / max(cur.n_samples, 1)) / np.log(p)))
        n = max(
            n_model, int(base.imu_run[k]) + 1 if k < len(base.imu_run) else 1, HealthThresholds().min_samples
        )
        runs = [(s, e) for s, e in _runs(_imu_repeats(cur, k)) if e - s + 1 >= n]
        if runs:
            s, e = max(runs, key=lambda r: r[1] - r[0])
            secs = float(cur.t[min(e, cur.n_samples - 1)] - cur.t[max(s - 1, 0)])
            detail = f"all six axes repeat one reading for {secs:.2f} s from t={cur.t[s] - cur.t[0]:.2f} s"
            out.append(Finding("imu_dead", imu=name, detail=detail))
    return out


def _encoders(cur: Recording, base: FloatingBaseline, opts: FloatingOptions) -> list[Finding]:
    qd, floor1, rate = _band_rates(cur, opts)
    quantum = np.where(base.quantum > 0, base.quantum, encoder_steps(cur.q))
    active = _body_moving(qd, floor1 * quantum, base.moving, opts.p_false)
    holds = _holds(cur.q, active, 1.0 / rate)
    jerk = np.abs(np.diff(cur.q, axis=0))
    out = []
    for j, name in enumerate(cur.joint_names):
        if not base.moving[j]:
            continue
        if holds[j] > base.still_run_s[j] + opts.still_seconds:
            detail = f"encoder holds one reading for {holds[j]:.1f} s while the body moves"
            out.append(Finding("encoder_fault", joint=name, detail=detail))
            continue
        lim = base.max_jerk[j] + 4 * quantum[j]
        if jerk[:, j].size and jerk[:, j].max() > lim:
            i = int(np.argmax(jerk[:, j])) + 1
            detail = (
                f"reading jumps {jerk[i - 1, j]:.3f} rad at t={cur.t[i] - cur.t[0]:.2f} s "
                f"(baseline travel {base.max_jerk[j]:.3f} rad)"
            )
            out.append(Finding("encoder_fault", joint=name, detail=detail))
    return out


def _hypotheses(ch: _Chain, q: np.ndarray, qd: np.ndarray, w: np.ndarray, names: tuple[str, ...]):
    """(label, finding kind, part, residual RMS) for each fault that could explain the chain's misfit."""
    cols = list(ch.columns)

    def rms(qq: np.ndarray, qqd: np.ndarray, ww: np.ndarray) -> float:
        return float(np.sqrt(np.mean((ch.bias - chain_rates(ch.axes, qq, qqd) - ww) ** 2)))

    Q, QD = q[:, cols], qd[:, cols]
    out = [("as read", "", "", rms(Q, QD, w))]
    for i, c in enumerate(cols):
        s = np.ones(len(cols))
        s[i] = -1.0
        out.append(("sign flipped", "encoder_fault", names[c], rms(Q * s, QD * s, w)))
        e = np.zeros(len(cols))
        grid = np.radians(np.linspace(-10, 10, 41))
        vals = []
        for d in grid:
            e[i] = d
            vals.append(rms(Q + e, QD, w))
        k = int(np.argmin(vals))
        out.append((f"offset {np.degrees(grid[k]):+.1f} deg", "encoder_fault", names[c], vals[k]))
    pred = ch.bias - chain_rates(ch.axes, Q, QD)
    # w = R pred ≈ pred + theta x pred = pred - [pred]x theta
    A = -skew(pred - ch.bias).reshape(-1, 3)
    theta, *_ = np.linalg.lstsq(A, (w - pred).reshape(-1), rcond=None)
    rot = np.einsum("tij,j->ti", skew(pred - ch.bias), theta)
    out.append(
        (
            f"turned {np.degrees(np.linalg.norm(theta)):.1f} deg",
            "imu_rotated",
            "",
            float(np.sqrt(np.mean((pred + rot - w) ** 2))),
        )
    )
    return out


def _chain_checks(cur: Recording, base: FloatingBaseline, opts: FloatingOptions) -> list[Finding]:
    forces, _ = foot_forces(cur)
    if forces is None or base.force_threshold is None or not base.chains or cur.n_imus < 1:
        return []
    if forces.shape[1] != base.force_threshold.shape[0]:
        return []
    from bodyschema.stance_chains import _band

    q, qd, w, rate = _band(cur, opts.chains)
    down = forces[: q.shape[0]] > base.force_threshold
    out: list[Finding] = []
    seen: set[str] = set()
    per = 2 * opts.chains.cutoff_hz / rate
    for ch in base.chains:
        idx = np.flatnonzero(np.all(down == np.array(ch.key), axis=1))
        idx = idx[(idx > 5) & (idx < q.shape[0] - 5)]
        dof = idx.size * per * 3
        if dof < 6:
            continue
        hyp = _hypotheses(ch, q[idx], qd[idx], w[idx], cur.joint_names)
        r0 = hyp[0][3]
        crit = float(f_dist.isf(opts.p_false, dof, ch.dof))
        if (r0 / ch.rms) ** 2 <= crit:
            continue
        label, kind, part, r = min(hyp[1:], key=lambda h: h[3])
        if (r0 / r) ** 2 <= float(f_dist.isf(opts.p_false, dof, dof)):
            continue
        key = f"{kind}:{part}"
        if key in seen:
            continue
        seen.add(key)
        detail = (
            f"{ch.phase}: base gyro {r0:.3f} rad/s off the stance chain (baseline {ch.rms:.3f}); "
            f"{label} fits {r:.3f}"
        )
        if kind == "imu_rotated":
            out.append(Finding("imu_rotated", imu=cur.imu_names[0], detail=detail))
        else:
            out.append(Finding("encoder_fault", joint=part, detail=detail))
    return out


def _tilt_checks(cur: Recording, base: FloatingBaseline, opts: FloatingOptions) -> list[Finding]:
    """The stance feet's gravity against the base IMU's (:mod:`bodyschema.stance_tilt`): one finding,
    the most likely of an IMU turned on its mount or a chain joint offset, when the window's tilt
    residual is beyond the baseline's spread."""
    forces, _ = foot_forces(cur)
    model = base.tilt
    if model is None or forces is None or base.force_threshold is None or cur.n_imus < 1:
        return []
    if forces.shape[1] != base.force_threshold.shape[0]:
        return []
    down = forces > base.force_threshold
    acc = cur.acc[:, 0]
    got = tilt_test(model, cur.q, acc, down, cur.sample_rate, opts.tilt)
    if got is None or got[0] <= got[1]:
        return []
    t2, crit, m, S, stance = got
    hyp = tilt_hypotheses(model, cur.q, acc, stance, m, S, opts.tilt)
    kind, label, part, _, p = hyp[0]
    total = sum(h[4] for h in hyp)
    conf = p / total if total > 0 else 0.0
    # A rival whose residual is within the error model at the test's own level is not rejected: joints
    # with parallel axes (the iCub's hip and ankle roll, its pitch joints) tilt the stance foot alike.
    rivals = [h for h in hyp[1:] if h[4] >= opts.tilt.p_false]
    names = [_tilt_part(cur, h) for h in rivals]
    detail = (
        f"stance feet's gravity off the IMU's (T² {t2:.1f} > {crit:.1f} at p={opts.tilt.p_false:g}); "
        f"{label} fits best (chi-square p {p:.3g})"
    )
    if rivals:
        detail += (
            f"; {', '.join(f'{n} ({h[1]}, p {h[4]:.3g})' for n, h in zip(names, rivals, strict=True))} "
            f"fits within the error model as well: undetermined between them (their axes tilt the stance "
            f"feet alike in these postures); stances that turn one axis against the other would decide"
        )
    said = {"confidence": conf, "detail": detail, "candidates": tuple(names)}
    if kind == "imu":
        return [Finding("imu_rotated", imu=cur.imu_names[0], **said)]
    return [Finding("encoder_fault", joint=cur.joint_names[part], **said)]


def _tilt_part(cur: Recording, h: tuple[str, str, int, float, float]) -> str:
    """The part key (:attr:`Finding.part`) of one tilt hypothesis."""
    return f"imu:{cur.imu_names[0]}" if h[0] == "imu" else f"joint:{cur.joint_names[h[2]]}"


def floating_diff(
    baseline: Recording | FloatingBaseline, current: Recording, opts: FloatingOptions | None = None
) -> Diff:
    """Findings of ``current`` against the healthy ``baseline`` (a recording, or what
    :func:`floating_baseline` learned from one), dead IMUs first."""
    opts = opts or FloatingOptions()
    if baseline.joint_names != current.joint_names or baseline.imu_names != current.imu_names:
        raise ValueError("baseline and current recordings name different joints or IMUs")
    base = baseline if isinstance(baseline, FloatingBaseline) else floating_baseline(baseline, opts)
    cur = current.synced() if current.t_q is not None else current
    found = _dead_imus(cur, base, opts)
    enc = _encoders(cur, base, opts)
    chain = [f for f in _chain_checks(cur, base, opts) if f.joint not in {e.joint for e in enc}]
    seen = {f.part for f in enc + chain}
    # a tilt that one of its candidate parts explains is that part's fault, already found
    tilt = [f for f in _tilt_checks(cur, base, opts) if not {f.part, *f.candidates} & seen]
    return Diff(findings=tuple(found + enc + chain + tilt))
