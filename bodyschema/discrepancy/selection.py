"""Forward selection of the effects that explain a measured IMU's discrepancy, on the evidence of
each effect on each channel, checked on held-out time blocks.

The procedure:

1. The usable samples are cut into ``n_blocks`` contiguous time blocks. Fold *k* fits on all blocks
   but *k* and scores on block *k* (contiguous blocks, not shuffled samples: neighbouring samples are
   correlated and would leak).
2. **Evidence.** Every round tests every effect not yet in the model on each channel it moves, gyro
   and accelerometer apart, given the model fitted so far on all samples
   (:func:`~bodyschema.discrepancy.evidence.effect_evidence`: the effect's residual signature
   regressed on the residual, a Wald test with a covariance that is robust within ``block_s``-second
   blocks). The tests of a round share ``alpha`` (Bonferroni). No effect is skipped because another
   failed: the library's order decides nothing.
3. **Confirmation.** The effects that pass, most significant first, are tried in turn: every fold is
   refitted by nonlinear least squares with the effect added (all effects of the model free), and
   the effect joins when the held-out score of the channel that gave the evidence drops by at least
   ``min_gain`` of what the model leaves of that channel's residual, on average (a small gyro effect
   is measured neither against the accelerometer's larger residual nor against a large one the
   model already explains). When none joins, selection stops.
4. The accepted model is fitted on all usable samples; the spread of the leave-one-block-out fits
   gives each parameter's jackknife standard error, the evidence in the final model each
   parameter's 95 % interval and each effect not named its detection limit.

5. **Separability.** A named effect whose signature overlaps another's so much on this recording
   that an unseen change of the other would move it beyond its interval
   (:mod:`~bodyschema.discrepancy.separability`) keeps its own name only when its evidence holds with
   the other free, and then the interval that leaves the other free; otherwise the two are named
   jointly (:class:`~bodyschema.discrepancy.report.JointCause`), with their joint value and the
   motion that would tell them apart.

White ``noise`` is measured apart (it changes no expected reading): named when its std exceeds
``noise_floor``; its density follows the convention ``std = density * sqrt(rate)``.

Example
-------
>>> import numpy as np
>>> from bodyschema.rigid_motion import reference_motion, smooth_random_motion
>>> m = smooth_random_motion(30.0, 100.0, np.random.default_rng(3))
>>> ref = reference_motion(m["t"], m["quat"], m["pos"], cutoff=10.0)
>>> rep = analyze(ref, m["gyro"] + [0.0, 0.05, 0.0], m["acc"])
>>> rep.names, np.round(rep.params["gyro_bias"]["vector"], 3).tolist()[1]
(['gyro_bias'], 0.05)
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bodyschema.discrepancy.effects import EFFECTS, FITTED_EFFECTS, Params, nominal, pack, predict, unpack
from bodyschema.discrepancy.evidence import CHANNELS, Evidence, effect_evidence
from bodyschema.discrepancy.fit import (
    Problem,
    block_folds,
    fit_params,
    normalized_residual,
    prepare,
    residual,
    score,
    shifted_residuals,
)
from bodyschema.discrepancy.report import Cause, DiscrepancyReport, JointCause
from bodyschema.discrepancy.residuals import noise_std, residual_structure
from bodyschema.discrepancy.separability import (
    Z95,
    Overlap,
    Signatures,
    groups,
    joint_maps,
    overlaps,
    separate_by,
    signature_columns,
)
from bodyschema.progress import progress
from bodyschema.recording import Recording
from bodyschema.rigid_motion import ReferenceMotion, reference_motion
from bodyschema.threads import blas_threads

__all__ = ["AnalyzerOptions", "DiscrepancyAnalyzer", "analyze", "analyze_recording", "reference_of"]

log = logging.getLogger(__name__)


@dataclass
class _Fold:
    train: np.ndarray
    test: np.ndarray
    params: Params = field(default_factory=dict)
    held: float = 0.0
    #: (gyro, acc) held-out scores of the current model
    held_ch: np.ndarray = field(default_factory=lambda: np.zeros(2))


def _rms(prob: Problem, params: Params, index: np.ndarray) -> dict[str, object]:
    r, _ = residual(prob, params)
    rg = r[index, :3]
    ra = r[index, 3:]
    return {
        "gyro_rms": float(np.sqrt(np.mean(rg**2))),
        "acc_rms": float(np.sqrt(np.mean(ra**2))),
        "gyro_rms_axis": [float(x) for x in np.sqrt(np.mean(rg**2, axis=0))],
        "acc_rms_axis": [float(x) for x in np.sqrt(np.mean(ra**2, axis=0))],
    }


def _init_time_offset(prob: Problem, params: Params, index: np.ndarray) -> Params:
    """Start a time-offset fit at the best of a grid (the cost is not convex in the offset).

    The prediction without the offset is computed once; only the measurement is shifted per grid
    point (:func:`~bodyschema.discrepancy.fit.shifted_residuals`).
    """
    p0 = {k: v for k, v in params.items() if k != "time_offset"}
    gp, ap = predict(prob.ref, p0)
    pred = np.concatenate([gp, ap], axis=1)
    w = np.repeat(1.0 / prob.scale, 3)
    best, best_s = 0.0, np.inf
    step = 2.0 / prob.rate
    for tau, r in shifted_residuals(prob, pred, np.arange(-0.2, 0.2 + step / 2, step), index):
        s = float(np.mean((r * w) ** 2))
        if s < best_s:
            best, best_s = tau, s
    out = dict(params)
    out["time_offset"] = {"seconds": best}
    return out


def _init_mounting(prob: Problem, params: Params, index: np.ndarray) -> Params:
    """Start a mounting-rotation fit at the rotation that best aligns predicted and measured rates."""
    p0 = {k: v for k, v in params.items() if k != "mounting_rotation"}
    gp, _ = predict(prob.ref, p0)
    w = np.linalg.norm(gp[index], axis=1) > 0.05
    if w.sum() < 10:
        return params
    # measured ~ R^T predicted, so R maps measured onto predicted.
    rot, _ = Rotation.align_vectors(gp[index][w], prob.gyro[index][w])
    out = dict(params)
    out["mounting_rotation"] = {"rotvec": [float(x) for x in rot.as_rotvec()]}
    return out


def _mean_params(params: list[Params], names: list[str]) -> Params:
    if not names:
        return {}
    return unpack(np.mean([pack(p, names) for p in params], axis=0), names)


def _step_params(params: Params, names: list[str], delta: np.ndarray, ref: ReferenceMotion) -> Params:
    x = pack(params, names, ref) + delta
    out = dict(params)
    out.update(unpack(x, names))
    return out


@dataclass(frozen=True)
class AnalyzerOptions:
    """The settings of the held-out effect selection (see the module docstring for the procedure).

    Shared by :func:`analyze`, :func:`analyze_recording` and :class:`DiscrepancyAnalyzer`; each also
    takes any field as a keyword, which overrides the options given.
    """

    #: The candidate effects, from :data:`~bodyschema.discrepancy.effects.FITTED_EFFECTS`.
    effects: Sequence[str] = FITTED_EFFECTS
    #: Contiguous time blocks the usable samples are cut into (one fold per block).
    n_blocks: int = 8
    #: Family significance level of a round's evidence tests (split over them, Bonferroni).
    alpha: float = 0.01
    #: Least mean held-out gain an effect must bring on the channel of its evidence, as a fraction of
    #: what the model so far leaves of that channel's residual (floored by ``scale_floor``): what an
    #: effect must explain to be worth naming
    #: (half a percent; on BROAD a real gyro bias of 0.4 deg/s explains 1-2 % of the gyro's).
    min_gain: float = 0.005
    #: Low-pass cutoff of the reference motion and the readings, Hz (None: no low-pass).
    cutoff: float | None = 10.0
    #: Rate the readings are decimated to for the analysis, Hz (None: the recording's own).
    analysis_rate: float | None = 100.0
    #: Seconds dropped at both ends and around every invalid stretch (filter transients).
    margin: float = 0.25
    #: (gyro, accelerometer) white-noise std below which ``noise`` is not named, rad/s and m/s².
    noise_floor: tuple[float, float] = (1e-4, 1e-3)
    #: Floors of the (gyro, accelerometer) scales the residuals are divided by (their RMS under the
    #: ideal model), rad/s and m/s².
    scale_floor: tuple[float, float] = (0.002, 0.02)
    #: Seconds per time block of the evidence tests (blocks are taken as independent, samples within
    #: one are not; see :mod:`bodyschema.discrepancy.evidence`).
    block_s: float = 2.0
    #: Show a progress bar over the effects (:func:`bodyschema.progress.progress`); changes no result.
    progress: bool = False


def _energy_floor(prob: Problem, opts: AnalyzerOptions) -> tuple[float, float]:
    """(gyro, acc) mean squared normalised residual below which a channel counts as explained: its
    ``scale_floor`` in the units the residuals are normalised to."""
    g, a = (float(f / s) ** 2 for f, s in zip(opts.scale_floor, prob.scale, strict=True))
    return g, a


def _evidence_options(prob: Problem, opts: AnalyzerOptions) -> dict[str, object]:
    """The settings the evidence tests and their detection limits take from the analysis."""
    return {
        "alpha": opts.alpha,
        "block_s": opts.block_s,
        "min_gain": opts.min_gain,
        "energy_floor": _energy_floor(prob, opts),
    }


def _options(options: AnalyzerOptions | None, overrides: Mapping[str, object]) -> AnalyzerOptions:
    """``options`` (default: the defaults) with the keywords ``overrides`` replacing its fields."""
    unknown = sorted(set(overrides) - {f.name for f in fields(AnalyzerOptions)})
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {unknown}; the settings are AnalyzerOptions fields")
    return replace(options or AnalyzerOptions(), **overrides)


def analyze(
    ref: ReferenceMotion,
    gyro: np.ndarray,
    acc: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    options: AnalyzerOptions | None = None,
    **overrides: Any,
) -> DiscrepancyReport:
    """Name the effects that explain why the measured ``gyro``/``acc`` differ from the ideal prediction.

    ``ref`` is the reference motion low-passed at ``cutoff`` (:func:`reference_of` builds it from a
    recording); ``gyro``/``acc`` (T, 3) the measured readings on ``ref.t``; ``valid`` (T,) the
    samples with a trustworthy reference. The settings are ``options`` with any
    :class:`AnalyzerOptions` field given as a keyword (``n_blocks=6``) replacing its value. See the
    module docstring for the procedure.
    """
    opts = _options(options, overrides)
    bad = [e for e in opts.effects if e not in FITTED_EFFECTS]
    if bad:
        raise ValueError(f"unknown or unfittable effects {bad}; choose from {list(FITTED_EFFECTS)}")
    # The matrices here are tall and thin (samples x a few dozen parameters): BLAS threads only
    # contend, several-fold slower on a busy machine than one thread.
    with blas_threads(1):
        return _analyze(ref, gyro, acc, valid, opts)


def _analyze(
    ref: ReferenceMotion, gyro: np.ndarray, acc: np.ndarray, valid: np.ndarray | None, opts: AnalyzerOptions
) -> DiscrepancyReport:
    """Prepare, select on the folds, refit on all samples, measure the noise, report."""
    prob = prepare(ref, gyro, acc, valid, opts.cutoff, opts.analysis_rate, opts.margin, opts.scale_floor)
    folds = _make_folds(prob, opts.n_blocks)
    held_before = float(np.mean([f.held for f in folds]))
    selected, causes, screening, params = _select(prob, folds, opts, held_before)
    causes = _final_fit(folds, selected, causes, params, opts.n_blocks)
    # The evidence of every effect in the final model: the named ones given the others (their
    # intervals), the rest as candidates (their detection limits).
    final = effect_evidence(
        prob, params, selected, opts.effects, channels=tuple(CHANNELS), **_evidence_options(prob, opts)
    )
    causes = _with_intervals(causes, params, final)
    # A named effect whose value the recording cannot tell from another's is named jointly with it.
    causes, joint = _joint_causes(prob, params, selected, causes, final, opts)
    # Noise, from the full-rate measured readings above the motion band.
    causes += _noise_cause(ref, gyro, acc, valid, prob, opts.margin, opts.noise_floor)
    if any(c.effect == "noise" for c in causes):
        params["noise"] = causes[-1].params
    return replace(_report(prob, folds, causes, params, screening, held_before, opts, final), joint=joint)


def _make_folds(prob: Problem, n_blocks: int) -> list[_Fold]:
    """Fold *k* trains on every block but *k* and is scored on block *k*, starting from the ideal model."""
    blocks = block_folds(prob.index, n_blocks)
    folds = [
        _Fold(np.concatenate([b for j, b in enumerate(blocks) if j != k]), blocks[k]) for k in range(n_blocks)
    ]
    r0 = normalized_residual(prob, {})
    for f in folds:
        f.held = score(r0, f.test)
        f.held_ch = _channel_scores(r0, f.test)
    return folds


def _select(
    prob: Problem, folds: list[_Fold], opts: AnalyzerOptions, held_before: float
) -> tuple[list[str], list[Cause], list[dict[str, float]], Params]:
    """Forward selection on the evidence: every round tests every effect not yet named on each
    channel, and the most significant one that also gains on held-out blocks joins the model.

    The folds are updated in place to the fits of the accepted model. Returns the accepted effects in
    order, their causes (parameters still empty), each round's p-values (the smallest over the
    channels) and the model's fit on all usable samples.
    """
    selected: list[str] = []
    causes: list[Cause] = []
    screening: list[dict[str, float]] = []
    params: Params = {}
    bar = progress(total=len(opts.effects), desc="effects", unit="effect", enabled=opts.progress)
    while True:
        cands = [e for e in opts.effects if e not in selected]
        if not cands:
            break
        tests = effect_evidence(prob, params, selected, cands, **_evidence_options(prob, opts))
        # Bonferroni over the round's tests: every effect on every channel it touches.
        level = opts.alpha / max(len(tests), 1)
        best: dict[str, Evidence] = {}
        for ev in tests:
            if ev.effect not in best or ev.p_value < best[ev.effect].p_value:
                best[ev.effect] = ev
        ranked = sorted(best.values(), key=lambda ev: (ev.p_value, -ev.statistic))
        screening.append({ev.effect: float(f"{ev.p_value:.3g}") for ev in ranked})
        cause = None
        for ev in (ev for ev in ranked if ev.p_value < level):
            cause = _confirm(prob, folds, selected, ev, params, opts, held_before)
            if cause is not None:
                selected.append(ev.effect)
                causes.append(cause)
                names = [n for n in EFFECTS if n in selected]
                params = fit_params(prob, names, _mean_params([f.params for f in folds], names), prob.index)
                bar.update(1)
                break
        if cause is None:
            break
    bar.close()
    return selected, causes, screening, params


def _channel_scores(resid: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(gyro, acc) mean squared normalised residual over ``index``."""
    r = resid[index]
    return np.array([float(np.mean(r[:, :3] ** 2)), float(np.mean(r[:, 3:] ** 2))])


