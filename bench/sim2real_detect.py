"""Hidden effects at 3x and 10x their detection limit in every BROAD trial: named, measured, alone?

For every trial: analyse it untouched (its null case: the effects it already has, their values and,
for every effect of the library, the detection limit this trial has for it), then hide each effect at
``--factors`` times that limit, in a random direction (:func:`inject`), and random pairs and triples
of effects at the first factor, and analyse each. Per case:

* **named**: every hidden effect is among the names;
* **within 3 sigma**: each hidden effect's fitted value lies within 3 combined standard errors (the
  case's 95 % interval, as sigmas, taken for both) of the trial's own value with the hidden one
  composed on top (added, multiplied for gains, composed for rotations). The trial's own value is
  the untouched recording's fit *in the model the case named* (:func:`_own_in`): an effect the
  recording cannot tell from another that was not named takes that one's part of the trial's
  residual (on a translation trial an accelerometer bias takes the trial's gravity error), and it
  does so alike with and without the hidden change;
* **jointly named**: where the trial cannot tell two effects apart, the analysis names them together
  (``"acc_bias or gravity"``, :mod:`bodyschema.discrepancy.separability`) with their joint value in
  the parameters of the pair's first effect. A hidden effect of such a pair counts as named when the
  joint name is reported, and as within 3 sigma when the joint value lies within 3 combined standard
  errors of the untouched trial's joint value plus the hidden effects' contributions (the first's
  change plus ``maps`` times each other's);
* **extra names**: names beyond the untouched trial's and the hidden ones. A trial's own effects at
  the edge of naming come and go with what else is named: a name the untouched trial's evidence
  already asked for (significant there, but short of the held-out gain) is counted apart as an
  *edge* name, and an untouched trial's name missing from a case as *own lost*.

Writes ``sim2real-detect.json``, ``sim2real-detect.md`` and ``sim2real-detect.png``.

Measured data: BROAD (Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7), 2021, CC BY 4.0).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bench import RESULTS_DIR, detection_table, machine_note, map_jobs, write_results
from bench.sim2real import trial_paths
from bodyschema.discrepancy.effects import EFFECTS, FITTED_EFFECTS, nominal
from bodyschema.discrepancy.fit import fit_params
from bodyschema.discrepancy.separability import Z95
from sim2real.broad import broad_data_dir

__all__ = ["add_arguments", "inject", "run", "summary"]

#: The share of effects hidden at the first factor that must be named with their value within 3 sigma.
TARGET = 0.95


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=broad_data_dir(), help="folder with BROAD *.hdf5 trials")
    parser.add_argument("--trials", nargs="*", default=None, help="trial name prefixes (default: all)")
    parser.add_argument("--effects", nargs="*", default=list(FITTED_EFFECTS), help="effects to hide")
    parser.add_argument(
        "--factors", nargs="*", type=float, default=[3.0, 10.0], help="multiples of the limit"
    )
    parser.add_argument("--pairs", type=int, default=1, help="random pairs of effects per trial")
    parser.add_argument("--triples", type=int, default=1, help="random triples of effects per trial")
    parser.add_argument("--seed", type=int, default=0, help="seed of the directions and combinations")
    parser.add_argument("--jobs", type=int, default=2, help="trials analysed in parallel")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def inject(effect: str, magnitude: float, rng: np.random.Generator, gravity: np.ndarray) -> dict[str, object]:
    """Parameters of ``effect`` whose change from null has norm ``magnitude`` in a random direction
    (the detection limit is for the weakest direction, so any direction at it is revealed); a gravity
    change is a tilt of ``gravity`` by ``magnitude`` m/s² at the tip.

    >>> p = inject("gyro_scale", 0.03, np.random.default_rng(0), np.array([0.0, 0.0, -9.81]))
    >>> round(float(np.linalg.norm(np.subtract(p["matrix"], 1.0))), 6)
    0.03
    """
    if effect == "time_offset":
        return {"seconds": float(rng.choice([-1.0, 1.0]) * magnitude)}
    if effect == "gravity":
        g = np.asarray(gravity, dtype=np.float64)
        axis = np.cross(g, _unit(rng))
        angle = magnitude / np.linalg.norm(g)
        return {"vector": Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).apply(g).tolist()}
    v = magnitude * _unit(rng)
    if effect.endswith("_scale"):
        return {"matrix": (1.0 + v).tolist()}
    return {EFFECTS[effect].key: v.tolist()}


def _vec(effect: str, params: dict[str, object]) -> np.ndarray:
    return np.atleast_1d(np.asarray(params[EFFECTS[effect].key], dtype=np.float64))


def _own(null: Any, effect: str, gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The untouched trial's value of ``effect`` and its standard error: the fit when named, else the
    null value moved by what the evidence estimates (below the limit, but not zero)."""
    c = null.cause(effect)
    if c is not None and c.interval:
        return _vec(effect, c.params), _se(c.interval)
    evs = [e for e in null.evidence if e["effect"] == effect]
    ev = next((e for e in evs if e["channel"] == "both"), None) or min(evs, key=lambda e: e["p_value"])
    return _null(effect, gravity) + np.asarray(ev["estimate"]), np.asarray(ev["stderr"])


