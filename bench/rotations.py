"""Rotations between IMUs, and what one recording leaves open about them.

:func:`bodyschema.kinematics.estimate_kinematics` reports, besides each joint's axis and each IMU's
lever arm, the rotation from the parent IMU's frame (``rotation_from_parent``) and between IMUs on one
link (``same_link``). Under a parent link that turned about one axis only (a root joint on a fixed
base), a child's turn about that axis trades with the joint's position about it, and only gravity
across the axis tells it: the answer carries that turn's std and, above ``max_axis_std_deg``, is
reported ``undetermined``; two gyros on such a link do not fix their rotation about its axis
(``SameLink.rank`` 1). This bench checks that the split is right: every catalog robot in ``--robots``
runs ``--seeds`` recordings of ``--seconds`` at 1 kHz, MPU-6050 IMU errors, ``robot`` sensing preset,
estimated on the true tree (learning it is the topology bench's subject), and every rotation is
compared with the simulator's relative site pose (:mod:`simulators.kinematics_truth`).

Per robot: the rotations from the parent reported determined (count, largest error) and undetermined
(count, smallest and largest error, their turn stds); the same-link rotations at rank 2 or more (count,
largest error, the share within twice their std) and at rank 1. Writes ``rotations.json``,
``rotations.md`` and ``rotations.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, fmt, machine_note, map_jobs, write_results
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run", "summary"]

_ROBOTS = "ur5e,quadruped,humanoid,dual-arm,paper-1,paper-2,paper-3,paper-4,paper-5,paper-6"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default=_ROBOTS, help="catalog robots")
    parser.add_argument("--seeds", type=int, default=2, help="recordings per robot (seeds 0..N-1)")
    parser.add_argument("--seconds", type=float, default=30.0, help="recording length, s")
    parser.add_argument("--workers", type=int, default=1, help="processes, one recording each")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _recording(robot_name: str, seed: int, seconds: float) -> dict:
    """One recording's rotations against the truth (module docstring)."""
    from bodyschema.kinematics import estimate_kinematics
    from bodyschema.threads import blas_threads
    from bodyschema.topology import Topology
    from simulators.kinematics_truth import rotation_from_parent_error_deg, same_link_error_deg
    from simulators.robot import Robot
    from simulators.sensing import apply_sensing
    from simulators.simulation import Simulation

    robot = Robot.from_catalog(robot_name, rate=1000.0)
    sim = Simulation(robot, seed=seed, rate=1000.0, imu_model="mpu6050")
    rec = apply_sensing(sim.advance(seconds=seconds), "robot", np.random.default_rng(seed + 1000))
    topo = Topology(joint_parent=rec.truth_parent_map, imu_joint=rec.truth_imu_map)  # type: ignore[arg-type]
    cpu0 = time.process_time()
    with blas_threads(1):
        kin = estimate_kinematics(rec, topo)
    cpu = time.process_time() - cpu0
    parents = [
        {
            "imu": k.imu,
            "parent_rank": k.parent_rank,
            "error_deg": round(rotation_from_parent_error_deg(robot, k), 3),
            "turn_std_deg": None
            if np.isnan(k.turn_about_parent_std_deg)
            else round(k.turn_about_parent_std_deg, 4),
            "undetermined": bool(k.undetermined),
        }
        for k in kin.imus.values()
        if k.rotation_from_parent is not None
    ]
    same = [
        {
            "imus": [s.a, s.b],
            "rank": s.rank,
            "error_deg": round(same_link_error_deg(robot, s), 3),
            "std_deg": None if not np.isfinite(s.std_deg) else round(s.std_deg, 4),
            "noise_std_deg": None if not np.isfinite(s.noise_std_deg) else round(s.noise_std_deg, 4),
        }
        for s in kin.same_link
    ]
    return {
        "robot": robot_name,
        "seed": seed,
        "from_parent": parents,
        "same_link": same,
        "cpu_s": round(cpu, 1),
    }