def _confirm(
    prob: Problem,
    folds: list[_Fold],
    selected: list[str],
    ev: Evidence,
    params: Params,
    opts: AnalyzerOptions,
    held_before: float,
) -> Cause | None:
    """Refit every fold with ``ev.effect`` added; accept when the held-out score of the channel that
    gave the evidence drops by at least ``min_gain`` of that channel's ideal-model energy. On
    acceptance update the folds and return the cause (parameters filled in by the final fit)."""
    c = ev.effect
    names = [n for n in EFFECTS if n in selected or n == c]
    ch = 0 if ev.channel == "gyro" else 1
    step = _step_params(params, [c], np.asarray(ev.estimate), prob.ref)
    new_params, new_held, new_ch = [], [], []
    for f in folds:
        init = {**f.params, c: step[c]}
        if c == "time_offset":
            init = _init_time_offset(prob, f.params, f.train)
        elif c == "mounting_rotation":
            init = _init_mounting(prob, init, f.train)
        p = fit_params(prob, names, init, f.train)
        r = normalized_residual(prob, p)
        new_params.append(p)
        new_held.append(score(r, f.test))
        new_ch.append(_channel_scores(r, f.test))
    # The gain is a share of what the model leaves of this channel's residual (floored, so that a
    # near-perfect channel's round-off is not blown up): a small gyro effect is measured neither
    # against the accelerometer's residual nor against a large one the model already explains.
    old_ch = np.array([f.held_ch[ch] for f in folds])
    remaining = max(float(np.mean(old_ch)), _energy_floor(prob, opts)[ch])
    gain_ch = float(np.mean(old_ch - np.array(new_ch)[:, ch])) / remaining
    log.info("candidate %s (%s): p=%.2g, held-out gain %.4f", c, ev.channel, ev.p_value, gain_ch)
    if gain_ch < opts.min_gain:
        return None
    d = np.array([f.held for f in folds]) - np.array(new_held)
    for f, p, h, hc in zip(folds, new_params, new_held, new_ch, strict=True):
        f.params, f.held, f.held_ch = p, h, hc
    return Cause(
        effect=c,
        params={},
        uncertainty={},
        gain=float(np.mean(d)) / held_before,
        p_value=ev.p_value,
        signature=EFFECTS[c].signature,
        explained=gain_ch,
        block_gains=[float(x) / held_before for x in d],
    )


