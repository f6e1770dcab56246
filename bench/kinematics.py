"""Joint axes and IMU lever arms learned from random robots, against the truth and recording length.

Random MuJoCo trees (:mod:`simulators.random_robot`: random out-trees, random axes, one or two IMUs at
random surface poses per link) with ``--joints`` hinges, ``--robots`` of each size, simulated for the
longest of ``--seconds`` at 1 kHz, MPU-6050 IMU errors, then the realistic ``robot`` sensing preset
(:mod:`simulators.sensing`). Each recording's first S seconds, for every S in ``--seconds``, go through
the fast topology estimator and :func:`bodyschema.kinematics.estimate_kinematics`; the converged IMUs'
axes and lever arms are compared with the model's (:mod:`simulators.kinematics_truth`). The *gyro floor*
is the angle by which each IMU's drawn gyro sensitivity matrix turns its true axis: the part of the
axis error no estimate from that gyro alone can remove; the *gyro axis* is the axis the gyro reports
(``ImuKinematics.gyro_axis``), the *axis* the accelerometer-frame answer. *Within 2 std*: the share of
axes whose error is at most twice their reported ``axis_std_deg``. Writes ``kinematics.md``,
``kinematics.json`` and ``kinematics.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, fmt, machine_note, write_results
from bodyschema.progress import progress
from sim2real.figures import save_figure

__all__ = ["PUBLISHED", "TARGETS", "add_arguments", "run"]

#: Accuracy targets from 60 s of data: (median, max) axis error in degrees and lever-arm error in mm.
TARGETS = {"axis_deg": (0.5, 1.5), "lever_mm": (5.0, 15.0)}

#: Published figures the results are set beside (what each measured, on what).
PUBLISHED = (
    {"source": "Olsson et al. 2020", "what": "joint axes from IMU data", "axis_deg": 2.0, "lever_mm": None},
    {
        "source": "urdf_estimation_with_imus",
        "what": "IMU pose in a URDF",
        "axis_deg": 1.8,
        "lever_mm": 5.7,
    },
    {
        "source": "HIRO roboskin",
        "what": "IMU position on a real arm (mean)",
        "axis_deg": None,
        "lever_mm": 13.8,
    },
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--joints", default="5,10,15", help="joint counts of the random robots")
    parser.add_argument("--robots", type=int, default=3, help="random robots per joint count")
    parser.add_argument("--seconds", default="15,30,60", help="recording lengths compared, s")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))
    return float(np.degrees(np.arccos(c)))


def _robot_rows(n_joints: int, index: int, lengths: list[int], seed: int) -> list[dict]:
    from bodyschema.estimate import estimate_topology
    from bodyschema.kinematics import estimate_kinematics
    from simulators.kinematics_truth import axis_error_deg, kinematics_truth
    from simulators.random_robot import random_robot
    from simulators.sensing import apply_sensing
    from simulators.simulation import Simulation

    robot_ss, sim_ss, sense_ss = np.random.SeedSequence([seed, n_joints, index]).spawn(3)
    robot = random_robot(np.random.default_rng(robot_ss), n_joints, rate=1000.0)
    sim = Simulation(robot, seed=sim_ss, rate=1000.0, imu_model="mpu6050")
    fine = sim.advance(seconds=float(max(lengths)) + 0.5)
    full = apply_sensing(fine, "robot", np.random.default_rng(sense_ss))
    truth = kinematics_truth(robot)
    gyro = {name: sim.params.gyro_matrix[k] for k, name in enumerate(robot.imu_names)}
    rows = []
    for secs in lengths:
        rec = full.window(float(full.t[0]), float(full.t[0]) + secs)
        t0 = time.process_time()
        topo = estimate_topology(rec, method="fast")
        kin = estimate_kinematics(rec, topo)
        cpu = time.process_time() - t0
        axis, lever, floor, gyro_axis, z, conv, on_links = [], [], [], [], [], 0, 0
        for name, t in truth.items():
            if t.joint is None:
                continue
            on_links += 1
            k = kin.imus.get(name)
            if k is None or not k.converged or k.joint != t.joint:
                continue
            conv += 1
            axis.append(axis_error_deg(k.axis, t.axis))  # type: ignore[arg-type]
            z.append(axis[-1] / k.axis_std_deg)
            lever.append(1e3 * float(np.linalg.norm(k.lever_arm - t.lever_arm)))  # type: ignore[operator]
            floor.append(_angle(gyro[name] @ t.axis, t.axis))  # type: ignore[operator]
            gyro_axis.append(axis_error_deg(k.gyro_axis, t.axis))  # type: ignore[arg-type]
        rows.append(
            {
                "joints": n_joints,
                "robot": index,
                "seconds": secs,
                "imus_on_links": on_links,
                "converged": conv,
                "tree_exact": topo.joint_parent == rec.truth_parent_map
                and topo.imu_joint == rec.truth_imu_map,
                "axis_err_deg": [round(x, 4) for x in axis],
                "lever_err_mm": [round(x, 3) for x in lever],
                "gyro_floor_deg": [round(x, 4) for x in floor],
                "gyro_axis_err_deg": [round(x, 4) for x in gyro_axis],
                "axis_err_in_std": [round(x, 3) for x in z],
                "cpu_s": round(cpu, 3),
            }
        )
    return rows


def _summary(rows: list[dict], lengths: list[int]) -> list[dict]:
    out = []
    for secs in lengths:
        mine = [r for r in rows if r["seconds"] == secs]
        ax = [x for r in mine for x in r["axis_err_deg"]]
        lv = [x for r in mine for x in r["lever_err_mm"]]
        fl = [x for r in mine for x in r["gyro_floor_deg"]]
        sg = [x for r in mine for x in r["gyro_axis_err_deg"]]
        zs = [x for r in mine for x in r["axis_err_in_std"]]
        out.append(
            {
                "seconds": secs,
                "robots": len(mine),
                "imus_on_links": sum(r["imus_on_links"] for r in mine),
                "converged": sum(r["converged"] for r in mine),
                "trees_exact": sum(r["tree_exact"] for r in mine),
                "axis_median_deg": float(np.median(ax)) if ax else None,
                "axis_max_deg": float(np.max(ax)) if ax else None,
                "lever_median_mm": float(np.median(lv)) if lv else None,
                "lever_max_mm": float(np.max(lv)) if lv else None,
                "gyro_floor_median_deg": float(np.median(fl)) if fl else None,
                "gyro_floor_max_deg": float(np.max(fl)) if fl else None,
                "gyro_axis_median_deg": float(np.median(sg)) if sg else None,
                "gyro_axis_max_deg": float(np.max(sg)) if sg else None,
                "axis_within_2std": float(np.mean(np.asarray(zs) <= 2.0)) if zs else None,
                "cpu_s_median": float(np.median([r["cpu_s"] for r in mine])) if mine else None,
            }
        )
    return out


def run(args: argparse.Namespace) -> Path:
    from bodyschema.threads import blas_threads

    sizes, lengths = _ints(args.joints), sorted(_ints(args.seconds))
    plan = [(n, i) for n in sizes for i in range(args.robots)]
    rows: list[dict] = []
    with blas_threads(1):
        for n, i in progress(plan, desc="bench kinematics", unit="robot"):
            rows += _robot_rows(n, i, lengths, args.seed)
    summary = _summary(rows, lengths)
    command = (
        f"bodyhealth bench kinematics --joints {args.joints} --robots {args.robots} "
        f"--seconds {args.seconds} --seed {args.seed}"
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = {
        "machine": machine_note(),
        "command": command,
        "settings": {
            "joints": sizes,
            "robots_per_size": args.robots,
            "seconds": lengths,
            "imu_model": "mpu6050",
            "sensing": "robot",
            "seed": args.seed,
        },
        "targets": {k: list(v) for k, v in TARGETS.items()},
        "published": list(PUBLISHED),
        "summary": summary,
        "rows": rows,
    }
    return write_results(out, "kinematics", data, _markdown(data), lambda path: _plot(summary, path))


def _markdown(d: dict) -> str:
    s = d["settings"]
    lines = [
        "# Benchmark: joint axes and IMU lever arms",
        "",
        f"`{d['command']}`",
        "",
        f"Machine: {d['machine']}. Random trees of {', '.join(map(str, s['joints']))} joints, "
        f"{s['robots_per_size']} per size, MPU-6050 IMU errors, `robot` sensing preset (14-bit encoders "
        "at 250 Hz on their own clock, IMU at 100 Hz behind a 42 Hz low-pass, 8 ms skew, 30 ppm drift); "
        "the tree is the one the fast estimator learns from the same data. Errors are over the IMUs "
        "whose answer converged. *Axis*: the answer, in the accelerometer's frame; *gyro axis*: the axis "
        "the gyro reports; the gyro floor is the angle each IMU's own gyro sensitivity matrix turns its "
        "true axis by; *within 2 std*: the share of axes off by at most twice their reported std. CPU "
        "seconds: topology plus kinematics, one thread.",
        "",
        "| seconds | robots | converged / IMUs on links | trees exact | axis median ° | axis max ° "
        "| within 2 std | gyro axis median ° | gyro axis max ° | gyro floor median ° | lever median mm "
        "| lever max mm | CPU s (median) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["summary"]:
        lines.append(
            f"| {r['seconds']} | {r['robots']} | {r['converged']} / {r['imus_on_links']} | "
            f"{r['trees_exact']} | {fmt(r['axis_median_deg'], '.2f')} | {fmt(r['axis_max_deg'], '.2f')} | "
            f"{fmt(r['axis_within_2std'], '.0%')} | "
            f"{fmt(r['gyro_axis_median_deg'], '.2f')} | {fmt(r['gyro_axis_max_deg'], '.2f')} | "
            f"{fmt(r['gyro_floor_median_deg'], '.2f')} | "
            f"{fmt(r['lever_median_mm'], '.1f')} | {fmt(r['lever_max_mm'], '.1f')} | "
            f"{fmt(r['cpu_s_median'], '.2f')} |"
        )
    t = d["targets"]
    lines += [
        "",
        f"Targets from 60 s: axis median ≤ {t['axis_deg'][0]} ° (max {t['axis_deg'][1]} °), lever arm "
        f"median ≤ {t['lever_mm'][0]} mm (max {t['lever_mm'][1]} mm).",
        "",
        "Published figures, set beside (different robots, sensors and protocols):",
        "",
        "| source | what | axis ° | position mm |",
        "|---|---|---:|---:|",
    ]
    for p in d["published"]:
        lines.append(
            f"| {p['source']} | {p['what']} | {fmt(p['axis_deg'], '.1f')} | {fmt(p['lever_mm'], '.1f')} |"
        )
    lines += ["", "![kinematics](kinematics.png)", ""]
    return "\n".join(lines)


def _plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    secs = [r["seconds"] for r in summary]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    ax = axes[0]
    ax.plot(secs, [r["axis_median_deg"] for r in summary], "o-", label="median")
    ax.plot(secs, [r["axis_max_deg"] for r in summary], "s--", label="max")
    ax.plot(secs, [r["gyro_axis_median_deg"] for r in summary], ":", color="0.5", label="gyro axis median")
    ax.axhline(TARGETS["axis_deg"][0], color="tab:green", lw=0.8, label="target median")
    ax.set_xlabel("recording length, s")
    ax.set_ylabel("axis error, deg")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    ax = axes[1]
    ax.plot(secs, [r["lever_median_mm"] for r in summary], "o-", label="median")
    ax.plot(secs, [r["lever_max_mm"] for r in summary], "s--", label="max")
    ax.axhline(TARGETS["lever_mm"][0], color="tab:green", lw=0.8, label="target median")
    ax.set_xlabel("recording length, s")
    ax.set_ylabel("lever-arm error, mm")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    save_figure(fig, path, dpi=100)
