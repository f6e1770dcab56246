"""``bodyhealth import FORMAT FILE --out rec.npz``: convert measured data into a recording.

Formats: ``broad`` (a BROAD trial, HDF5: one IMU plus optical motion capture; see :mod:`sim2real.broad`),
``rosbag`` (a ROS 1 ``.bag``, or a ROS 2 bag directory, ``.mcap`` or ``.db3``: IMU and joint-state
topics; see :mod:`service.ingest.rosbag`), ``csv`` and ``mat`` (a robot's own log, CSV or MATLAB v7.3,
read through an import map; see :mod:`sim2real.robot_logs`). The readers are imported only when their
format is asked for, so ``bodyhealth --help`` loads none of them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["format_report", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="convert measured data (ROS bag, BROAD HDF5, CSV or MATLAB logs) into a recording (.npz)",
    )
    fsub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    b = fsub.add_parser("broad", help="a BROAD trial (Laidig et al., Data 6(7) 2021, CC BY 4.0)")
    b.add_argument("trial", type=Path, help="BROAD trial file (.hdf5)")
    b.add_argument("--out", type=Path, required=True, help="recording to write (.npz)")
    b.add_argument(
        "--max-gap",
        type=float,
        default=0.1,
        help="optical dropouts up to this many seconds are interpolated; longer ones are masked",
    )
    b.set_defaults(func=_import_broad)
    r = fsub.add_parser(
        "rosbag", help="a ROS bag: sensor_msgs/Imu topics become IMUs, sensor_msgs/JointState encoders"
    )
    r.add_argument("bag", type=Path, help="ROS 1 .bag file, or ROS 2 bag directory (or its .mcap/.db3)")
    r.add_argument("-o", "--out", type=Path, required=True, help="recording to write (.npz)")
    r.add_argument(
        "--imu-topic",
        action="append",
        default=[],
        metavar="TOPIC",
        help="an IMU topic to read (repeatable; default: every sensor_msgs/msg/Imu topic)",
    )
    r.add_argument(
        "--joint-topic",
        action="append",
        default=[],
        metavar="TOPIC",
        help="a joint-state topic to read (repeatable; default: every sensor_msgs/msg/JointState topic)",
    )
    r.set_defaults(func=_import_rosbag)
    for fmt, what in (("csv", "a CSV log (header row, one row per sample)"), ("mat", "a MATLAB v7.3 file")):
        c = fsub.add_parser(fmt, help=f"{what}, read through an import map (TOML; docs/recording-format.md)")
        c.add_argument("log", type=Path, help=f"the robot's log (.{fmt})")
        c.add_argument("--map", type=Path, required=True, metavar="MAP.toml", help="the import map")
        c.add_argument("-o", "--out", type=Path, required=True, help="recording to write (.npz)")
        c.add_argument("--json", action="store_true", help="print the import report as JSON")
        c.set_defaults(func=_import_log)


def _import_broad(args: argparse.Namespace) -> int:
    from sim2real.broad import load_broad
    from simulators.recording_io import save_recording

    rec = load_broad(args.trial, max_gap=args.max_gap)
    save_recording(rec, args.out)
    valid = rec.extra["ref_valid"]
    print(
        f"{args.out}: {rec.n_samples} samples at {rec.sample_rate:.1f} Hz, "
        f"{int(valid.sum())} with a valid reference, {int(rec.extra['movement'].sum())} in movement"
    )
    return 0


def _import_rosbag(args: argparse.Namespace) -> int:
    from service.ingest.rosbag import RosbagOptions, import_rosbag

    opts = RosbagOptions(imu_topics=tuple(args.imu_topic), joint_topics=tuple(args.joint_topic))
    rec, summary = import_rosbag(args.bag, args.out, opts)
    clocks = (
        f"encoders on their own stamps ({len(rec.encoder_t)} at {rec.encoder_rate:.1f} Hz)"
        if rec.is_multirate
        else "encoders on the IMU stamps"
    )
    dropped = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in summary.dropped.items()) or "none"
    print(
        f"{args.out}: {summary.messages} messages from {len(summary.imu_topics)} IMU and "
        f"{len(summary.joint_topics)} joint-state topic(s): {rec.n_imus} IMUs at {rec.sample_rate:.1f} Hz "
        f"({rec.n_samples} samples), {rec.n_joints} joints, {clocks}, "
        f"velocity {'present' if rec.qd is not None else 'absent'}; dropped: {dropped}"
    )
    return 0


def _import_log(args: argparse.Namespace) -> int:
    import json

    from sim2real.robot_logs import import_log
    from simulators.recording_io import save_recording

    rec, report = import_log(args.log, args.map, args.format)
    save_recording(rec, args.out)
    if args.json:
        out = {"output": str(args.out), "samples": rec.n_samples, "joints": rec.n_joints, "imus": rec.n_imus}
        print(json.dumps({**out, "multirate": rec.is_multirate, "report": report}, indent=2))
        return 0
    print(format_report(rec.n_samples, rec.n_joints, rec.n_imus, report, args.out))
    return 0


def format_report(samples: int, joints: int, imus: int, report: dict, out: Path) -> str:
    """The import report as lines a person reads: clocks, streams (unit, held rows), encoder quanta."""
    lines = [f"{out}: {samples} samples, {joints} joints, {imus} IMU(s) from {report['source']}"]
    for name, c in report["clocks"].items():
        g = c["gaps"]
        gaps = f"{g['count']} gap(s) over {g['factor']}x the median" + (
            f", largest {1e3 * g['largest_s']:.1f} ms" if g["count"] else ""
        )
        lines.append(
            f"  clock {name}: {c['rate_hz']:.2f} Hz, step {1e3 * c['median_step_s']:.2f} ms "
            f"({1e3 * c['min_step_s']:.2f}-{1e3 * c['max_step_s']:.2f}, "
            f"jitter {1e6 * c['jitter_std_s']:.0f} us), {gaps}"
        )
    for key, s in report["streams"].items():
        unit = s.get("unit") or "-"
        unit += " (assumed)" if s.get("unit_assumed") else ""
        held = ""
        if s.get("repeated_rows") is not None:
            rate = s["update_rate_hz"]
            held = f"; repeats {100 * s['repeat_fraction']:.1f} % of rows" + (
                f", updates at {rate:.1f} Hz" if rate else ""
            )
        lines.append(f"  {key}: {unit}{held}")
    enc = report.get("encoders", {})
    if enc:
        q = {j: e for j, e in enc.items() if e["quantum_rad"] is not None}
        match = sum(e["matches_power_of_two"] is True for e in q.values())
        unres = sum(e["matches_power_of_two"] is None for e in q.values())
        smallest = min((e["quantum_rad"] for e in q.values()), default=None)
        lines.append(
            f"  encoders: {len(q)} joints moved; {match} with a quantum 2pi/2^bits, {unres} not resolved by "
            f"the log; smallest step {smallest:.6g} rad"
            if smallest is not None
            else "  encoders: no joint moved"
        )
    absent = report.get("extras", {}).get("absent", [])
    if absent:
        lines.append(f"  optional extras absent from the log: {', '.join(absent)}")
    return "\n".join(lines)