def _final_fit(
    folds: list[_Fold], selected: list[str], causes: list[Cause], params: Params, n_blocks: int
) -> list[Cause]:
    """The causes with the model's fit on all usable samples and each parameter's standard error from
    the spread of the fold fits (delete-one-block jackknife)."""
    names = [n for n in EFFECTS if n in selected]
    if not names:
        return causes
    xs = np.stack([pack(f.params, names) for f in folds])
    se = np.sqrt((n_blocks - 1) / n_blocks * np.sum((xs - xs.mean(axis=0)) ** 2, axis=0))
    unc = unpack(se, names)
    return [replace(c, params=params[c.effect], uncertainty=unc[c.effect]) for c in causes]


def _with_intervals(causes: list[Cause], params: Params, evidence: list[Evidence]) -> list[Cause]:
    """The causes with the 95 % interval of each fitted parameter, from the block-robust evidence of
    the effect in the final model (all the channels it moves, stacked)."""
    combined = {ev.effect: ev for ev in evidence if ev.channel == "both"}
    single = {ev.effect: ev for ev in evidence if ev.channel != "both"}
    out = []
    for c in causes:
        ev = combined.get(c.effect, single.get(c.effect))
        if ev is None:
            out.append(c)
            continue
        value = pack(params, [c.effect])
        out.append(replace(c, interval=_interval(value, Z95 * np.asarray(ev.stderr))))
    return out