def summary(rows: list[dict]) -> list[dict]:
    """Per robot, over its recordings: the counts and extremes the table shows."""
    out = []
    for name in dict.fromkeys(r["robot"] for r in rows):
        mine = [r for r in rows if r["robot"] == name]
        det = [x for r in mine for x in r["from_parent"] if not x["undetermined"]]
        und = [x for r in mine for x in r["from_parent"] if x["undetermined"]]
        fixed = [x for r in mine for x in r["same_link"] if x["rank"] >= 2]
        loose = [x for r in mine for x in r["same_link"] if x["rank"] < 2]

        def most(xs: list[dict], key: str, f=max) -> float | None:
            vals = [x[key] for x in xs if x[key] is not None]
            return f(vals) if vals else None

        out.append(
            {
                "robot": name,
                "recordings": len(mine),
                "determined": len(det),
                "determined_max_deg": most(det, "error_deg"),
                "determined_turn_std_max_deg": most(det, "turn_std_deg"),
                "undetermined": len(und),
                "undetermined_min_deg": most(und, "error_deg", min),
                "undetermined_max_deg": most(und, "error_deg"),
                "undetermined_turn_std_min_deg": most(und, "turn_std_deg", min),
                "same_link_fixed": len(fixed),
                "same_link_fixed_max_deg": most(fixed, "error_deg"),
                "same_link_fixed_within_2std": (
                    round(float(np.mean([x["error_deg"] <= 2.0 * x["std_deg"] for x in fixed])), 4)
                    if fixed
                    else None
                ),
                "same_link_rank1": len(loose),
                "cpu_s": round(sum(r["cpu_s"] for r in mine), 1),
            }
        )
    return out


def run(args: argparse.Namespace) -> Path:
    robots = [x.strip() for x in args.robots.split(",") if x.strip()]
    jobs = [(r, s, float(args.seconds)) for r in robots for s in range(args.seeds)]
    rows = map_jobs(_recording, jobs, args.workers, "bench rotations", "recording")
    data = {
        "machine": machine_note(),
        "command": (
            f"bodyhealth bench rotations --robots {args.robots} --seeds {args.seeds} "
            f"--seconds {args.seconds:g}"
        ),
        "settings": {
            "robots": robots,
            "seeds": args.seeds,
            "seconds": args.seconds,
            "imu_model": "mpu6050",
            "sensing": "robot",
        },
        "summary": summary(rows),
        "rows": rows,
    }
    return write_results(args.out, "rotations", data, _markdown(data), lambda p: _plot(rows, p))


def _markdown(d: dict) -> str:
    s = d["settings"]
    lines = [
        "# Benchmark: rotations between IMUs, and what a recording leaves open",
        "",
        f"`{d['command']}`",
        "",
        f"Machine: {d['machine']}. Each robot: {s['seeds']} recordings of {s['seconds']:g} s, MPU-6050 IMU "
        "errors, `robot` sensing preset, geometry on the true tree, in the accelerometers' frame. Errors "
        "are rotation angles against the simulator's relative site poses. *From the parent*: "
        "`rotation_from_parent`, reported determined or, where its turn about a one-axis parent's axis "
        "has a std above 1°, undetermined. *Same link*: the gyros' rotation between two IMUs on a link, "
        "fixed where the link turned about two axes or more (rank ≥ 2); at rank 1 its turn about the "
        "link's axis is left open; its std holds the gyros' cross-axis errors.",
        "",
        "| robot | determined | max error ° | undetermined | their errors ° | their turn std ° (min) "
        "| same link, rank ≥ 2 | max error ° | within 2 std | same link, rank 1 | CPU s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["summary"]:
        span = (
            "—"
            if not r["undetermined"]
            else f"{fmt(r['undetermined_min_deg'], '.1f')}–{fmt(r['undetermined_max_deg'], '.1f')}"
        )
        lines.append(
            f"| {r['robot']} | {r['determined']} | {fmt(r['determined_max_deg'])} | {r['undetermined']} | "
            f"{span} | {fmt(r['undetermined_turn_std_min_deg'])} | {r['same_link_fixed']} | "
            f"{fmt(r['same_link_fixed_max_deg'])} | {fmt(r['same_link_fixed_within_2std'], '.0%')} | "
            f"{r['same_link_rank1']} | {r['cpu_s']:.0f} |"
        )
    lines += ["", "![rotations](rotations.png)", ""]
    return "\n".join(lines)


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [x for r in rows for x in r["from_parent"] if x["turn_std_deg"] is not None]
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for flag, color, label in ((False, "tab:blue", "determined"), (True, "tab:red", "undetermined")):
        xs = [max(x["turn_std_deg"], 1e-4) for x in pts if x["undetermined"] is flag]
        ys = [max(x["error_deg"], 1e-3) for x in pts if x["undetermined"] is flag]
        ax.scatter(xs, ys, s=14, color=color, label=f"{label} ({len(xs)})")
    ax.axvline(1.0, color="0.4", lw=0.8, ls="--", label="max_axis_std_deg")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("std of the turn about the one-axis parent's axis, deg")
    ax.set_ylabel("rotation_from_parent error, deg")
    ax.set_title("Children of one-axis parents: error against stated turn std")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3, which="both")
    save_figure(fig, path)
