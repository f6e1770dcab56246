"""Hidden encoder effects at 3x and 10x their detection limit on simulated robots: named, measured, alone?

For every robot and seed: simulate ``--seconds`` with the ``robot`` sensing preset (14-bit encoders at
250 Hz, MPU-6050 IMUs at 100 Hz behind their low-pass, two clocks, jitter, drops) and analyse it
untouched (:func:`sim2real.encoders.encoder_analysis` with the robot's own model): its
null case. What the null names is the recording's own set (the time offset its stamps already have:
the IMU's skew plus its filter delay), measured once; every other effect on every joint gets the
detection limit this recording has for it. Then each effect is hidden on a random joint where it is
observable, at ``--factors`` times that limit with a random sign (a dead band is positive), and random
pairs and triples on distinct joints at the first factor, and each case is analysed. The effects go in
through the simulator, so the motion and the IMU readings are the null case's: zero offsets and gear
ratios as ``encoder_fault`` (``offset``, ``scale``), dead bands as ``backlash`` damage, a time offset
as more skew of the IMU's stamps.

Per case:

* **named**: the hidden effect's name is reported, alone or jointly with effects the recording cannot
  tell from it (``"encoder_offset[elbow] or encoder_offset[wrist_1]"``);
* **within 3 sigma**: its value, through the joint name's factor where named jointly, lies within 3
  combined standard errors of the null's value plus the hidden change;
* **extra names**: names none of whose members is hidden or named by the null.

Writes ``sim2real-encoders.json``, ``sim2real-encoders.md`` and ``sim2real-encoders.png``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, detection_table, machine_note, map_jobs
from bodyschema.discrepancy.encoders import ENCODER_EFFECTS, ENCODER_NULL, EncoderReport

__all__ = ["TARGET", "Hidden", "add_arguments", "analyze_case", "draw_cases", "run", "score", "summary"]

#: The share of effects hidden at the first factor that must be named with their value within 3 sigma.
TARGET = 0.95


@dataclass(frozen=True)
class Hidden:
    """One hidden effect: ``change`` from the recording's own value (s, rad, gain - 1, rad)."""

    effect: str
    joint: str | None
    change: float
    factor: float

    @property
    def name(self) -> str:
        return self.effect if self.joint is None else f"{self.effect}[{self.joint}]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", nargs="*", default=["ur5e", "dual-arm", "paper-2"], help="catalog robots")
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2], help="simulation seeds per robot")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of each recording")
    parser.add_argument(
        "--factors", nargs="*", type=float, default=[3.0, 10.0], help="multiples of the limit"
    )
    parser.add_argument("--pairs", type=int, default=1, help="random pairs of effects per recording")
    parser.add_argument("--triples", type=int, default=1, help="random triples of effects per recording")
    parser.add_argument("--jobs", type=int, default=2, help="recordings analysed in parallel")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def analyze_case(robot: str, seconds: float, seed: int, hidden: list[Hidden]) -> tuple[EncoderReport, float]:
    """Simulate ``robot`` with the effects ``hidden`` and analyse it: the report and its CPU seconds."""
    from sim2real.encoders import encoder_analysis
    from simulators.sensing import PRESETS
    from simulators.simulation import simulate

    damage: list[tuple[str, dict]] = []
    skew = PRESETS["robot"].skew
    for h in hidden:
        if h.effect == "encoder_time_offset":
            skew += h.change
        elif h.effect == "encoder_offset":
            damage.append(("encoder_fault", {"joint": h.joint, "mode": "offset", "value": h.change}))
        elif h.effect == "encoder_scale":
            damage.append(("encoder_fault", {"joint": h.joint, "mode": "scale", "value": 1.0 + h.change}))
        else:
            damage.append(("backlash", {"joint": h.joint, "deg": float(np.degrees(h.change))}))
    rec = simulate(robot, seconds, seed, sensing=replace(PRESETS["robot"], skew=skew), damage=damage)
    t0 = time.process_time()
    rep = encoder_analysis(rec, robot)
    return rep, time.process_time() - t0


def draw_cases(
    null: EncoderReport, factors: list[float], pairs: int, triples: int, rng: np.random.Generator
) -> list[list[Hidden]]:
    """Each effect alone at every factor on a random joint that observes it, then random pairs and
    triples of effects on distinct joints at the first factor."""
    limits = _limits(null)

    def one(effect: str, factor: float, taken: set[str | None]) -> Hidden | None:
        return _draw(limits, effect, factor, taken, rng)

    cases: list[list[Hidden]] = []
    for f in factors:
        for e in ENCODER_EFFECTS:
            h = one(e, f, set())
            if h is not None:
                cases.append([h])
    for size, count in ((2, pairs), (3, triples)):
        for _ in range(count):
            effects = rng.choice(len(ENCODER_EFFECTS), size=size, replace=False)
            taken: set[str | None] = set()
            case = []
            for i in sorted(effects):
                h = one(ENCODER_EFFECTS[i], factors[0], taken)
                if h is not None:
                    case.append(h)
                    taken.add(h.joint)
            cases.append(case)
    return cases


