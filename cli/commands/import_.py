"""``bodyhealth import FORMAT FILE --out rec.npz``: convert measured data into a docs/design.md §2 recording.

Formats: ``broad`` (a BROAD trial, HDF5: one IMU plus optical motion capture; see :mod:`sim2real.broad`),
``rosbag`` (a ROS 1 ``.bag``, or a ROS 2 bag directory, ``.mcap`` or ``.db3``: IMU and joint-state
topics; see :mod:`service.ingest.rosbag`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="convert measured data (ROS bag, BROAD HDF5) into a recording (.npz)")
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