def _joint_causes(
    prob: Problem,
    params: Params,
    selected: list[str],
    causes: list[Cause],
    evidence: list[Evidence],
    opts: AnalyzerOptions,
) -> tuple[list[Cause], list[JointCause]]:
    """The causes less those named jointly, and the joint names: the named effects whose signatures
    overlap another effect's beyond the cut of :mod:`~bodyschema.discrepancy.separability` are named
    together with it."""
    if not selected:
        return causes, []
    level = opts.alpha / max(1, sum(ev.channel != "both" for ev in evidence))
    sig = signature_columns(prob, params, opts.effects, opts.block_s)
    found = overlaps(sig, selected, opts.effects, level=level)
    found, wide = _revealed_apart(prob, params, selected, found, level, opts)
    joint = [_joint(prob, params, selected, causes, g, found, sig, opts) for g in groups(found, selected)]
    members = {e for j in joint for e in j.effects}
    return [_widened(c, params, wide) for c in causes if c.effect not in members], joint


def _revealed_apart(
    prob: Problem,
    params: Params,
    selected: list[str],
    found: list[Overlap],
    level: float,
    opts: AnalyzerOptions,
) -> tuple[list[Overlap], dict[str, np.ndarray]]:
    """The overlaps still to be named jointly, and the standard errors of the named effects that stay
    named alone with a wider interval.

    A named effect that overlaps an effect not named beyond the cut is tested again with that effect
    free in the model: when its evidence still holds at ``level``, the data reveal it apart from
    the other, and its interval becomes the one that leaves the other free (the largest over such
    partners); otherwise the two are named jointly. Two named effects beyond the cut are judged
    alike, each with the other in the model: both keep their names when both hold (a missing 9.81
    m/s² of gravity beside an accelerometer bias of tenths overlaps it on a short recording and
    still stands out), and a pair whose split rests on what their signatures do not share is named
    jointly."""
    keep, wide = [], {}
    for o in found:
        if o.separable:
            keep.append(o)
            continue
        evs = effect_evidence(
            prob,
            params,
            selected if o.partner in selected else [*selected, o.partner],
            [o.named],
            channels=tuple(CHANNELS),
            **_evidence_options(prob, opts),
        )
        best = min((e for e in evs if e.channel != "both"), key=lambda e: e.p_value)
        if best.p_value >= level:
            keep.append(o)
            continue
        ev = next((e for e in evs if e.channel == "both"), best)
        wide[o.named] = np.maximum(wide.get(o.named, 0.0), np.asarray(ev.stderr))
    return keep, wide


