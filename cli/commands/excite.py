"""``bodyhealth excite --model ROBOT [--recording REC.npz] [--limits L.toml] --seconds S -o plan.csv|.mcap``.

Plans the joint motion that decides the tree and every IMU's geometry soonest, within the joints'
position, velocity and acceleration limits (:mod:`bodyschema.excitation_plan`, docs/excitation.md).
With ``--recording`` only the joints that recording left undetermined or unconverged move (the fast
estimator and the kinematics run on it first); the others are held still, from the recording's last
pose. Writes a CSV (``time`` and one column per joint, rad) or a ROS 2 bag (a directory named as given,
MCAP storage, as ``ros2 bag`` and ``rosbags`` read it) with one ``trajectory_msgs/msg/JointTrajectory``
message on ``/excitation``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bodyschema.excitation_plan import ExcitationPlan

__all__ = ["TOPIC", "register", "run", "write_csv", "write_mcap"]

#: The MCAP bag's topic.
TOPIC = "/excitation"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "excite",
        help="plan the joint motion that decides the body schema soonest",
        description="Write a joint trajectory within the joint limits that makes every joint decidable "
        "by the fast estimator and every IMU's axis and lever arm converge in the least time.",
    )
    p.add_argument("--model", metavar="ROBOT", help="URDF, MJCF or catalog name (joints and limits)")
    p.add_argument("--recording", type=Path, metavar="REC.npz", help="plan only what it left open")
    p.add_argument("--limits", metavar="limits.toml", help="joint limits (docs/excitation.md)")
    p.add_argument("--seconds", type=float, required=True, help="length of the plan, s")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate of the plan, Hz")
    p.add_argument("--seed", type=int, default=0, help="seed of the plan's search")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="plan.csv|plan.mcap")
    p.set_defaults(func=run)


def write_csv(plan: ExcitationPlan, path: Path) -> None:
    """``time`` and one column per joint (rad), one row per sample."""
    import numpy as np

    rows = np.column_stack([plan.t, plan.q])
    header = ",".join(["time", *plan.joint_names])
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.9g")


def write_mcap(plan: ExcitationPlan, path: Path) -> None:
    """One ``trajectory_msgs/msg/JointTrajectory`` on :data:`TOPIC` of a ROS 2 MCAP bag at ``path``."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if path.exists():
        raise ValueError(f"{path} exists: a bag is written to a new directory")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    vel = np.gradient(plan.q, 1.0 / plan.rate, axis=0)
    empty = np.zeros(0)
    points = [
        T["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=plan.q[i].astype(np.float64),
            velocities=vel[i].astype(np.float64),
            accelerations=empty,
            effort=empty,
            time_from_start=T["builtin_interfaces/msg/Duration"](*divmod(round(t * 1e9), 10**9)),
        )
        for i, t in enumerate(plan.t.tolist())
    ]
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
    msg = T["trajectory_msgs/msg/JointTrajectory"](
        header=header, joint_names=list(plan.joint_names), points=points
    )
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection(TOPIC, "trajectory_msgs/msg/JointTrajectory", typestore=ts)
        w.write(conn, 0, ts.serialize_cdr(msg, "trajectory_msgs/msg/JointTrajectory"))


def _from_recording(
    path: Path, limits_names: tuple[str, ...]
) -> tuple[list[str], list[list[str]], list[float]]:
    """Joints the recording left open, the gyros' joint sets, and its last pose (limits' order)."""
    from bodyschema.estimate import estimate_topology
    from bodyschema.excitation_plan import groups_from_topology, undecided_joints
    from bodyschema.kinematics import estimate_kinematics
    from bodyschema.threads import blas_threads
    from simulators.recording_io import load_recording

    rec = load_recording(path)
    missing = sorted(set(rec.joint_names) - set(limits_names))
    if missing:
        raise ValueError(f"{path}: joints {', '.join(missing)} have no limits in the model/limits file")
    with blas_threads(1):
        topo = estimate_topology(rec)
        kin = estimate_kinematics(rec, topo)
    last = dict(zip(rec.joint_names, rec.q[-1].tolist(), strict=True)) if rec.q is not None else {}
    return (
        list(undecided_joints(topo, kin)),
        groups_from_topology(topo),
        [last.get(n, 0.0) for n in limits_names],
    )


def run(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from bodyschema.excitation_plan import PlanOptions, plan_excitation
    from simulators.limits import load_limits

    suffix = args.output.suffix.lower()
    if suffix not in (".csv", ".mcap"):
        raise ValueError(f"output must end in .csv or .mcap, got {args.output.name!r}")
    if args.model is None and args.limits is None:
        raise ValueError("give --model or --limits (the joints and their limits)")
    limits = load_limits(args.model, args.limits)
    excite, groups = None, None
    q0 = np.clip(np.zeros(len(limits.names)), limits.lower, limits.upper)
    if args.model is not None and args.recording is None:
        from simulators.robot import Robot

        robot = (
            Robot.from_catalog(args.model)
            if "." not in Path(args.model).name
            else Robot.from_file(args.model)
        )
        q0 = np.array([robot.q()[robot.joint_names.index(n)] for n in limits.names])
        groups = [[j for j in robot.truth().ancestors(jt)] for jt in robot.truth().imu_joint.values() if jt]
    if args.recording is not None:
        joints, groups, last = _from_recording(args.recording, limits.names)
        excite, q0 = joints, np.clip(np.array(last), limits.lower, limits.upper)
    cpu = time.process_time()
    plan = plan_excitation(
        limits, q0, args.seconds, excite, groups, PlanOptions(rate=args.rate, seed=args.seed)
    )
    cpu = time.process_time() - cpu
    args.output.parent.mkdir(parents=True, exist_ok=True)
    (write_csv if suffix == ".csv" else write_mcap)(plan, args.output)
    what = ", ".join(plan.excited) if plan.excited else f"nothing ({plan.reason})"
    decide = (
        f"decides at about {plan.decide_s:g} s" if plan.decide_s is not None else "does not reach the target"
    )
    print(
        f"{plan.method} plan of {plan.seconds:g} s moving {what}; {decide} (cond {plan.cond:.2f}); "
        f"planned in {cpu:.2f} CPU s; written to {args.output}"
    )
    return 0