def _own_in(null: Any, rep: Any, effect: str) -> np.ndarray:
    """The untouched trial's value of ``effect`` in the model ``rep`` named: the untouched recording
    refitted with the effects the case's model holds (started from the untouched fit, the case's
    values where it has none).

    A trial's own value depends on the model it is fitted in wherever two effects overlap: compared
    with a value from another model, a case would be judged on the split between them, not on the
    hidden change."""
    names = [n for n in EFFECTS if n in rep.params and n != "noise"]
    init = {n: rep.params[n] for n in names} | {n: v for n, v in null.params.items() if n in names}
    prob = null.problem
    return _vec(effect, fit_params(prob, names, init, prob.index)[effect])


def _se(interval: list[list[float]]) -> np.ndarray:
    """The standard errors a reported 95 % interval stands for."""
    return np.array([(hi - lo) / 2.0 for lo, hi in interval]) / Z95


def _null(effect: str, gravity: np.ndarray) -> np.ndarray:
    """``effect``'s value when absent: its nominal, or the trial's gravity."""
    return gravity if effect == "gravity" else nominal(effect)


def _expected(effect: str, own: np.ndarray, hidden: dict[str, object], gravity: np.ndarray) -> np.ndarray:
    h = _vec(effect, hidden)
    if effect.endswith("_scale"):
        return own * h
    if effect == "gravity":
        return own + (h - gravity)
    if effect == "mounting_rotation":
        return (Rotation.from_rotvec(h) * Rotation.from_rotvec(own)).as_rotvec()
    return own + h


def _within(effect: str, got: np.ndarray, want: np.ndarray, sigma: np.ndarray) -> tuple[bool, float]:
    """Whether ``got`` is within 3 ``sigma`` of ``want``, and the largest deviation in sigmas."""
    if effect == "mounting_rotation":
        err = (Rotation.from_rotvec(got).inv() * Rotation.from_rotvec(want)).as_rotvec()
    else:
        err = got - want
    z = float(np.max(np.abs(err) / np.maximum(sigma, 1e-15)))
    return z <= 3.0, z


def _change(effect: str, hidden: dict[str, dict[str, object]], gravity: np.ndarray) -> np.ndarray:
    """The change of ``effect`` from its null that was hidden (zero when it was not)."""
    if effect not in hidden:
        return np.zeros(EFFECTS[effect].size)
    return _vec(effect, hidden[effect]) - _null(effect, gravity)