def _limits(null: EncoderReport) -> dict[str, dict[str | None, float]]:
    """Per effect, each joint that observes it and the smallest change the null run could detect there."""
    limits: dict[str, dict[str | None, float]] = {e: {} for e in ENCODER_EFFECTS}
    for x in null.not_named:
        if x.observable:
            limits[x.effect][x.joint] = x.detection_limit
    for c in null.causes:  # named by the null: a change of it is judged by its own limit
        limits[c.effect][c.joint] = c.detection_limit
    return limits


def _draw(
    limits: dict[str, dict[str | None, float]],
    effect: str,
    factor: float,
    taken: set[str | None],
    rng: np.random.Generator,
) -> Hidden | None:
    """``effect`` at ``factor`` times its limit on a random joint not ``taken`` (None: none left)."""
    joints = [j for j in limits[effect] if j not in taken or j is None]
    if not joints:
        return None
    j = joints[int(rng.integers(len(joints)))]
    sign = 1.0 if effect == "backlash" else float(rng.choice([-1.0, 1.0]))
    return Hidden(effect, j, sign * factor * limits[effect][j], factor)


def score(rep: EncoderReport, null: EncoderReport, hidden: list[Hidden]) -> dict[str, object]:
    """Named, z (the value's distance from the null's plus the change, in combined standard errors)
    and within 3 sigma per hidden effect; the extra names."""
    per = []
    for h in hidden:
        c, base = rep.cause(h.name), null.cause(h.name)
        own, se0 = (
            (base.value, base.stderr)
            if base is not None and base.own_name == h.name
            else (ENCODER_NULL[h.effect], 0.0)
        )
        truth = own + h.change
        z = None
        if c is not None:
            factor = 1.0 if c.own_name == h.name else dict(c.alternatives)[h.name]
            value = ENCODER_NULL[h.effect] + factor * (c.value - ENCODER_NULL[c.effect])
            z = (value - truth) / float(np.hypot(abs(factor) * c.stderr, se0))
        per.append(
            {
                "name": h.name,
                "factor": h.factor,
                "change": h.change,
                "named": c is not None,
                "z": z,
                "within": z is not None and abs(z) <= 3.0,
            }
        )
    known = {n for c in null.causes for n in c.name.split(" or ")} | {h.name for h in hidden}
    extra = [c.name for c in rep.causes if not set(c.name.split(" or ")) & known]
    return {"hidden": per, "names": rep.names, "extra": extra}


def _recording(robot: str, seconds: float, seed: int, factors: list[float], pairs: int, triples: int) -> dict:
    null, cpu = analyze_case(robot, seconds, seed, [])
    rng = np.random.default_rng([seed, len(robot)])
    cases = []
    for hidden in draw_cases(null, factors, pairs, triples, rng):
        rep, c = analyze_case(robot, seconds, seed, hidden)
        cases.append({**score(rep, null, hidden), "cpu_s": round(c, 2)})
    return {
        "robot": robot,
        "seed": seed,
        "null": {
            "names": null.names,
            "causes": [c.to_json() for c in null.causes],
            "limits": {x.name: (x.detection_limit if x.observable else None) for x in null.not_named},
            "cpu_s": round(cpu, 2),
        },
        "cases": cases,
    }


def _rates(recordings: list[dict], factors: list[float]) -> dict:
    hidden = [(h, len(c["hidden"])) for r in recordings for c in r["cases"] for h in c["hidden"]]
    cpu = [r["null"]["cpu_s"] for r in recordings] + [c["cpu_s"] for r in recordings for c in r["cases"]]
    out: dict = {"by_factor": {}, "by_effect": {}}
    for f in factors:
        sel = [h for h, _ in hidden if h["factor"] == f]
        out["by_factor"][f"{f:g}"] = {
            "hidden": len(sel),
            "named": sum(h["named"] for h in sel),
            "named_within": sum(h["within"] for h in sel),
        }
        for e in ENCODER_EFFECTS:
            one = [h for h, n in hidden if h["factor"] == f and n == 1 and h["name"].startswith(e)]
            out["by_effect"][f"{e}@{f:g}"] = {
                "n": len(one),
                "named": sum(h["named"] for h in one),
                "within": sum(h["within"] for h in one),
            }
    out["cases"] = sum(len(r["cases"]) for r in recordings)
    out["cases_with_extra"] = sum(bool(c["extra"]) for r in recordings for c in r["cases"])
    out["null_extra"] = sum(
        len([n for n in r["null"]["names"] if n != "encoder_time_offset"]) for r in recordings
    )
    out["cpu_s"] = {"median": float(np.median(cpu)), "max": float(np.max(cpu))}
    return out


