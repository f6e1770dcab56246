"""Warm against cold sensor-network training on the same window: cost and answer.

Per catalog robot, simulated on the ``robot`` sensing preset (encoder positions only, quantized, on
their own clock, low-passed IMU) for two consecutive windows: the networks are trained cold on the
first; on the second, once cold and once warm from the first window's weights (what the service's
retrains do, :mod:`service.store.weights`). Each robot runs once healthy and once with each of
``--damages`` applied at the start of the second window (the warm start then begins from the body
before the damage: it must learn the damaged one, as the cold run does). Per run: CPU seconds (one
thread) and epochs of both runs on the second window, whether the warm run gives the cold run's
tree (IMU placement and joint parents, read from the dependency matrix), and both answers against
the simulator's truth.

Writes ``warmstart.json``, ``warmstart.md`` and ``warmstart.png`` (CPU of warm against cold).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note, process_pool
from bodyschema.progress import progress

__all__ = ["TARGET_RATIO", "add_arguments", "run"]

#: The most a warm retrain may cost, as a share of a cold one on the same window.
TARGET_RATIO = 0.2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--robots", default="paper-1,paper-3,ur5e,quadruped", help="catalog robots, comma-separated"
    )
    parser.add_argument("--window", type=float, default=30.0, help="seconds per window")
    parser.add_argument(
        "--damages", default="imu_moved", help="damages applied between the windows, comma-separated"
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation seed (the networks use seed 1)")
    parser.add_argument("--jobs", type=int, default=2, help="robots trained in parallel")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _robot(job: dict[str, Any]) -> dict[str, Any]:
    """One robot: cold on window 1, cold and warm on window 2 (runs in a worker process)."""
    from bodyschema.estimate import fit_topology
    from bodyschema.threads import blas_threads, set_torch_threads
    from simulators.simulation import simulate

    set_torch_threads(1)
    w = job["window"]
    damage = f"{job['damage']}:at={w:g}" if job["damage"] else None
    rec = simulate(job["robot"], seconds=2 * w, seed=job["seed"], sensing="robot", damage=damage)
    first, second = rec.select(rec.t < w), rec.select(rec.t >= w)
    truth = (rec.truth_parent_map, rec.truth_imu_map)  # the body of the second window
    out: dict[str, Any] = {
        "robot": job["robot"],
        "damage": job["damage"] or "none",
        "joints": rec.n_joints,
        "imus": rec.n_imus,
    }
    with blas_threads(1):
        before = fit_topology(first, "network", seed=1)
        runs = {}
        for name, start in (("cold", None), ("warm", before.weights)):
            c0 = time.process_time()
            fit = fit_topology(second, "network", seed=1, warm_start=start)
            cpu = time.process_time() - c0
            topo = fit.topology
            runs[name] = fit
            out[name] = {
                "cpu_s": round(cpu, 2),
                "epochs": int(topo.training["epochs"]),
                "converged": bool(topo.training["converged"]),
                "warm": bool(topo.training["warm"]),
                "loss": round(float(topo.training.get("loss", float("nan"))), 5),
                "exact": (topo.joint_parent, topo.imu_joint) == truth,
            }
    c, wm = runs["cold"].topology, runs["warm"].topology
    out["same_tree"] = (c.joint_parent, c.imu_joint) == (wm.joint_parent, wm.imu_joint)
    out["ratio"] = round(out["warm"]["cpu_s"] / max(out["cold"]["cpu_s"], 1e-9), 3)
    return out


def _markdown(data: dict[str, Any]) -> str:
    rows = data["robots"]
    lines = [
        "# Warm against cold sensor-network training",
        "",
        f"Machine: {data['machine']}. Command: `{data['command']}`. Networks on one thread, seed 1;",
        f"two {data['window']:g} s windows per robot, `robot` sensing. Target: a warm retrain costs at most "
        f"{TARGET_RATIO:.0%} of a cold one on the same window, with the same tree.",
        "",
        "| robot | damage | joints | IMUs | cold CPU s | cold epochs | warm CPU s | warm epochs | warm/cold"
        " | same tree | cold exact | warm exact |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cold, warm = r["cold"], r["warm"]
        lines.append(
            f"| {r['robot']} | {r['damage']} | {r['joints']} | {r['imus']} | "
            f"{cold['cpu_s']:.1f} | {cold['epochs']} | "
            f"{warm['cpu_s']:.1f} | {warm['epochs']} | {r['ratio']:.2f} | {r['same_tree']} | "
            f"{cold['exact']} | {warm['exact']} |"
        )
    s = data["summary"]
    lines += [
        "",
        f"Median warm/cold CPU: {s['median_ratio']:.2f} (max {s['max_ratio']:.2f}); same tree on "
        f"{s['same_tree']} of {len(rows)} runs; target {'met' if s['meets_target'] else 'NOT met'}.",
        "",
        "![warm against cold](warmstart.png)",
        "",
    ]
    return "\n".join(lines)


def _plot(data: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    rows = data["robots"]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["cold"]["cpu_s"] for r in rows], 0.4, label="cold")
    ax.bar(x + 0.2, [r["warm"]["cpu_s"] for r in rows], 0.4, label="warm")
    ax.set_xticks(x, [f"{r['robot']}\n{r['damage']}" for r in rows], fontsize=7)
    ax.set_ylabel("CPU s (one thread)")
    ax.set_title("network retrain on the second window")
    ax.legend()
    save_figure(fig, path)


def run(args: argparse.Namespace) -> Path:
    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    damages = [None, *(d.strip() for d in args.damages.split(",") if d.strip())]
    jobs = [
        {"robot": r, "window": args.window, "seed": args.seed, "damage": d} for r in robots for d in damages
    ]
    rows: list[dict[str, Any]] = []
    with process_pool(args.jobs) as pool:
        bar = progress(total=len(jobs), desc="warm start", unit="robot")
        for row in pool.map(_robot, jobs):
            rows.append(row)
            bar.update(1)
        bar.close()
    ratios = [r["ratio"] for r in rows]
    summary = {
        "median_ratio": float(np.median(ratios)),
        "max_ratio": float(np.max(ratios)),
        "same_tree": sum(r["same_tree"] for r in rows),
        "meets_target": bool(max(ratios) <= TARGET_RATIO and all(r["same_tree"] for r in rows)),
    }
    command = (
        f"bodyhealth bench warmstart --robots {args.robots} --damages {args.damages} "
        f"--window {args.window:g} --seed {args.seed}"
    )
    data = {
        "machine": machine_note(),
        "command": command,
        "window": args.window,
        "robots": rows,
        "summary": summary,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "warmstart.json").write_text(json.dumps(data, indent=1) + "\n")
    (out / "warmstart.md").write_text(_markdown(data))
    _plot(data, out / "warmstart.png")
    print(_markdown(data))
    return out / "warmstart.md"