def _interval(value: np.ndarray, half: np.ndarray) -> list[list[float]]:
    """``[[value - half, value + half], ...]`` per parameter."""
    return [[float(v - h), float(v + h)] for v, h in zip(value, half, strict=True)]


def _widened(cause: Cause, params: Params, wide: Mapping[str, np.ndarray]) -> Cause:
    """``cause`` with the 95 % interval that leaves its overlapping partners free, where it is wider."""
    if cause.effect not in wide or not cause.interval:
        return cause
    value = pack(params, [cause.effect])
    half = np.maximum(Z95 * wide[cause.effect], [(hi - lo) / 2.0 for lo, hi in cause.interval])
    return replace(cause, interval=_interval(value, half))


def _joint(
    prob: Problem,
    params: Params,
    selected: list[str],
    causes: list[Cause],
    group: list[str],
    found: list[Overlap],
    sig: Signatures,
    opts: AnalyzerOptions,
) -> JointCause:
    """The joint value of a group in its first effect's parameters, with its interval: the model
    refitted with the first in the place of the whole group (started from the group's values carried
    over to it), the interval the first's evidence in that model."""
    first = group[0]
    maps = joint_maps(sig, group, selected)
    names = [n for n in EFFECTS if (n in selected and n not in group) or n == first]
    init = {k: v for k, v in params.items() if k not in group}
    start = pack(params, [first], prob.ref)
    for n, m in maps.items():
        if n in selected:
            start = start + m @ (pack(params, [n], prob.ref) - nominal(n, prob.ref))
    init[first] = EFFECTS[first].to_params(start)
    # the fit stands when the first was named and the others were not (it already takes them up)
    fit = fit_params(prob, names, init, prob.index) if set(group[1:]) & set(selected) else params
    evs = effect_evidence(
        prob, fit, names, [first], channels=tuple(CHANNELS), **_evidence_options(prob, opts)
    )
    ev = next((e for e in evs if e.channel == "both"), None) or min(evs, key=lambda e: e.p_value)
    value = pack(fit, [first], prob.ref)
    se = np.asarray(ev.stderr)
    named = [c for c in causes if c.effect in group]
    pairs = [o for o in found if {o.named, o.partner} <= set(group) and not o.separable]
    return JointCause(
        effects=tuple(group),
        named=tuple(c.effect for c in named),
        params=EFFECTS[first].to_params(value),
        uncertainty=EFFECTS[first].to_params(se),
        interval=_interval(value, Z95 * se),
        correlation=max(o.correlation for o in pairs),
        cut=min(o.cut for o in pairs),
        maps={n: [[float(x) for x in row] for row in m] for n, m in maps.items()},
        separate_by=separate_by(group),
        gain=float(sum(c.gain for c in named)),
        p_value=min(c.p_value for c in named),
    )


