"""``bodyhealth simulate ROBOT``: simulate a catalog robot or a model file and write a recording."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a robot with IMUs and write a recording (docs/recording-format.md) (.npz)",
        description="ROBOT is a catalog name (see `bodyhealth robots`) or an MJCF/URDF file "
        "(instrumented with 2 IMUs per link when it has none).",
    )
    p.add_argument("robot", metavar="ROBOT")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated duration (default 10)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--imu-model",
        default="mpu6050",
        metavar="ideal|mpu6050|FILE.json",
        help="IMU error model: a preset or a JSON file (default mpu6050)",
    )
    p.add_argument(
        "--excitation",
        default="observable",
        choices=("random-torque", "sine", "observable", "poses", "hold"),
        help="how the robot moves (default observable: every joint moves)",
    )
    p.add_argument(
        "--damage",
        action="append",
        default=[],
        metavar="KIND[:key=value,...]",
        help="damage to apply, e.g. imu_moved:imu=imu3,to=j4,at=5 (repeatable; at= seconds "
        "into the run, default 0). Kinds: imu_moved, imu_detached, imu_dead, joint_locked, "
        "encoder_fault, link_lost",
    )
    p.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz (default 100)")
    p.add_argument(
        "--sensing",
        default="robot",
        metavar="robot|ideal|JSON",
        help="how the robot senses and stamps its motion: robot (the default: 14-bit position-only "
        "encoders at 250 Hz, 100 Hz IMUs with a 42 Hz low-pass, 8 ms skew, 30 ppm drift, jitter, 0.5%% "
        "drops; a multi-rate recording, docs/recording-format.md; --rate is then unused), ideal (synced "
        "exact velocities at --rate, what a simulator hands out and no robot does) or a JSON object of "
        "simulators.sensing.SensingOptions",
    )
    p.add_argument("--out", type=Path, default=Path("rec.npz"), help="recording to write (default rec.npz)")
    p.set_defaults(func=_simulate)


def _simulate(args: argparse.Namespace) -> int:
    from simulators.recording_io import save_recording
    from simulators.simulation import simulate

    rec = simulate(
        args.robot,
        seconds=args.seconds,
        seed=args.seed,
        imu_model=args.imu_model,
        excitation=args.excitation,
        damage=args.damage or None,
        rate=args.rate,
        sensing=args.sensing,
    )
    save_recording(rec, args.out)
    exc = rec.extra["excitation"]
    enc = f", encoders {rec.t_q.shape[0]} samples at {rec.encoder_rate:.0f} Hz" if rec.t_q is not None else ""
    print(
        f"{args.out}: {args.robot}, {rec.n_samples} samples at {rec.sample_rate:.0f} Hz{enc}, "
        f"{rec.n_joints} joints, {rec.n_imus} IMUs; excitation (RMS rad/s) "
        f"min {exc.min():.3f} max {exc.max():.3f}"
    )
    if "truth_diff" in rec.extra:
        print("damage:", json.dumps(json.loads(str(rec.extra["truth_diff"]))["findings"]))
    return 0
