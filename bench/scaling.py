"""How the CPU time of the ``fast`` topology estimator grows with joints, IMUs and samples.

Random kinematic trees (:mod:`simulators.kinematic_tree`: random hinge axes, IMU poses and smooth
joint motion, MPU-6050-like errors) at 100 Hz; one series varies the joints (1 IMU per link and one on
the base, 60 s), one the IMUs (10 joints, 60 s), one the samples (10 joints, 1 IMU per link). Each point
is the minimum CPU time over ``--repeats`` estimates on one thread (BLAS limited with threadpoolctl),
and whether the estimate was exact. Writes ``scaling.md``, ``scaling.json`` and ``scaling.png``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, machine_note
from bodyschema.progress import progress
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--joints", default="5,10,20,40", help="joint counts of the first series")
    parser.add_argument("--imus-per-link", default="1,2,4,8", help="IMUs per link (10 joints) of the second")
    parser.add_argument(
        "--seconds", default="10,30,60,120", help="recording lengths (10 joints) of the third"
    )
    parser.add_argument("--repeats", type=int, default=3, help="estimates per point; the minimum is kept")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _measure(n_joints: int, per_link: int, seconds: float, repeats: int, seed: int) -> dict:
    from bodyschema.estimate import estimate_topology
    from simulators.kinematic_tree import random_robot_recording

    rec = random_robot_recording(
        np.random.default_rng(seed), n_joints=n_joints, seconds=seconds, imus_per_link=(per_link, per_link)
    )
    cpu, exact = [], []
    for _ in range(repeats):
        topo = estimate_topology(rec, "fast", timer=time.process_time)
        cpu.append(topo.seconds)
        exact.append(topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map)
    return {
        "joints": n_joints,
        "imus": rec.n_imus,
        "samples": rec.n_samples,
        "cpu_s": min(cpu),
        "exact": all(exact),
    }


def run(args: argparse.Namespace) -> Path:
    from bodyschema.threads import blas_threads

    plan = (
        [("joints", n, 1, 60.0) for n in _ints(args.joints)]
        + [("imus", 10, k, 60.0) for k in _ints(args.imus_per_link)]
        + [("samples", 10, 1, float(s)) for s in _ints(args.seconds)]
    )
    series: dict[str, list[dict]] = {"joints": [], "imus": [], "samples": []}
    with blas_threads(1):
        for name, n, k, secs in progress(plan, desc="bench scaling", unit="point"):
            series[name].append(_measure(n, k, secs, args.repeats, args.seed))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling.json").write_text(
        json.dumps({"machine": machine_note(), "series": series}, indent=1) + "\n", encoding="utf-8"
    )
    _plot(series, out / "scaling.png")
    path = out / "scaling.md"
    path.write_text(_markdown(series, args), encoding="utf-8")
    return path


def _table(rows: list[dict], key: str, label: str) -> list[str]:
    return [
        f"| {label} | " + " | ".join(f"{r[key]:,}" for r in rows) + " |",
        "|---|" + "---|" * len(rows),
        "| CPU s | " + " | ".join(f"{r['cpu_s']:.3f}" for r in rows) + " |",
        "| exact | " + " | ".join("yes" if r["exact"] else "no" for r in rows) + " |",
        "",
    ]


def _slope(rows: list[dict], key: str) -> float:
    """Log-log slope of CPU time against ``key``: the exponent of the growth."""
    x = np.log([r[key] for r in rows])
    y = np.log([r["cpu_s"] for r in rows])
    return float(np.polyfit(x, y, 1)[0]) if len(rows) > 1 else float("nan")


def _markdown(series: dict[str, list[dict]], args: argparse.Namespace) -> str:
    lines = [
        "# Benchmark: how `fast` scales",
        "",
        f"`bodyhealth bench scaling --joints {args.joints} --imus-per-link {args.imus_per_link} "
        f"--seconds {args.seconds} --repeats {args.repeats} --seed {args.seed}`",
        "",
        f"Machine: {machine_note()}. One CPU thread; CPU time is the minimum over {args.repeats} "
        "estimates of one random robot per point (100 Hz, MPU-6050-like errors).",
        "",
    ]
    lines += ["## Joints (1 IMU per link, 60 s)", "", *_table(series["joints"], "joints", "joints N")]
    lines += ["## IMUs (10 joints, 60 s)", "", *_table(series["imus"], "imus", "IMUs K")]
    lines += [
        "## Samples (10 joints, 1 IMU per link)",
        "",
        *_table(series["samples"], "samples", "samples T"),
    ]
    lines += [
        "Growth exponents (log-log slope of CPU time): "
        f"joints {_slope(series['joints'], 'joints'):.2f}, IMUs {_slope(series['imus'], 'imus'):.2f}, "
        f"samples {_slope(series['samples'], 'samples'):.2f}.",
        "",
        "![scaling](scaling.png)",
        "",
    ]
    return "\n".join(lines)


def _plot(series: dict[str, list[dict]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (name, key) in zip(
        axes, (("joints", "joints"), ("imus", "imus"), ("samples", "samples")), strict=True
    ):
        rows = series[name]
        ax.loglog([r[key] for r in rows], [r["cpu_s"] for r in rows], "o-")
        ax.set_xlabel(key)
        ax.set_ylabel("CPU s (fast)")
        ax.set_title(f"slope {_slope(rows, key):.2f}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    save_figure(fig, path, dpi=100)