def _report(
    prob: Problem,
    folds: list[_Fold],
    causes: list[Cause],
    params: Params,
    screening: list[dict[str, float]],
    held_before: float,
    opts: AnalyzerOptions,
    evidence: list[Evidence],
) -> DiscrepancyReport:
    """The report: residuals and their structure before and after, held-out scores, the evidence of
    every effect, settings."""
    fitted = {k: v for k, v in params.items() if k != "noise"}
    held_after = float(np.mean([f.held for f in folds]))
    res_b, pred_b = residual(prob, {})
    res_a, pred_a = residual(prob, fitted)
    held = _held_out_rms(prob, folds)
    return DiscrepancyReport(
        residual_before=_rms(prob, {}, prob.index),
        causes=causes,
        residual_after=_rms(prob, fitted, prob.index),
        held_out={
            "blocks": opts.n_blocks,
            "score_before": held_before,
            "score_after": held_after,
            "gain": 1.0 - held_after / held_before,
            **held,
        },
        params=params,
        structure_before=residual_structure(prob.ref, res_b, pred_b, prob.index, prob.rate),
        structure_after=residual_structure(prob.ref, res_a, pred_a, prob.index, prob.rate),
        screening=screening,
        evidence=[ev.to_json() for ev in evidence],
        settings={
            "n_blocks": opts.n_blocks,
            "alpha": opts.alpha,
            "block_s": opts.block_s,
            "min_gain": opts.min_gain,
            "cutoff_hz": opts.cutoff,
            "analysis_rate_hz": prob.rate,
            "margin_s": opts.margin,
            "channel_scale": [float(x) for x in prob.scale],
            "samples_used": int(prob.index.size),
            "effects": list(opts.effects),
        },
        problem=prob,
    )