def _own_joint(null: Any, joint: Any, gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The untouched trial's joint value of a group (in its first effect's parameters) and its
    standard error: its own joint value of the part of the group it named jointly in the same
    parameters (else the first's value), and on top, carried over through ``maps``, every other joint
    value it named whose first effect is in the group and every member it named alone."""
    first = joint.effects[0]
    parts = sorted(
        (j for j in null.joint if j.effects[0] in joint.effects), key=lambda j: j.effects[0] != first
    )
    value, se = _own(null, first, gravity) if not parts or parts[0].effects[0] != first else (0.0, 0.0)
    covered = {first}
    for j in parts:
        half = _se(j.interval)
        if j.effects[0] == first:
            value, se = _vec(first, j.params), half
        else:
            value, se = _carry(value, se, joint, j.effects[0], _vec(j.effects[0], j.params), half, gravity)
        covered |= set(j.effects)
    for e in joint.effects:
        if e not in covered and null.cause(e) is not None:
            value, se = _carry(value, se, joint, e, *_own(null, e, gravity), gravity)
    return value, se


def _carry(
    value: np.ndarray,
    se: np.ndarray,
    joint: Any,
    effect: str,
    own: np.ndarray,
    own_se: np.ndarray,
    gravity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``value`` with ``effect``'s change from null at ``own`` carried over to the joint's first."""
    m = np.asarray(joint.maps[effect])
    return value + m @ (own - _null(effect, gravity)), np.sqrt(se**2 + (m**2) @ own_se**2)


def _joint_check(
    joint: Any, null: Any, hidden: dict[str, dict[str, object]], gravity: np.ndarray
) -> dict[str, object]:
    """A hidden effect named jointly: whether the joint value is where the untouched trial's joint
    value with the hidden changes on top puts it."""
    first = joint.effects[0]
    own_v, own_se = _own_joint(null, joint, gravity)
    want = _expected(first, own_v, hidden[first], gravity) if first in hidden else own_v
    for e in joint.effects[1:]:
        want = want + np.asarray(joint.maps[e]) @ _change(e, hidden, gravity)
    se = _se(joint.interval)
    ok, z = _within(first, _vec(first, joint.params), want, np.hypot(se, own_se))
    return {"named": True, "within": ok, "z": round(z, 2), "joint": joint.label}


def _members(rep: Any) -> dict[str, set[str]]:
    """Every name of a report (alone or joint) -> the effects it stands for."""
    out = {n: {n} for n in rep.names}
    out.update({j.label: set(j.effects) for j in rep.joint})
    return out


def _trial(path: str, effects: list[str], factors: list[float], pairs: int, triples: int, seed: int) -> dict:
    """The null and every hidden-effect case of one trial (runs in a worker process)."""
    from bodyschema.discrepancy import analyze_recording
    from bodyschema.discrepancy.hidden import hide_effect
    from sim2real.broad import load_broad

    rec = load_broad(Path(path))
    g0 = np.asarray(rec.gravity, dtype=np.float64)
    rng = np.random.default_rng([seed, int.from_bytes(Path(path).stem.encode()[:8], "little")])
    t0 = time.process_time()
    null = analyze_recording(rec)
    null_cpu = time.process_time() - t0
    limits = {e: null.detection_limit(e) for e in effects}
    # effects the untouched trial has evidence of but did not name: its own, at the edge of naming
    edge = {ev["effect"] for ev in null.evidence if ev["p_value"] < ev["alpha"]} - null.stated
    combos = [list(rng.choice(effects, size=2, replace=False)) for _ in range(pairs)]
    combos += [list(rng.choice(effects, size=3, replace=False)) for _ in range(triples)]
    plan = [([e], f) for f in factors for e in effects] + [(c, factors[0]) for c in combos]
    cases = []
    for hidden_effects, factor in plan:
        hidden = {e: inject(e, factor * limits[e], rng, g0) for e in EFFECTS if e in hidden_effects}
        gyro, acc = rec.gyro[:, 0], rec.acc[:, 0]
        for e, p in hidden.items():
            gyro, acc = hide_effect(e, p, rec.t, gyro, acc, rec.ref_quat, rng)
        t0 = time.process_time()
        rep = analyze_recording(replace(rec, gyro=gyro[:, None], acc=acc[:, None]))
        cpu = time.process_time() - t0
        per = {}
        for e, p in hidden.items():
            c = rep.cause(e)
            joint = rep.joint_cause(e) if c is None else None
            if joint is not None:
                per[e] = _joint_check(joint, null, hidden, g0)
                continue
            if c is None:
                per[e] = {"named": False, "within": False, "z": None}
                continue
            # the same model on the same motion: the untouched fit's standard error is the case's
            se = _se(c.interval)
            want = _expected(e, _own_in(null, rep, e), p, g0)
            ok, z = _within(e, _vec(e, c.params), want, np.sqrt(2.0) * se)
            per[e] = {"named": True, "within": ok, "z": round(z, 2)}
        # a joint name counts like any other: beyond the untouched trial's when none of its effects
        # was stated there (alone or jointly) or hidden
        known, members = null.stated | set(hidden), _members(rep)
        beyond = {n for n, m in members.items() if not m & known}
        near = {n for n in beyond if members[n] & edge}
        cases.append(
            {
                "hidden": sorted(hidden),
                "factor": factor,
                "magnitudes": {e: factor * limits[e] for e in hidden},
                "effects": per,
                "joint": rep.joint_names,
                "extra": sorted(beyond - near),
                "edge": sorted(near),
                "own_lost": sorted(n for n, m in _members(null).items() if not m & rep.stated),
                "cpu_s": round(cpu, 2),
            }
        )
    return {
        "trial": Path(path).stem,
        "null_names": null.names,
        "null_joint": null.joint_names,
        "edge": sorted(edge),
        "null_cpu_s": round(null_cpu, 2),
        "limits": limits,
        "cases": cases,
    }


def _rates(trials: list[dict], effects: list[str], factors: list[float]) -> dict[str, Any]:
    """Per effect and factor (single-effect cases), and over all cases at the first factor."""
    out: dict[str, Any] = {"single": {}, "first_factor": {}}
    for e in effects:
        for f in factors:
            rows = [
                c["effects"][e] for t in trials for c in t["cases"] if c["hidden"] == [e] and c["factor"] == f
            ]
            out["single"][f"{e}@{f:g}"] = {
                "n": len(rows),
                "named": sum(r["named"] for r in rows),
                "within": sum(r["within"] for r in rows),
            }
    first = [
        r for t in trials for c in t["cases"] if c["factor"] == factors[0] for r in c["effects"].values()
    ]
    cases = [c for t in trials for c in t["cases"]]
    out["first_factor"] = {
        "hidden": len(first),
        "named": sum(r["named"] for r in first),
        "named_within": sum(r["named"] and r["within"] for r in first),
        "named_joint": sum("joint" in r for r in first),
    }
    out["cases"] = len(cases)
    out["cases_with_extra"] = sum(bool(c["extra"]) for c in cases)
    out["cases_with_edge"] = sum(bool(c["edge"]) for c in cases)
    out["cases_with_own_lost"] = sum(bool(c["own_lost"]) for c in cases)
    cpu = [c["cpu_s"] for c in cases] + [t["null_cpu_s"] for t in trials]
    out["cpu_s"] = {"median": float(np.median(cpu)), "max": float(np.max(cpu))}
    return out


def _joint_rule(first_factor: dict) -> list[str]:
    """How a hidden effect the trial cannot separate from another is scored (results that predate
    joint names have no such count and no such line)."""
    if "named_joint" not in first_factor:
        return []
    return [
        "",
        'Where a trial cannot tell two effects apart, the analysis names them jointly ("acc_bias or '
        "gravity\") with their joint value in the parameters of the pair's first effect. A hidden "
        "effect of such a pair counts as named when the joint name is reported, and as within 3 sigma "
        "when the joint value is within 3 sigma of the untouched trial's joint value plus the hidden "
        "effects' contributions (the first's change plus the others' carried over by the reported "
        f"maps); {first_factor['named_joint']} of the hidden effects at the first factor were named "
        "jointly. A joint name on an untouched trial is one of its own names like any other.",
    ]


def summary(data: dict) -> list[str]:
    """The result in a few lines and the per-effect table (the bench file and the docs both show it)."""
    r, f = data["rates"], data["factors"]
    ff = r["first_factor"]
    share = ff["named_within"] / max(ff["hidden"], 1)
    lines = [
        f"{len(data['trials'])} trials; every effect hidden alone at {' and '.join(f'{x:g}' for x in f)} "
        f"times the trial's own detection limit for it, in a random direction, plus random pairs and "
        f"triples at {f[0]:g} times: {r['cases']} analyses besides the untouched trials.",
        "",
        f"**At {f[0]:g}x the limit, {ff['named_within']} of {ff['hidden']} hidden effects "
        f"({100 * share:.1f} %) were named with their value within 3 sigma** "
        f"({ff['named']} named; target {100 * TARGET:.0f} %: {'met' if share >= TARGET else 'missed'}). "
        f"Cases with an extra name: {r['cases_with_extra']} of {r['cases']}; with an edge name (an own "
        f"effect the untouched trial had evidence of but did not name): {r['cases_with_edge']}; with one "
        f"of the trial's own names missing: {r['cases_with_own_lost']}. CPU per analysis: median "
        f"{r['cpu_s']['median']:.1f} s, max {r['cpu_s']['max']:.1f} s (limit 30 s).",
        *_joint_rule(ff),
        "",
    ]
    rows = [
        (
            e,
            [t["limits"][e] for t in data["trials"] if t["limits"][e] is not None],
            [r["single"][f"{e}@{x:g}"] for x in f],
        )
        for e in data["effects"]
    ]
    lines += detection_table(rows, f, "trials")
    return lines


def _markdown(data: dict) -> str:
    lines = [
        "# Hidden effects at multiples of their detection limit (BROAD)",
        "",
        f"Command: `{data['command']}`. Machine: {data['machine']}.",
        "",
        *summary(data),
    ]
    lines += ["", "## Cases that missed", ""]
    misses = [
        (t["trial"], c, e, v)
        for t in data["trials"]
        for c in t["cases"]
        for e, v in c["effects"].items()
        if not (v["named"] and v["within"])
    ]
    for trial, c, e, v in misses:
        why = "not named" if not v["named"] else f"{v['z']} sigma off"
        if v.get("joint"):
            why += f" (named as {v['joint']})"
        lines.append(f"- {trial}: {e} at {c['factor']:g}x ({', '.join(c['hidden'])} hidden): {why}")
    if not misses:
        lines.append("none")
    lines += ["", "## Extra names", ""]
    extras = [(t["trial"], c) for t in data["trials"] for c in t["cases"] if c["extra"]]
    lines += [
        f"- {trial}: {', '.join(c['extra'])} ({', '.join(c['hidden'])} hidden)" for trial, c in extras
    ] or ["none"]
    lines += ["", "Data: BROAD (Laidig, Caruso, Cereatti, Seel, Data 6(7), 2021, CC BY 4.0).", ""]
    return "\n".join(lines)


def _plot(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    effects, f, r = data["effects"], data["factors"], data["rates"]["single"]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    x = np.arange(len(effects))
    w = 0.8 / (2 * len(f))
    for i, fac in enumerate(f):
        for j, key in enumerate(("named", "within")):
            vals = [r[f"{e}@{fac:g}"][key] / max(r[f"{e}@{fac:g}"]["n"], 1) for e in effects]
            label = f"{'named' if key == 'named' else 'within 3σ'} at {fac:g}x"
            ax.bar(x + (2 * i + j) * w - 0.4 + w / 2, vals, w, label=label)
    ax.axhline(TARGET, color="k", lw=0.8, ls="--")
    ax.set_xticks(x, effects, rotation=20, fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("share of trials")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("hidden effects at multiples of their detection limit (BROAD)", fontsize=9)
    save_figure(fig, path)


def run(args: argparse.Namespace) -> Path:
    paths = trial_paths(args.data, args.trials)
    effects = [e for e in FITTED_EFFECTS if e in args.effects]
    jobs = [(str(p), effects, list(args.factors), args.pairs, args.triples, args.seed) for p in paths]
    trials = map_jobs(_trial, jobs, args.jobs, "sim2real-detect", "trial")
    argv = ["bodyhealth bench sim2real_detect"]
    if args.trials:
        argv += ["--trials", *args.trials]
    data = {
        "command": " ".join(argv),
        "machine": machine_note(),
        "effects": effects,
        "factors": list(args.factors),
        "seed": args.seed,
        "trials": trials,
        "rates": _rates(trials, effects, list(args.factors)),
    }
    return write_results(args.out, "sim2real-detect", data, _markdown(data), lambda path: _plot(data, path))