def summary(data: dict) -> list[str]:
    """The result in a few lines and the per-effect table (the bench file and the docs both show it)."""
    r, f = data["rates"], data["factors"]
    ff = r["by_factor"][f"{f[0]:g}"]
    share = ff["named_within"] / max(ff["hidden"], 1)
    robots = ", ".join(dict.fromkeys(x["robot"] for x in data["recordings"]))
    lines = [
        f"{len(data['recordings'])} simulated recordings ({robots}; {data['seconds']:g} s each, `robot` "
        f"sensing, MPU-6050 IMUs); every encoder effect hidden alone at "
        f"{' and '.join(f'{x:g}' for x in f)} times the recording's own detection limit for it, on a "
        f"random joint that observes it, plus random pairs and triples at {f[0]:g} times: {r['cases']} "
        "analyses besides the untouched recordings.",
        "",
        f"**At {f[0]:g}x the limit, {ff['named_within']} of {ff['hidden']} hidden effects "
        f"({100 * share:.1f} %) were named with their value within 3 sigma** ({ff['named']} named; "
        f"target {100 * TARGET:.0f} %: {'met' if share >= TARGET else 'missed'}). Names beyond the time "
        f"offset on the untouched recordings: {r['null_extra']}; cases with an extra name: "
        f"{r['cases_with_extra']} of {r['cases']}. CPU per analysis: median {r['cpu_s']['median']:.1f} s, "
        f"max {r['cpu_s']['max']:.1f} s.",
        "",
    ]
    rows = []
    for e in ENCODER_EFFECTS:
        lim = [
            v
            for rec in data["recordings"]
            for k, v in [*rec["null"]["limits"].items(), *_null_limits(rec)]
            if k.split("[")[0] == e and v is not None
        ]
        rows.append((e, lim, [r["by_effect"][f"{e}@{x:g}"] for x in f]))
    lines += detection_table(rows, f, "recordings and joints")
    unobservable = sorted(
        {
            f"{k} ({rec['robot']})"
            for rec in data["recordings"]
            for k, v in rec["null"]["limits"].items()
            if v is None
        }
    )
    lines += [
        "",
        "Not observable with these motions (no IMU reading changes): "
        + (", ".join(unobservable) or "none")
        + ".",
    ]
    return lines


def _null_limits(rec: dict) -> list[tuple[str, float]]:
    """The limits of the effects the null named (a change of them is judged by them)."""
    return [(c["name"], c["detection_limit"]) for c in rec["null"]["causes"]]


def _markdown(data: dict) -> str:
    lines = [
        "# Hidden encoder effects at multiples of their detection limit (simulated robots)",
        "",
        f"Command: `{data['command']}`. Machine: {data['machine']}.",
        "",
        *summary(data),
        "",
        "![sim2real-encoders](sim2real-encoders.png)",
        "",
    ]
    return "\n".join(lines)


def _plot(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    f = data["factors"]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    width = 0.8 / len(f)
    x = np.arange(len(ENCODER_EFFECTS))
    for i, fac in enumerate(f):
        cells = [data["rates"]["by_effect"][f"{e}@{fac:g}"] for e in ENCODER_EFFECTS]
        named = [c["within"] / max(c["n"], 1) for c in cells]
        ax.bar(x + i * width, named, width, label=f"{fac:g}x the limit")
    ax.axhline(TARGET, color="k", lw=0.8, ls="--", label=f"target {100 * TARGET:.0f} %")
    ax.set_xticks(x + width * (len(f) - 1) / 2, ENCODER_EFFECTS, fontsize=8)
    ax.set_ylabel("named, value within 3σ")
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("Hidden encoder effects, alone, on simulated robots")
    save_figure(fig, path)


def run(args: argparse.Namespace) -> Path:
    jobs = [
        (r, args.seconds, s, list(args.factors), args.pairs, args.triples)
        for r in args.robots
        for s in args.seeds
    ]
    recordings = map_jobs(_recording, jobs, args.jobs, "sim2real-encoders", "recording")
    argv = ["bodyhealth bench sim2real_encoders", "--robots", *args.robots, "--seeds", *map(str, args.seeds)]
    data = {
        "command": " ".join(argv),
        "machine": machine_note(),
        "seconds": args.seconds,
        "factors": list(args.factors),
        "recordings": recordings,
        "rates": _rates(recordings, list(args.factors)),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "sim2real-encoders.json"
    path.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    (out / "sim2real-encoders.md").write_text(_markdown(data), encoding="utf-8")
    _plot(data, out / "sim2real-encoders.png")
    for line in summary(data):
        print(line)
    return path
