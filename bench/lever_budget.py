"""What makes one window's lever arms scatter: the IMU model's effects taken out one at a time.

The service judges a slide of an IMU on its link against the scatter of its lever arm between healthy
windows (:mod:`bodyschema.lever_pool`), so that scatter sets the smallest slide it can find. This
bench splits it by cause. One catalog robot (``--robot``) runs on a simulated farm, ``robot`` sensing
preset, for ``--windows`` windows of ``--window-s``; each window's geometry is estimated as the worker
estimates it (:func:`bench.drift.window_tree`: the tree of the first window, the timing of each), in
the gyros' frame and in the accelerometers', and every IMU's lever arm is compared with the model's
(:mod:`simulators.kinematics_truth`). The same robot, seed and motion run under each condition:

* the MPU-6050 model (:data:`simulators.imu_model.PRESETS`) as the farm uses it;
* that model without one of its effects (gyro sensitivity, accelerometer gains, biases, noise,
  quantization), or with its noise only, or an ideal IMU;
* the MPU-6050 on ideal sensing (exact encoder velocities, one clock, no on-chip filter): the sensing
  preset's share.

Per IMU and frame: *scatter*, the RMS distance of the window's lever arm from the mean of the windows
(mm); *stated*, the median of the std each window states (``lever_arm_std_m``); *bias*, the distance of
that mean from the truth; *lag-one correlation* of the errors between consecutive windows. Writes
``lever-budget.json``, ``lever-budget.md`` and ``lever-budget.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note, map_jobs, write_results
from sim2real.figures import save_figure

__all__ = ["CONDITIONS", "add_arguments", "run"]

#: Conditions, in the order of the tables: (IMU model: None for the MPU-6050, or the effects it keeps
#: (``+``) or drops (``-``); sensing preset).
CONDITIONS: dict[str, tuple[str | None, str]] = {
    "MPU-6050": (None, "robot"),
    "without gyro_scale": ("-gyro_scale", "robot"),
    "without acc_scale": ("-acc_scale", "robot"),
    "without gyro_bias": ("-gyro_bias", "robot"),
    "without acc_bias": ("-acc_bias", "robot"),
    "without noise": ("-noise", "robot"),
    "without quantization": ("-quantization", "robot"),
    "noise only": ("+noise", "robot"),
    "ideal IMU": ("+", "robot"),
    "MPU-6050 on ideal sensing": (None, "ideal"),
}

#: The conditions the plot shows.
_PLOTTED = ("MPU-6050", "without gyro_scale", "noise only", "ideal IMU")

_FRAMES = {"gyro": False, "accelerometer": True}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="ur5e", help="catalog robot")
    parser.add_argument("--windows", type=int, default=20, help="windows per condition")
    parser.add_argument("--window-s", type=float, default=30.0, help="window length, s")
    parser.add_argument("--conditions", default=",".join(CONDITIONS), help="conditions run (default: all)")
    parser.add_argument("--workers", type=int, default=1, help="processes, one condition each")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _imu_model(spec: str | None) -> Any:
    """The MPU-6050 model, or the one ``spec`` keeps ("+noise", "+": none) or drops ("-gyro_scale")."""
    from simulators.imu_model import PRESETS, ImuModel

    full = PRESETS["mpu6050"]
    if spec is None:
        return full
    names = {x for x in spec[1:].split(",") if x}
    keep = [e for e in full.effects if (e[0] in names) == (spec[0] == "+")]
    return ImuModel(name=f"mpu6050 {spec}", effects=tuple(keep))


def _condition(label: str, robot: str, windows: int, seconds: float, seed: int) -> dict:
    """Every IMU's lever-arm scatter, stated std and bias (:func:`_stats`) in both frames."""
    from bench.drift import Watch
    from bodyschema.kinematics import KinematicsOptions, estimate_kinematics
    from bodyschema.threads import blas_threads
    from simulators.farm import Farm
    from simulators.kinematics_truth import kinematics_truth
    from simulators.robot import Robot

    spec, sensing = CONDITIONS[label]
    truth = kinematics_truth(Robot.from_catalog(robot))
    farm = Farm({"r": robot}, seed=seed, imu_model=_imu_model(spec), sensing=sensing)
    out: dict = {frame: {} for frame in _FRAMES}
    cpu0 = time.process_time()
    watch = Watch(farm)
    with blas_threads(1):
        for _ in range(windows):
            rec = farm.advance(seconds)["r"]
            topo = watch.tree_of(rec)  # one tree, both frames
            for frame, acc in _FRAMES.items():
                kin = estimate_kinematics(rec, topo, KinematicsOptions(accelerometer_frame=acc))
                for name, k in kin.imus.items():
                    true = truth[name].lever_arm
                    if k.lever_arm is None or true is None or truth[name].joint != k.joint:
                        continue
                    rows = out[frame].setdefault(name, {"error_mm": [], "stated_mm": []})
                    rows["error_mm"].append([round(float(x), 4) for x in (k.lever_arm - true) * 1e3])
                    rows["stated_mm"].append(round(float(k.lever_arm_std_m) * 1e3, 4))
    lever = {n: float(np.linalg.norm(t.lever_arm)) * 1e3 for n, t in truth.items() if t.lever_arm is not None}
    return {
        "label": label,
        "frames": {
            f: {n: _stats(v) | {"lever_arm_mm": round(lever[n], 1)} for n, v in d.items()}
            for f, d in out.items()
        },
        "cpu_s": round(time.process_time() - cpu0, 1),
    }


