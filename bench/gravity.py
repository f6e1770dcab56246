"""The robot gravity case: sensor networks without gravity (Eq. 11) against with it (Eq. 24).

Per robot and seed: simulate the robot (``bodyhealth simulate ROBOT --seconds S --seed SEED``), then run
what ``bodyhealth sim2real REC.npz --model ROBOT --gravity-case --seed SEED`` runs
(:func:`bodyschema.discrepancy.network_gravity.gravity_case` with the robot's kinematic references):
both network forms trained on the same seed, their residuals, the cause named on the Eq. 11 residual
(on the exact kinematics and on the Eq. 11 networks), and each form's topology against the truth.
Writes ``gravity.json`` (one entry per run; runs already there are kept, so an interrupted bench
resumes), ``gravity.md`` and ``gravity.png``.

A run costs minutes (two trainings and 24 analyses), so the defaults are two robots and three seeds.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, machine_note
from bodyschema.progress import progress
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run", "run_one", "runs_table", "summary_table"]

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default="ur5e,paper-3", help="comma-separated catalog robots")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated seeds (recording and training)")
    parser.add_argument("--seconds", type=float, default=60.0, help="recording length")
    parser.add_argument("--imu-model", default="mpu6050", help="IMU preset of the simulated recordings")
    parser.add_argument("--epochs", type=int, default=40, help="training epochs of each network form")
    parser.add_argument("--fresh", action="store_true", help="ignore runs kept in the results file")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def run_one(robot: str, seed: int, seconds: float, imu_model: str, epochs: int) -> dict:
    """One simulated recording and its gravity case, as the JSON entry the results file keeps."""
    from bodyschema.discrepancy.network_gravity import gravity_case
    from sim2real.report import robot_references
    from simulators.simulation import simulate

    rec = simulate(robot, seconds=seconds, seed=seed, imu_model=imu_model)
    t0 = time.process_time()
    case = gravity_case(rec, seed=seed, epochs=epochs, references=robot_references(rec, robot))
    d = case.to_json()
    d["cpu_s"] = time.process_time() - t0
    d["robot"], d["seed"], d["machine"] = robot, seed, machine_note()
    d["settings"].update({"seconds": seconds, "imu_model": imu_model})
    return d


def _gravity(analysis: dict) -> dict | None:
    return next((c for c in analysis["causes"] if c["effect"] == "gravity"), None)


def _named(runs: list[dict], reference: str) -> list[dict]:
    """The gravity causes named on the Eq. 11 residual against ``reference`` (kinematics or network),
    one per run that named gravity."""
    return [c for c in (_gravity(d["analyses"][reference]) for d in runs) if c is not None]


def _span(values: list[float], fmt: str = ".2f") -> str:
    lo, hi = min(values), max(values)
    return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}}–{hi:{fmt}}"


def _acc(a: dict) -> str:
    return f"{'exact' if a['exact'] else 'no'} ({a['joint_parent']:.2f} / {a['imu_joint']:.2f})"


def runs_table(runs: list[dict]) -> str:
    """One row per robot and seed."""
    rows = [
        "| robot | seed | acc residual Eq. 11 → Eq. 24 (m/s²) | gyro residual Eq. 11 → Eq. 24 (rad/s) | "
        "named on Eq. 11 (kinematics): IMUs, \\|g\\|, angle | "
        "named on Eq. 11 (networks): IMUs, \\|g\\| | "
        "topology Eq. 11: exact (parents / IMUs) | topology Eq. 24 | CPU s |",
        "|---|---:|---|---|---|---|---|---|---:|",
    ]
    for d in runs:
        f11, f24 = d["forms"]["eq11"], d["forms"]["eq24"]

        def named(an: dict, angle: bool) -> str:
            c = _gravity(an)
            if c is None:
                return "gravity not named"
            text = f"gravity {c['imus']}/{c['of']}, {c['params']['norm']:.2f}"
            return text + (f", {c['params']['angle_to_recording_deg']:.1f}°" if angle else "")

        rows.append(
            f"| {d['robot']} | {d['seed']} | {f11['acc_rms']:.3f} → {f24['acc_rms']:.3f} | "
            f"{f11['gyro_rms']:.3f} → {f24['gyro_rms']:.3f} | {named(d['analyses']['kinematics'], True)} | "
            f"{named(d['analyses']['network'], False)} | {_acc(f11['accuracy'])} | {_acc(f24['accuracy'])} | "
            f"{d['cpu_s']:.0f} |"
        )
    return "\n".join(rows)


def summary_table(runs: list[dict]) -> str:
    """One row per robot over its seeds (the table the README shows)."""
    rows = [
        "| robot | seeds | acc residual Eq. 11 → Eq. 24 (m/s², median) | gravity named on Eq. 11 "
        "(kinematics): \\|g\\| m/s², angle | topology exact Eq. 11 / Eq. 24 | right joint parents, IMU "
        "joints: Eq. 11 → Eq. 24 (mean) |",
        "|---|---:|---|---|---|---|",
    ]
    for robot in dict.fromkeys(d["robot"] for d in runs):
        rs = [d for d in runs if d["robot"] == robot]
        f = {k: [d["forms"][k] for d in rs] for k in ("eq11", "eq24")}
        named = _named(rs, "kinematics")
        gtext = (
            f"{len(named)}/{len(rs)} runs: {_span([c['params']['norm'] for c in named])}, "
            f"{_span([c['params']['angle_to_recording_deg'] for c in named], '.1f')}°"
            if named
            else "not named"
        )
        mean = {
            k: {a: np.mean([x["accuracy"][a] for x in f[k]]) for a in ("joint_parent", "imu_joint")}
            for k in f
        }
        rows.append(
            f"| {robot} | {len(rs)} | {np.median([x['acc_rms'] for x in f['eq11']]):.2f} → "
            f"{np.median([x['acc_rms'] for x in f['eq24']]):.2f} | {gtext} | "
            f"{sum(x['accuracy']['exact'] for x in f['eq11'])}/{len(rs)} / "
            f"{sum(x['accuracy']['exact'] for x in f['eq24'])}/{len(rs)} | "
            f"{mean['eq11']['joint_parent']:.2f}, {mean['eq11']['imu_joint']:.2f} → "
            f"{mean['eq24']['joint_parent']:.2f}, {mean['eq24']['imu_joint']:.2f} |"
        )
    return "\n".join(rows)


def _findings(runs: list[dict]) -> list[str]:
    """What the runs say, computed from them (the numbers in docs/sim2real.md come from here)."""
    n = len(runs)
    kin, net = _named(runs, "kinematics"), _named(runs, "network")
    f11 = [d["forms"]["eq11"] for d in runs]
    f24 = [d["forms"]["eq24"] for d in runs]
    lines = [
        f"* Gravity named on the Eq. 11 residual on the exact kinematics in {len(kin)}/{n} runs"
        + (
            f": {_span([c['params']['norm'] for c in kin])} m/s², "
            f"{_span([c['params']['angle_to_recording_deg'] for c in kin], '.1f')}° from the recording's "
            f"gravity, by {_span([c['imus'] for c in kin], 'd')} of {_span([c['of'] for c in kin], 'd')} "
            "IMUs."
            if kin
            else "."
        )
    ]
    if net:
        norms = _span([c["params"]["norm"] for c in net])
        lines.append(
            f"* On the Eq. 11 networks themselves: named in {len(net)}/{n} runs, with only {norms} "
            "m/s², the rest absorbed by the networks' bent accelerations and biases."
        )
    gain = [d["residual_gain"] for d in runs]
    lines.append(
        f"* Eq. 24 removes {_span([100 * g['acc'] for g in gain], '.1f')} % of the accelerometer "
        f"residual energy ({_span([x['acc_rms'] for x in f11])} → "
        f"{_span([x['acc_rms'] for x in f24])} m/s²) and "
        f"{_span([100 * g['gyro'] for g in gain], '.0f')} % of the gyro residual's."
    )
    lines.append(
        f"* Topology exact: Eq. 11 in {sum(x['accuracy']['exact'] for x in f11)}/{n} runs "
        f"({_span([100 * x['accuracy']['joint_parent'] for x in f11], '.0f')} % of joint parents, "
        f"{_span([100 * x['accuracy']['imu_joint'] for x in f11], '.0f')} % of IMU joints right), "
        f"Eq. 24 in {sum(x['accuracy']['exact'] for x in f24)}/{n}."
    )
    for robot in dict.fromkeys(d["robot"] for d in runs):
        cpu = [d["cpu_s"] for d in runs if d["robot"] == robot]
        lines.append(
            f"* {robot}: {_span(cpu, '.0f')} CPU s per run (both trainings, both topologies, the analyses)."
        )
    return lines


def _plot(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(runs))
    for off, form, color in ((-0.2, "eq11", "tab:red"), (0.2, "eq24", "tab:blue")):
        axes[0].bar(
            x + off,
            [d["forms"][form]["acc_rms"] for d in runs],
            width=0.4,
            color=color,
            label=f"Eq. {form[2:]}",
        )
        axes[1].bar(
            x + off,
            [d["forms"][form]["accuracy"]["imu_joint"] for d in runs],
            width=0.4,
            color=color,
            label=f"Eq. {form[2:]}",
        )
    axes[0].set_ylabel("accelerometer residual RMS (m/s²)")
    axes[1].set_ylabel("fraction of IMUs on the right joint")
    for ax in axes:
        ax.set_xticks(x, [f"{d['robot']}\ns{d['seed']}" for d in runs], fontsize=7)
        ax.legend(fontsize=8, loc="lower right", framealpha=0.9)
    fig.suptitle("sensor networks without (Eq. 11) and with (Eq. 24) gravity", fontsize=10)
    save_figure(fig, path, dpi=80)


def _settings_text(runs: list[dict], args: argparse.Namespace) -> str:
    s = runs[0]["settings"]
    machines = "; ".join(dict.fromkeys(d["machine"] for d in runs))
    return (
        f"`bodyhealth bench gravity --robots {args.robots} --seeds {args.seeds}` (resumable: runs "
        "already in `gravity.json` are kept). Per robot and seed: `bodyhealth simulate ROBOT --seconds "
        f"{s['seconds']:g} --seed S --imu-model {s['imu_model']}`, then what `bodyhealth sim2real "
        "REC.npz --model ROBOT --gravity-case --seed S` runs: both network forms trained with seed S "
        f"({s['epochs']} epochs, hidden {'-'.join(map(str, s['hidden']))}), residuals in-sample, the "
        "held-out effect selection on the Eq. 11 residual (up to 12 IMUs, spread over the Eq. 11 "
        "residual ranking) against the exact kinematics and against the Eq. 11 networks, and each "
        "form's topology against the ground truth.\n\n"
        f"Machine: {machines}, one torch thread (runs measured while other work shared the cores). "
        "CPU s: process time of both trainings, both topologies and the analyses."
    )


def _markdown(runs: list[dict], args: argparse.Namespace) -> str:
    return "\n".join(
        [
            "# The robot gravity case: sensor networks without gravity (Eq. 11) and with it (Eq. 24)",
            "",
            _settings_text(runs, args),
            "",
            "## Summary",
            "",
            summary_table(runs),
            "",
            *_findings(runs),
            "",
            "## Per run",
            "",
            runs_table(runs),
            "",
            "![residual and topology per run](gravity.png)",
            "",
        ]
    )


def run(args: argparse.Namespace) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = out / "gravity.json"
    runs: list[dict] = [] if args.fresh or not results.exists() else json.loads(results.read_text())
    done = {(d["robot"], d["seed"]) for d in runs}
    todo = [
        (r, int(s)) for r in args.robots.split(",") for s in args.seeds.split(",") if (r, int(s)) not in done
    ]
    for robot, seed in progress(todo, desc="bench gravity", unit="run"):
        d = run_one(robot, seed, args.seconds, args.imu_model, args.epochs)
        runs.append(d)
        results.write_text(json.dumps(runs, indent=1) + "\n", encoding="utf-8")  # resumable
        log.info("%s", runs_table([d]).splitlines()[-1])
    if not runs:
        raise ValueError("no runs: give --robots and --seeds")
    _plot(runs, out / "gravity.png")
    path = out / "gravity.md"
    path.write_text(_markdown(runs, args), encoding="utf-8")
    return path
