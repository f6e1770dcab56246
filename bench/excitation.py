"""Time to verdict: the planned excitation against the default random motion and one joint at a time.

Per robot (catalog robots and random trees of :mod:`simulators.random_robot`), three motions at the
same joint speed and acceleration limits (:func:`simulators.limits.robot_limits`: the model's ranges,
1 rad/s, 4 rad/s²), each starting from rest at the robot's home pose:

* ``planned``: :func:`bodyschema.excitation_plan.plan_excitation` with the robot's gyro joint sets;
* ``random``: the simulators' default excitation (:class:`simulators.excitation.Observable`, random
  smooth sinusoids), scaled per joint to use the same limits fully;
* ``one-at-a-time``: each joint alone in turn (:func:`bodyschema.excitation_plan.staggered_motion`).

Each runs on the simulated robot (the ``robot`` sensing preset: 1 kHz physics, 100 Hz IMUs behind an
MPU-6050 filter, 250 Hz 14-bit encoders, clock skew and drift) and the recording's growing prefixes
(from 2 s, 1 s apart at first, then every ``--step`` s: :func:`prefixes`) go through the fast
estimator; the time to verdict is the first prefix whose tree is unique and right, and, from there,
the first whose every IMU's axis and lever arm converged
(:func:`bodyschema.kinematics.estimate_kinematics`). A tree that is unique and wrong at any prefix is
counted (``wrong``). Writes ``excitation.json``, ``excitation.md`` and ``excitation.png``.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, fmt, machine_note, map_jobs

__all__ = ["MOTIONS", "add_arguments", "motion_plan", "prefixes", "run", "run_one"]

log = logging.getLogger(__name__)

MOTIONS = ("planned", "random", "one-at-a-time")
DEFAULT_ROBOTS = "paper-2,ur5e,quadruped,dual-arm,humanoid"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default=DEFAULT_ROBOTS, help="comma-separated catalog robots ('' none)")
    parser.add_argument("--trees", type=int, default=20, help="random trees")
    parser.add_argument("--joints", default="5-25", help="joints of a random tree, drawn from MIN-MAX")
    parser.add_argument("--seconds", type=float, default=60.0, help="longest motion evaluated, s")
    parser.add_argument("--step", type=float, default=5.0, help="prefix step, s")
    parser.add_argument(
        "--geometry-step",
        type=float,
        default=10.0,
        help="prefix step of the geometry (kinematics) verdict, s",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the trees, the motions and the noise")
    parser.add_argument("--workers", type=int, default=1, help="processes")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _robot(spec: tuple[str, int, int]) -> Any:
    from simulators.random_robot import random_robot
    from simulators.robot import Robot
    from simulators.sensing import resolve_sensing

    rate = resolve_sensing("robot").inner_rate
    kind, seed, n = spec
    if kind == "random":
        return random_robot(np.random.default_rng(seed), n, rate=rate)
    return Robot.from_catalog(kind, rate=rate)


def motion_plan(robot: Any, motion: str, seconds: float, seed: int) -> tuple[Any, float]:
    """The ``motion`` for ``robot`` as a plan within its limits, and the CPU seconds planning took."""
    from bodyschema.excitation_plan import (
        ExcitationPlan,
        PlanOptions,
        finite_differences,
        fit_to_limits,
        plan_excitation,
        staggered_motion,
    )
    from simulators.excitation import Observable
    from simulators.limits import robot_limits

    lim, q0 = robot_limits(robot), robot.q()
    opts = PlanOptions(seed=seed)
    cpu = time.process_time()
    if motion == "planned":
        truth = robot.truth()
        groups = [truth.ancestors(j) for j in truth.imu_joint.values() if j]
        return plan_excitation(lim, q0, seconds, groups=groups, options=opts), time.process_time() - cpu
    t = np.arange(round(seconds * opts.rate) + 1) / opts.rate
    lo = np.where(np.isfinite(lim.lower), lim.lower, q0 - opts.free_range)
    hi = np.where(np.isfinite(lim.upper), lim.upper, q0 + opts.free_range)
    if motion == "one-at-a-time":
        room = np.where(hi - q0 >= q0 - lo, 1.0, -1.0)
        shape = staggered_motion(t, len(q0), opts.segment, room, seconds)
    else:
        exc = Observable(ramp=1e-9).bind(robot, np.random.default_rng(seed))
        exc.center_ = q0.copy()  # about the start pose, as the others: from rest, no transfer move
        fine = np.arange(round(seconds * 1000) + 1) / 1000
        w = np.clip(fine / opts.ramp, 0, 1)
        w = 0.5 - 0.5 * np.cos(np.pi * w)  # from rest, as the others
        d = ((exc.targets(fine)[1] - q0) * w[:, None])[::10]
        # the motion clips at the joint ranges (kinks): scale by the written samples' own differences,
        # exactly what the limits are checked on
        v, a = finite_differences(d, opts.rate)
        shape = (d, np.vstack([v, v[-1:]]), np.vstack([a[:1], a, a[-1:]]))
    sub = type(lim)(lim.names, lo, hi, lim.velocity, lim.acceleration)
    k = fit_to_limits(t, shape, q0, sub, opts.margin)
    q = q0 + k * shape[0]
    plan = ExcitationPlan(lim.names, opts.rate, t, q, lim.names, motion, None, float("nan"))
    return plan, time.process_time() - cpu


def prefixes(seconds: float, step: float) -> list[float]:
    """Prefix lengths evaluated, s: fine while verdicts come fast (a 3× ratio needs resolution at a
    few seconds), then every ``step``."""
    early = [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0]
    late = np.arange(20.0 + step, seconds + 1e-9, step).tolist()
    return [p for p in early + late if p <= seconds + 1e-9]


def _decided(topo: Any) -> bool:
    from bodyschema.diff import undetermined_reasons, unplaced_reasons

    return not undetermined_reasons(topo) and not unplaced_reasons(topo)


def run_one(
    spec: tuple[str, int, int],
    motion: str,
    seconds: float,
    step: float,
    seed: int,
    geometry_step: float = 10.0,
) -> dict:
    """One robot and motion: simulate, then the verdicts on growing prefixes (the geometry, the costly
    one, once the tree is right and then only every ``geometry_step`` s)."""
    from bodyschema.estimate import estimate_topology
    from bodyschema.excitation_plan import check_limits
    from bodyschema.kinematics import estimate_kinematics
    from bodyschema.threads import blas_threads
    from simulators.limits import robot_limits
    from simulators.planned_motion import PlannedMotion
    from simulators.sensing import apply_sensing
    from simulators.simulation import Simulation

    robot = _robot(spec)
    plan, plan_cpu = motion_plan(robot, motion, seconds, seed)
    violations = len(check_limits(plan, robot_limits(robot)))
    sim = Simulation(robot, seed=seed, excitation=PlannedMotion(plan), rate=robot.rate)
    rec = apply_sensing(sim.advance(seconds=seconds), "robot", np.random.default_rng(seed))
    out: dict[str, Any] = {
        "robot": spec[0] if spec[0] != "random" else f"random-{spec[1]}",
        "joints": robot.n_joints,
        "imus": robot.n_imus,
        "motion": motion,
        "method": plan.method,
        "plan_cpu_s": plan_cpu,
        "violations": violations,
        "topology_s": None,
        "geometry_s": None,
        "wrong": 0,
        "prefixes": [],
    }
    with blas_threads(1):
        for p in prefixes(seconds, step):
            sub = rec.window(0.0, float(p))
            try:
                topo = estimate_topology(sub)
            except ValueError as err:  # too short for the timed path's band: no verdict yet
                out["prefixes"].append({"s": float(p), "error": str(err)})
                continue
            right = topo.joint_parent == sub.truth_parent_map and topo.imu_joint == sub.truth_imu_map
            decided = _decided(topo)
            out["wrong"] += int(decided and not right)
            row: dict[str, Any] = {"s": float(p), "decided": decided, "right": bool(right)}
            if decided and right and out["topology_s"] is None:
                out["topology_s"] = float(p)
            due = abs(p / geometry_step - round(p / geometry_step)) < 1e-9 or p >= seconds - 1e-9
            if out["topology_s"] is not None and due:
                kin = estimate_kinematics(sub, topo)
                conv = [k.converged for k in kin.imus.values() if k.joint is not None]
                row["converged"] = f"{sum(conv)}/{len(conv)}"
                if all(conv):
                    out["geometry_s"] = float(p)
            out["prefixes"].append(row)
            if out["geometry_s"] is not None:
                break
    return out


def _ratio(a: float | None, b: float | None, cap: float) -> float:
    """``a / b`` with a verdict never reached counted as ``cap`` (a bound, said so in the table)."""
    return (a if a is not None else cap) / (b if b is not None else cap)


def _summary(runs: list[dict], seconds: float) -> dict[str, Any]:
    by: dict[str, dict[str, dict]] = {}
    for r in runs:
        by.setdefault(r["robot"], {})[r["motion"]] = r
    rows, topo_ratio, geo_ratio, later = [], [], [], []
    for robot, m in by.items():
        if set(MOTIONS) - set(m):
            continue
        p, r, o = m["planned"], m["random"], m["one-at-a-time"]
        topo_ratio.append(_ratio(r["topology_s"], p["topology_s"], seconds))
        geo_ratio.append(_ratio(r["geometry_s"], p["geometry_s"], seconds))
        for key in ("topology_s", "geometry_s"):
            if (p[key] or np.inf) > (o[key] or np.inf):
                later.append(f"{robot} ({key[:-2]})")
        rows.append((robot, p, r, o))
    return {
        "robots": len(rows),
        "median_topology_ratio": statistics.median(topo_ratio) if topo_ratio else None,
        "median_geometry_ratio": statistics.median(geo_ratio) if geo_ratio else None,
        "planned_later_than_one_at_a_time": later,
        "wrong": sum(r["wrong"] for r in runs),
        "violations": sum(r["violations"] for r in runs),
        "plan_cpu_s_max": max((r["plan_cpu_s"] for r in runs if r["motion"] == "planned"), default=None),
        "rows": rows,
    }


def _markdown(runs: list[dict], s: dict[str, Any], args: argparse.Namespace, cpu: float) -> str:
    cell = lambda x: fmt(x, "g") if x is not None else f">{args.seconds:g}"  # noqa: E731
    robots = args.robots or "''"
    lines = [
        "# Excitation: time to verdict",
        "",
        f"`bodyhealth bench excitation --robots {robots} --trees {args.trees} --joints {args.joints} "
        f"--seconds {args.seconds:g} --step {args.step:g} --seed {args.seed}`; {cpu / 60:.1f} CPU minutes. "
        f"Machine: {machine_note()}. `robot` sensing preset; limits 1 rad/s, 4 rad/s², the models' ranges.",
        "",
        "Seconds of motion until the tree is unique and right (topology) and until every IMU's axis and "
        "lever arm converged (geometry), at prefixes of 2, 3, 4, 5, 6, 8, 10, 12, 15, 20 s and then "
        f"every {args.step:g} s (the geometry every {args.geometry_step:g} s); `>{args.seconds:g}`: not "
        "within the motion evaluated (counted as that bound in the ratios, which are then lower bounds).",
        "",
        "| robot | joints | planned (method) | random | one at a time | planning CPU s |",
        "|---|---|---|---|---|---|",
    ]
    for robot, p, r, o in s["rows"]:
        lines.append(
            f"| {robot} | {p['joints']} | {cell(p['topology_s'])} / {cell(p['geometry_s'])} "
            f"({p['method']}) | "
            f"{cell(r['topology_s'])} / {cell(r['geometry_s'])} | {cell(o['topology_s'])} / "
            f"{cell(o['geometry_s'])} | {p['plan_cpu_s']:.2f} |"
        )
    later = ", ".join(s["planned_later_than_one_at_a_time"]) or "none"
    lines += [
        "",
        "Cells: topology / geometry seconds.",
        "",
        f"- median over robots, random ÷ planned: topology {fmt(s['median_topology_ratio'])}×, geometry "
        f"{fmt(s['median_geometry_ratio'])}× (targets: ≥ 3× and ≥ 2×)",
        f"- planned later than one joint at a time: {later}",
        f"- confidently wrong trees (unique and wrong) at any prefix evaluated: {s['wrong']}",
        f"- samples of any plan beyond a position, velocity or acceleration limit: {s['violations']}",
        f"- most CPU seconds one plan took: {fmt(s['plan_cpu_s_max'])}",
        "",
    ]
    return "\n".join(lines)


def _plot(s: dict[str, Any], path: Path, seconds: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    x = np.arange(len(s["rows"]))
    for ax, key, title in (
        (axes[0], "topology_s", "unique and right tree"),
        (axes[1], "geometry_s", "geometry converged"),
    ):
        for i, (motion, color) in enumerate(zip(MOTIONS, ("tab:green", "tab:red", "tab:blue"), strict=True)):
            vals = [row[1 + i][key] for row in s["rows"]]
            bars = ax.bar(
                x + (i - 1) * 0.27, [v or seconds for v in vals], width=0.27, color=color, label=motion
            )
            for bar, v in zip(bars, vals, strict=True):
                if v is None:  # not reached within the motion: hatched, at the bound
                    bar.set_hatch("//")
                    bar.set_alpha(0.4)
        ax.axhline(seconds, color="grey", lw=0.8, ls="--")
        ax.set_xticks(x, [row[0] for row in s["rows"]], rotation=60, fontsize=7)
        ax.set_ylabel("seconds of motion")
        ax.set_title(f"{title} (hatched: not within {seconds:g} s)", fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def run(args: argparse.Namespace) -> Path:
    cpu = time.process_time()
    rng = np.random.default_rng(args.seed)
    specs = [(r, 0, 0) for r in args.robots.split(",") if r]
    lo, hi = (int(x) for x in args.joints.split("-"))
    specs += [("random", int(args.seed * 1000 + i), int(rng.integers(lo, hi + 1))) for i in range(args.trees)]
    if not specs:
        raise ValueError("no robots: give --robots or --trees")
    jobs = [(sp, m, args.seconds, args.step, args.seed, args.geometry_step) for sp in specs for m in MOTIONS]
    runs = map_jobs(run_one, jobs, args.workers, "bench excitation", "run")
    cpu = time.process_time() - cpu
    s = _summary(runs, args.seconds)
    data = {
        "machine": machine_note(),
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "func"},
        "summary": {k: v for k, v in s.items() if k != "rows"},
        "runs": runs,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "excitation.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    _plot(s, out / "excitation.png", args.seconds)
    path = out / "excitation.md"
    path.write_text(_markdown(runs, s, args, cpu), encoding="utf-8")
    return path