def _stats(rows: dict) -> dict:
    e = np.asarray(rows["error_mm"], dtype=float)
    dev = e - e.mean(axis=0)
    lag = [
        float(np.corrcoef(dev[:-1, i], dev[1:, i])[0, 1])
        for i in range(3)
        if len(dev) > 2 and dev[:, i].std() > 1e-9
    ]
    return {
        "windows": len(e),
        "scatter_mm": round(float(np.sqrt(np.mean(np.sum(dev**2, axis=1)))), 2),
        "stated_mm": round(float(np.median(rows["stated_mm"])), 2),
        "bias_mm": round(float(np.linalg.norm(e.mean(axis=0))), 2),
        "worst_mm": round(float(np.linalg.norm(dev, axis=1).max()), 2),
        "lag_one": round(float(np.mean(lag)), 2) if lag else None,
    }


def run(args: argparse.Namespace) -> Path:
    labels = [x.strip() for x in args.conditions.split(",") if x.strip()]
    unknown = sorted(set(labels) - set(CONDITIONS))
    if unknown:
        raise SystemExit(
            f"bench lever_budget: unknown conditions {unknown}; the conditions are {list(CONDITIONS)}"
        )
    if args.windows < 3:
        raise SystemExit("bench lever_budget: --windows must be at least 3 (a scatter needs them)")
    jobs = [(label, args.robot, args.windows, args.window_s, args.seed) for label in labels]
    results = map_jobs(_condition, jobs, args.workers, desc="bench lever_budget", unit="condition")
    command = (
        f"bodyhealth bench lever_budget --robot {args.robot} --windows {args.windows} "
        f"--window-s {args.window_s:g} --seed {args.seed}"
        + ("" if labels == list(CONDITIONS) else f" --conditions '{','.join(labels)}'")
    )
    data = {
        "machine": machine_note(),
        "command": command,
        "robot": args.robot,
        "window_s": args.window_s,
        "conditions": {r["label"]: {"frames": r["frames"], "cpu_s": r["cpu_s"]} for r in results},
    }
    return write_results(args.out, "lever-budget", data, _markdown(data), lambda path: _plot(data, path))


def summary(cond: dict, frame: str) -> dict:
    """Median and largest scatter, median stated std and bias over the IMUs of one condition and frame."""
    rows = list(cond["frames"][frame].values())
    sc = [r["scatter_mm"] for r in rows]
    return {
        "scatter_median_mm": float(np.median(sc)),
        "scatter_max_mm": float(np.max(sc)),
        "stated_median_mm": float(np.median([r["stated_mm"] for r in rows])),
        "understated": sum(r["scatter_mm"] > 2.0 * r["stated_mm"] for r in rows),
        "imus": len(rows),
        "bias_median_mm": float(np.median([r["bias_mm"] for r in rows])),
        "bias_max_mm": float(np.max([r["bias_mm"] for r in rows])),
    }