def _held_out_rms(prob: Problem, folds: list[_Fold]) -> dict[str, float]:
    """Pooled held-out RMS per channel of the ideal model and of the fold fits."""
    sq = {"gyro_before": 0.0, "acc_before": 0.0, "gyro_after": 0.0, "acc_after": 0.0}
    n = 0
    for f in folds:
        for tag, p in (("before", {}), ("after", {k: v for k, v in f.params.items() if k != "noise"})):
            r, _ = residual(prob, p)
            sq[f"gyro_{tag}"] += float(np.sum(r[f.test, :3] ** 2))
            sq[f"acc_{tag}"] += float(np.sum(r[f.test, 3:] ** 2))
        n += f.test.size * 3
    return {f"{k.split('_')[0]}_rms_{k.split('_')[1]}": float(np.sqrt(v / n)) for k, v in sq.items()}


def _noise_cause(
    ref: ReferenceMotion,
    gyro: np.ndarray,
    acc: np.ndarray,
    valid: np.ndarray | None,
    prob: Problem,
    margin: float,
    floor: tuple[float, float],
) -> list[Cause]:
    rate = float(1.0 / np.median(np.diff(ref.t)))
    ok = np.ones(ref.t.shape[0], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    ok = ok & np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(acc), axis=1)
    m = max(1, round(margin * rate))
    ok[:m] = False
    ok[-m:] = False
    idx = np.flatnonzero(ok)
    if idx.size < 20:
        return []
    g = np.where(np.isfinite(gyro), gyro, 0.0)
    a = np.where(np.isfinite(acc), acc, 0.0)
    sg, sa = noise_std(g, rate, idx), noise_std(a, rate, idx)
    if np.all(sg < floor[0]) and np.all(sa < floor[1]):
        return []
    # Standard error of a std estimate from the halves of the trial (a crude block spread).
    halves = np.array_split(idx, 2)
    spread = (
        np.abs(
            np.concatenate([noise_std(g, rate, halves[0]), noise_std(a, rate, halves[0])])
            - np.concatenate([noise_std(g, rate, halves[1]), noise_std(a, rate, halves[1])])
        )
        / 2
    )
    std = np.concatenate([sg, sa])
    return [
        Cause(
            effect="noise",
            params={
                "std": [float(x) for x in std],
                "gyro_density": [float(x) for x in sg / np.sqrt(rate)],
                "acc_density": [float(x) for x in sa / np.sqrt(rate)],
                "rate_hz": rate,
            },
            uncertainty={"std": [float(x) for x in spread]},
            gain=0.0,
            p_value=float("nan"),
            signature=EFFECTS["noise"].signature
            + f"; measured above {rate / 4:.0f} Hz; changes no expected reading, so no held-out gain",
            explained=0.0,
        )
    ]


