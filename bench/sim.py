"""Simulation speed: samples per second of every catalog robot and of a 10-robot farm, × real time.

Measured side by side in one run, each with the MPU-6050 IMU model, the ``observable`` excitation
and 100 Hz sampling (physics at its own timestep, sensors read at the sample rate):

- each catalog robot alone, simulated in 1 s chunks;
- a farm of ``--farm-size`` paper robots (``paper-1`` … ``paper-6`` in turn) advanced in 0.1 s chunks
  (the granularity a live ingestor pulls) with the default 1 s read-ahead and without it, and in 1 s
  chunks.

"× real time" is simulated seconds per wall-clock second: a 10-robot farm at 20× produces ten robots'
data twenty times faster than the robots would. "IMU samples/s" counts one IMU's accelerometer and
gyro reading once.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, machine_note
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run"]

TARGET_FARM_X = 20.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per measurement")
    parser.add_argument("--farm-size", type=int, default=10, help="paper robots in the farm (default 10)")
    parser.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    parser.add_argument("--imu-model", default="mpu6050")
    parser.add_argument("--excitation", default="observable")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robots", nargs="*", default=None, help="catalog robots to time (default all)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _log(msg: str) -> None:
    print(f"[bench sim] {msg}", file=sys.stderr, flush=True)


def _time_robot(name: str, args: argparse.Namespace) -> dict[str, float]:
    from simulators.simulation import Simulation

    sim = Simulation(
        name, seed=args.seed, imu_model=args.imu_model, excitation=args.excitation, rate=args.rate
    )
    sim.advance(10)  # warm-up
    n = round(args.seconds * sim.rate)
    t0, c0 = time.perf_counter(), time.process_time()
    done = 0
    while done < n:
        k = min(int(sim.rate), n - done)
        sim.advance(k)
        done += k
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {
        "joints": sim.robot.n_joints,
        "imus": sim.robot.n_imus,
        "samples_per_s": n / wall,
        "imu_samples_per_s": n * sim.robot.n_imus / wall,
        "x_realtime": n / sim.rate / wall,
        "x_realtime_cpu": n / sim.rate / cpu,
        "warnings": sum(sim.robot.warnings().values()),
    }


def _time_farm(size: int, chunk: float, readahead: float, args: argparse.Namespace) -> dict[str, float]:
    from simulators.catalog import PAPER_TOPOLOGIES
    from simulators.farm import Farm

    papers = list(PAPER_TOPOLOGIES)
    robots = {
        f"{papers[i % len(papers)]}-{i // len(papers) + 1}": papers[i % len(papers)] for i in range(size)
    }
    farm = Farm(
        robots,
        seed=args.seed,
        imu_model=args.imu_model,
        excitation=args.excitation,
        rate=args.rate,
        readahead=readahead,
    )
    farm.advance(0.1)  # warm-up
    steps = max(1, round(args.seconds / chunk))
    samples = imu_samples = 0
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        for rec in farm.advance(chunk).values():
            samples += rec.n_samples
            imu_samples += rec.n_samples * rec.n_imus
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {
        "robots": size,
        "chunk": chunk,
        "readahead": readahead,
        "samples_per_s": samples / wall,
        "imu_samples_per_s": imu_samples / wall,
        "x_realtime": steps * chunk / wall,
        "x_realtime_cpu": steps * chunk / cpu,
    }


def _plot(path: Path, robots: dict[str, dict[str, float]], farms: list[dict[str, float]], note: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(robots) + [
        f"farm {int(f['robots'])} x paper\n{f['chunk']:g} s chunks, read-ahead {f['readahead']:g} s"
        for f in farms
    ]
    wall = [r["x_realtime"] for r in robots.values()] + [f["x_realtime"] for f in farms]
    cpu = [r["x_realtime_cpu"] for r in robots.values()] + [f["x_realtime_cpu"] for f in farms]
    x = np.arange(len(wall))
    fig, ax = plt.subplots(figsize=(11, 4.8))
    ax.bar(x - 0.2, wall, width=0.4, color="tab:blue", label="wall clock")
    ax.bar(x + 0.2, cpu, width=0.4, color="tab:orange", label="own CPU time")
    ax.axhline(TARGET_FARM_X, color="tab:red", ls="--", lw=1, label=f"farm target {TARGET_FARM_X:g}×")
    ax.set_xticks(x, labels, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("× real time (simulated s per wall s)")
    ax.set_yscale("log")
    ax.set_ylim(bottom=1.0)
    ax.set_title("Simulation speed (MPU-6050 IMU model, observable excitation, 100 Hz)")
    ax.legend()
    fig.text(0.01, 0.01, note, fontsize=7, color="gray")
    save_figure(fig, path, dpi=110)


def run(args: argparse.Namespace) -> Path:
    from bodyschema.progress import progress
    from simulators.catalog import CATALOG

    names = args.robots or list(CATALOG)
    unknown = [n for n in names if n not in CATALOG]
    if unknown:
        raise ValueError(f"unknown robots {unknown}")
    note = machine_note()
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    _log(f"{note}; load average {load}")
    robots: dict[str, dict[str, float]] = {}
    for name in progress(names, desc="robots", unit="robot", leave=True):
        robots[name] = _time_robot(name, args)
    farms = []
    for chunk, readahead in progress(
        ((0.1, 1.0), (0.1, 0.0), (1.0, 1.0)), desc="farm", unit="setting", leave=True
    ):
        farms.append(_time_farm(args.farm_size, chunk, readahead, args))

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md, png = out / "sim.md", out / "sim.png"
    lines = [
        "# bench sim: simulation speed",
        "",
        f"Machine: {note}",
        "",
        f"Settings: IMU model `{args.imu_model}`, excitation `{args.excitation}`, {args.rate:g} Hz, "
        f"{args.seconds:g} simulated s per row, seed {args.seed}. Command: `bodyhealth bench sim`.",
        "",
        f"Load average when it started: {load}. × real time is wall-clock based; the CPU column divides "
        "by the process's own CPU time instead (what the same code gives on an otherwise idle core).",
        "",
        "| robot | joints | IMUs | samples/s | IMU samples/s | × real time | × real time (CPU) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in robots.items():
        lines.append(
            f"| {name} | {r['joints']} | {r['imus']} | {r['samples_per_s']:,.0f} | "
            f"{r['imu_samples_per_s']:,.0f} | {r['x_realtime']:.0f}× | {r['x_realtime_cpu']:.0f}× |"
        )
    lines += [
        "",
        "| farm | robots | chunk | read-ahead | samples/s (all robots) | IMU samples/s "
        "| × real time | × real time (CPU) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for f in farms:
        ok = "meets" if f["x_realtime"] >= TARGET_FARM_X else "misses"
        lines.append(
            f"| paper robots | {f['robots']} | {f['chunk']:g} s | {f['readahead']:g} s | "
            f"{f['samples_per_s']:,.0f} | "
            f"{f['imu_samples_per_s']:,.0f} | {f['x_realtime']:.1f}× ({ok} {TARGET_FARM_X:g}×) | "
            f"{f['x_realtime_cpu']:.1f}× |"
        )
    lines += ["", "![simulation speed](sim.png)", ""]
    md.write_text("\n".join(lines), encoding="utf-8")
    _plot(png, robots, farms, note)
    print("\n".join(lines))
    return md
