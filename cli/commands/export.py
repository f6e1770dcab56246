"""``bodyhealth export rosbag REC.npz OUT``: write a recording as a ROS bag, to replay in ROS tools.

ROS 2 with MCAP storage by default (``--format sqlite3`` for the older storage, ``--format ros1`` for a
ROS 1 ``.bag``); the topics are described in :mod:`emulators.rosbag`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a recording (.npz) in another format (ROS bag)")
    fsub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    r = fsub.add_parser("rosbag", help="a ROS 2 (MCAP or sqlite3) or ROS 1 bag of IMU and joint-state topics")
    r.add_argument("recording", type=Path, help="recording to read (.npz)")
    r.add_argument("out", type=Path, help="bag to write: a ROS 2 bag directory, or a .bag file for ros1")
    r.add_argument(
        "--format",
        dest="bag_format",
        choices=("mcap", "sqlite3", "ros1"),
        default="mcap",
        help="ROS 2 storage (mcap, sqlite3) or a ROS 1 bag (default: mcap)",
    )
    r.add_argument("--joint-topic", default="/joint_states", help="topic of the joint states")
    r.add_argument(
        "--origin-ns",
        type=int,
        default=None,
        help="stamp of the recording's t = 0, ns since the epoch (default: the recording's own, or 0)",
    )
    r.set_defaults(func=_export_rosbag)


def _export_rosbag(args: argparse.Namespace) -> int:
    from emulators.rosbag import RosbagWriteOptions, write_rosbag
    from simulators.recording_io import load_recording

    rec = load_recording(args.recording)
    opts = RosbagWriteOptions(format=args.bag_format, joint_topic=args.joint_topic, origin_ns=args.origin_ns)
    n = write_rosbag(rec, args.out, opts)
    print(
        f"{args.out}: {n} messages ({args.bag_format}): {rec.n_imus} IMU topics under /imu/, "
        f"{rec.n_joints} joints on {args.joint_topic}"
    )
    return 0