def _markdown(d: dict) -> str:
    conds = d["conditions"]
    lines = [
        "# Benchmark: what makes the lever arms scatter between windows",
        "",
        f"`{d['command']}`",
        "",
        f"Machine: {d['machine']}. Catalog robot {d['robot']} on a simulated farm, seed as stated, "
        f"{d['window_s']:g} s windows; each window's geometry as the worker estimates it (the first window's "
        "tree, each window's timing), in the gyros' frame and in the accelerometers'. The same motion runs "
        "under every condition; sensing is the `robot` preset unless the condition says otherwise. "
        "*Scatter*: RMS distance of a window's lever arm from the mean of the windows; *stated*: the median "
        "std the windows state; *understated*: IMUs whose scatter is more than twice their stated std; "
        "*bias*: the mean's distance from the model's lever arm.",
        "",
        "| condition | frame | scatter, median over IMUs | largest | stated, median | understated "
        "| bias, median | largest | CPU s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, c in conds.items():
        for frame in _FRAMES:
            s = summary(c, frame)
            lines.append(
                f"| {label} | {frame} | {s['scatter_median_mm']:.2f} mm | {s['scatter_max_mm']:.2f} mm "
                f"| {s['stated_median_mm']:.2f} mm | {s['understated']} / {s['imus']} "
                f"| {s['bias_median_mm']:.2f} mm | {s['bias_max_mm']:.2f} mm | "
                + (f"{c['cpu_s']:.0f} |" if frame == "gyro" else "|")
            )
    for frame in _FRAMES:
        labels = list(conds)
        names = sorted(next(iter(conds.values()))["frames"][frame], key=_imu_order)
        lines += [
            "",
            f"Per IMU, {frame}s' frame: scatter (stated) in mm, the errors' lag-one correlation in brackets.",
            "",
            "| IMU | lever arm | " + " | ".join(labels) + " |",
            "|---|---:|" + "---:|" * len(labels),
        ]
        for n in names:
            cells = []
            for label in labels:
                r = conds[label]["frames"][frame].get(n)
                lag = "" if r is None or r["lag_one"] is None else f" [{r['lag_one']:+.2f}]"
                cells.append("" if r is None else f"{r['scatter_mm']:.1f} ({r['stated_mm']:.1f}){lag}")
            arm = next(iter(conds.values()))["frames"][frame][n]["lever_arm_mm"]
            lines.append(f"| {n} | {arm:.0f} mm | " + " | ".join(cells) + " |")
    lines += ["", "![lever-arm scatter](lever-budget.png)", ""]
    return "\n".join(lines)


def _imu_order(name: str) -> tuple[int, str]:
    digits = "".join(ch for ch in name if ch.isdigit())
    return (int(digits) if digits else -1, name)


def _plot(d: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conds = d["conditions"]
    shown = [c for c in _PLOTTED if c in conds] or list(conds)[:4]
    fig, axes = plt.subplots(1, len(_FRAMES), figsize=(12, 4), sharey=True)
    for ax, frame in zip(np.atleast_1d(axes), _FRAMES, strict=True):
        names = sorted(conds[shown[0]]["frames"][frame], key=_imu_order)
        x = np.arange(len(names))
        width = 0.8 / len(shown)
        for i, label in enumerate(shown):
            rows = [conds[label]["frames"][frame].get(n) for n in names]
            sc = [r["scatter_mm"] if r else np.nan for r in rows]
            st = [r["stated_mm"] if r else np.nan for r in rows]
            pos = x + (i - (len(shown) - 1) / 2) * width
            ax.bar(pos, sc, width, label=f"{label}: scatter")
            ax.plot(pos, st, "k_", markersize=8, label="stated std" if i == 0 else None)
        ax.set_xticks(x, names, rotation=45)
        ax.set_title(f"{d['robot']}, {frame}s' frame")
        ax.set_ylabel("lever arm between windows, mm")
        ax.grid(axis="y", alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7)
    save_figure(fig, path)
