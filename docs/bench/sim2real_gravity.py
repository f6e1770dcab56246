"""Bench of the robot gravity case: sensor networks without gravity (Eq. 11) against with it (Eq. 24).

Makes the recordings with ``bodyhealth simulate`` and runs what ``bodyhealth sim2real REC --model ROBOT
--gravity-case`` runs (:func:`bodyschema.discrepancy.network_gravity.gravity_case` with the robot's
kinematic references), once per robot and seed; writes ``sim2real_gravity.json``, ``.md`` and ``.png``
beside this file. Run from the repository root::

    OMP_NUM_THREADS=1 .venv/bin/python docs/bench/sim2real_gravity.py --robots ur5e,paper-3 --seeds 0,1,2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BIN = Path(sys.executable).parent


def run_one(robot: str, seed: int, seconds: float, imu_model: str, epochs: int, work: Path) -> dict:
    from bodyschema.discrepancy.network_gravity import gravity_case
    from service.sim2real_report import robot_references
    from simulators.recording_io import load_recording

    path = work / f"{robot}_{seed}.npz"
    cmd = [str(BIN / "bodyhealth"), "simulate", robot, "--seconds", str(seconds), "--seed", str(seed),
           "--imu-model", imu_model, "--out", str(path)]
    subprocess.run(cmd, check=True, capture_output=True)
    rec = load_recording(path)
    t0 = time.process_time()
    case = gravity_case(rec, seed=seed, epochs=epochs, references=robot_references(rec, robot))
    d = case.to_json()
    d["cpu_s"] = time.process_time() - t0
    d["robot"], d["seed"] = robot, seed
    return d


def _fmt_acc(a: dict) -> str:
    return f"{'exact' if a['exact'] else 'no'} ({a['joint_parent']:.2f} / {a['imu_joint']:.2f})"


def table(runs: list[dict]) -> str:
    rows = ["| robot | seed | acc residual Eq. 11 → Eq. 24 (m/s²) | gyro residual Eq. 11 → Eq. 24 (rad/s) | "
            "named on Eq. 11 (kinematics): IMUs, \\|g\\|, angle | "
            "named on Eq. 11 (networks): IMUs, \\|g\\| | "
            "topology Eq. 11: exact (parents / IMUs) | topology Eq. 24 | CPU s |",
            "|---|---:|---|---|---|---|---|---|---:|"]
    for d in runs:
        f11, f24 = d["forms"]["eq11"], d["forms"]["eq24"]

        def named(an: dict, angle: str | None) -> str:
            c = next((c for c in an["causes"] if c["effect"] == "gravity"), None)
            if c is None:
                return "gravity not named"
            p = c["params"]
            text = f"gravity {c['imus']}/{c['of']}, {p['norm']:.2f}"
            return text + (f", {p[angle]:.1f}°" if angle else "")

        rows.append(
            f"| {d['robot']} | {d['seed']} | {f11['acc_rms']:.3f} → {f24['acc_rms']:.3f} | "
            f"{f11['gyro_rms']:.3f} → {f24['gyro_rms']:.3f} | "
            f"{named(d['analyses']['kinematics'], 'angle_to_recording_deg')} | "
            f"{named(d['analyses']['network'], None)} | {_fmt_acc(f11['accuracy'])} | "
            f"{_fmt_acc(f24['accuracy'])} | {d['cpu_s']:.0f} |"
        )
    return "\n".join(rows)


def summary(runs: list[dict]) -> str:
    """One row per robot over its seeds (the README table)."""
    rows = ["| robot | seeds | acc residual Eq. 11 → Eq. 24 (m/s², median) | gravity named on Eq. 11 "
            "(kinematics): \\|g\\| m/s², angle | topology exact Eq. 11 / Eq. 24 | right joint parents, IMU "
            "joints: Eq. 11 → Eq. 24 (mean) |", "|---|---:|---|---|---|---|"]
    for robot in dict.fromkeys(d["robot"] for d in runs):
        rs = [d for d in runs if d["robot"] == robot]
        f = {k: [d["forms"][k] for d in rs] for k in ("eq11", "eq24")}
        gs = [next((c for c in d["analyses"]["kinematics"]["causes"] if c["effect"] == "gravity"), None)
              for d in rs]
        named = [c for c in gs if c is not None]
        norms = [c["params"]["norm"] for c in named]
        angles = [c["params"]["angle_to_recording_deg"] for c in named]
        gtext = (f"{len(named)}/{len(rs)} runs: {min(norms):.2f}–{max(norms):.2f}, "
                 f"{min(angles):.1f}–{max(angles):.1f}°") if named else "not named"
        rows.append(
            f"| {robot} | {len(rs)} | {np.median([x['acc_rms'] for x in f['eq11']]):.2f} → "
            f"{np.median([x['acc_rms'] for x in f['eq24']]):.2f} | {gtext} | "
            f"{sum(x['accuracy']['exact'] for x in f['eq11'])}/{len(rs)} / "
            f"{sum(x['accuracy']['exact'] for x in f['eq24'])}/{len(rs)} | "
            f"{np.mean([x['accuracy']['joint_parent'] for x in f['eq11']]):.2f}, "
            f"{np.mean([x['accuracy']['imu_joint'] for x in f['eq11']]):.2f} → "
            f"{np.mean([x['accuracy']['joint_parent'] for x in f['eq24']]):.2f}, "
            f"{np.mean([x['accuracy']['imu_joint'] for x in f['eq24']]):.2f} |"
        )
    return "\n".join(rows)


def plot(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{d['robot']}\ns{d['seed']}" for d in runs]
    x = np.arange(len(runs))
    for off, form, color in ((-0.2, "eq11", "tab:red"), (0.2, "eq24", "tab:blue")):
        axes[0].bar(x + off, [d["forms"][form]["acc_rms"] for d in runs], width=0.4, color=color,
                    label=f"Eq. {form[2:]}")
        axes[1].bar(x + off, [d["forms"][form]["accuracy"]["imu_joint"] for d in runs], width=0.4,
                    color=color, label=f"Eq. {form[2:]}")
    axes[0].set_ylabel("accelerometer residual RMS (m/s²)")
    axes[1].set_ylabel("fraction of IMUs on the right joint")
    for ax in axes:
        ax.set_xticks(x, labels, fontsize=7)
        ax.legend(fontsize=8, loc="lower right", framealpha=0.9)
    fig.suptitle("sensor networks without (Eq. 11) and with (Eq. 24) gravity", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="ur5e,paper-3")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--imu-model", default="mpu6050")
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--out", type=Path, default=HERE / "sim2real_gravity.json")
    args = ap.parse_args()
    out = args.out
    runs: list[dict] = json.loads(out.read_text()) if out.exists() else []
    done = {(d["robot"], d["seed"]) for d in runs}
    with tempfile.TemporaryDirectory() as tmp:
        for robot in args.robots.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                if (robot, seed) in done:
                    continue
                d = run_one(robot, seed, args.seconds, args.imu_model, args.epochs, Path(tmp))
                d["settings"].update({"seconds": args.seconds, "imu_model": args.imu_model})
                runs.append(d)
                out.write_text(json.dumps(runs, indent=1) + "\n")  # resumable
                print(table([d]).splitlines()[-1], flush=True)
    print(summary(runs))
    print(table(runs))
    plot(runs, out.with_suffix(".png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