def reference_of(rec: Recording, cutoff: float | None = 10.0) -> ReferenceMotion:
    """The low-passed reference motion of a recording with ``ref_quat``/``ref_pos`` (motion capture)."""
    if rec.ref_quat is None:
        raise ValueError("the recording has no reference motion (ref_quat); a robot recording needs a model")
    pos = rec.ref_pos if rec.ref_pos is not None else np.zeros((rec.n_samples, 3))
    return reference_motion(rec.t, rec.ref_quat, pos, rec.gravity, cutoff)


def analyze_recording(
    rec: Recording, imu: int | str = 0, *, options: AnalyzerOptions | None = None, **overrides: Any
) -> DiscrepancyReport:
    """:func:`analyze` for one IMU of a recording with a reference motion.

    The settings are as for :func:`analyze` (``cutoff`` also low-passes the reference motion).
    ``extra['ref_valid']`` (samples with a trustworthy reference) is honoured when present.
    """
    opts = _options(options, overrides)
    k = rec.imu_names.index(imu) if isinstance(imu, str) else int(imu)
    if not 0 <= k < rec.n_imus:
        raise ValueError(f"imu {imu!r} not in {rec.imu_names}")
    valid = rec.extra.get("ref_valid")
    ref = reference_of(rec, opts.cutoff)
    rep = analyze(ref, rec.gyro[:, k], rec.acc[:, k], valid, options=opts)
    meta = {"imu": rec.imu_names[k], "samples": rec.n_samples, "duration_s": rec.duration}
    for key in ("attribution", "source"):
        if key in rec.extra and rec.extra[key].shape == ():
            meta[key] = str(rec.extra[key])
    rep.meta.update(meta)
    return rep


class DiscrepancyAnalyzer:
    """Estimator form of :func:`analyze` (scikit-learn style: settings in ``__init__``, ``fit`` -> self).

    Settings: ``options`` (:class:`AnalyzerOptions`) with any of its fields given as a keyword
    replacing its value; kept as ``options``, and each field reads as an attribute too
    (``DiscrepancyAnalyzer(n_blocks=6).n_blocks``).

    Learned: ``report_`` (:class:`~bodyschema.discrepancy.report.DiscrepancyReport`), ``params_``
    (the fitted effects), ``causes_`` (their names in order).
    """

    def __init__(self, options: AnalyzerOptions | None = None, **overrides: Any) -> None:
        self.options = _options(options, overrides)

    def __getattr__(self, name: str) -> Any:
        # only called for names not found otherwise: the settings read through to the options
        if name != "options" and name in {f.name for f in fields(AnalyzerOptions)}:
            return getattr(self.options, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def fit(self, rec: Recording, imu: int | str = 0) -> DiscrepancyAnalyzer:
        """Analyse one IMU of a recording with a reference motion."""
        self.report_ = analyze_recording(rec, imu, options=self.options)
        self.params_ = self.report_.params
        self.causes_ = self.report_.names
        return self

    def predict(self, rec: Recording) -> tuple[np.ndarray, np.ndarray]:
        """``(gyro, acc)`` (T, 3) the fitted model says the IMU reads for ``rec``'s reference motion."""
        ref = reference_of(rec, self.options.cutoff)
        return predict(ref, {k: v for k, v in self.params_.items() if k != "noise"})
