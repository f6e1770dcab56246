"""``bodyhealth kinematics REC.npz [--topology T.json] [--json] [--urdf out.urdf] [--plot out.png]``.

Joint axes and IMU lever arms from a recording (:mod:`bodyschema.kinematics`, docs/kinematics.md), on
the tree the fast estimator learns or the one given; ``--urdf`` writes the learned body as a URDF
(:mod:`bodyschema.urdf`), ``--plot`` draws each IMU's axis and lever-arm uncertainty (and the errors
against the truth when the recording is simulated and names its robot).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bodyschema.kinematics import Kinematics

__all__ = ["format_kinematics", "plot_kinematics", "register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "kinematics",
        help="learn joint axes and IMU lever arms from a recording",
        description="Estimate each joint's axis and each IMU's lever arm from the gyros, accelerometers "
        "and encoders of a recording (docs/recording-format.md), on the learned (or given) joint tree.",
    )
    p.add_argument("recording", type=Path, metavar="REC.npz")
    p.add_argument(
        "--topology", type=Path, metavar="T.json", help="topology JSON to use instead of learning it"
    )
    p.add_argument("--json", action="store_true", help="print the kinematics JSON (docs/kinematics.md)")
    p.add_argument("--urdf", type=Path, metavar="out.urdf", help="write the learned body as a URDF")
    p.add_argument("--plot", type=Path, metavar="out.png", help="plot axis and lever-arm uncertainties")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bodyschema.kinematics import estimate_kinematics
    from bodyschema.threads import blas_threads
    from bodyschema.topology import Topology
    from bodyschema.urdf import to_urdf
    from simulators.recording_io import load_recording

    rec = load_recording(args.recording)
    topo = None
    if args.topology is not None:
        topo = Topology.from_json(json.loads(args.topology.read_text(encoding="utf-8")))
    with blas_threads(1):
        kin = estimate_kinematics(rec, topo)
    if args.json:
        print(json.dumps(kin.to_json(), indent=2))
    else:
        print(format_kinematics(kin))
    if args.urdf is not None:
        args.urdf.parent.mkdir(parents=True, exist_ok=True)
        args.urdf.write_text(to_urdf(kin, args.recording.stem), encoding="utf-8")
        if not args.json:
            print(f"URDF written to {args.urdf}")
    if args.plot is not None:
        plot_kinematics(kin, args.plot, title=args.recording.name)
        if not args.json:
            print(f"plot written to {args.plot}")
    return 0


def format_kinematics(kin: Kinematics) -> str:
    """One line per IMU: joint, axis, lever arm and their stds, or why nothing is claimed.

    >>> import numpy as np
    >>> from bodyschema.kinematics import ImuKinematics, Kinematics
    >>> from bodyschema.topology import Topology
    >>> imu = ImuKinematics("imu1", "j1", axis=np.array([0.0, 0, 1]), lever_arm=np.array([0.1, 0, 0]),
    ...                     axis_std_deg=0.1, lever_arm_std_m=0.001, converged=True)
    >>> kin = Kinematics({"imu1": imu}, {}, (), 10.0, 0.0, 100, Topology({"j1": None}, {"imu1": "j1"}))
    >>> print(format_kinematics(kin).splitlines()[1])
    imu1  j1  axis [+0.000 +0.000 +1.000] ±0.10°  lever arm [+100.0 +0.0 +0.0] mm ±1.0  converged
    """
    lines = [f"band {kin.band_hz:.1f} Hz, IMU lag {kin.lag_ms:.2f} ms, {kin.samples} samples"]
    for name, k in kin.imus.items():
        if k.axis is None or k.lever_arm is None:
            from bodyschema.diff import UNDETERMINED_HERE

            where = "?" if k.reason.startswith(UNDETERMINED_HERE) else (k.joint or "base")  # not placed
            lines.append(f"{name}  {where}  -- {k.reason}")
            continue
        ax = " ".join(f"{x:+.3f}" for x in k.axis)
        la = " ".join(f"{x * 1e3:+.1f}" for x in k.lever_arm)
        state = "converged" if k.converged else f"not converged ({k.reason})"
        if k.undetermined:
            state += (
                f"; rotation from {k.parent_imu} undetermined about its link's axis "
                f"(±{k.turn_about_parent_std_deg:.1f}°, see the JSON)"
            )
        lines.append(
            f"{name}  {k.joint}  axis [{ax}] ±{k.axis_std_deg:.2f}°  lever arm [{la}] mm "
            f"±{k.lever_arm_std_m * 1e3:.1f}  {state}"
        )
    return "\n".join(lines)


def plot_kinematics(kin: Kinematics, path: Path, title: str = "") -> None:
    """Per fitted IMU: axis std (deg) and lever-arm std (mm), bars; unconverged ones in grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from sim2real.figures import save_figure

    fitted = [(n, k) for n, k in kin.imus.items() if k.axis is not None]
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.35 * len(fitted) + 2), 5.5), sharex=True)
    x = np.arange(len(fitted))
    colors = ["tab:blue" if k.converged else "0.7" for _, k in fitted]
    axes[0].bar(x, [k.axis_std_deg for _, k in fitted], color=colors)
    axes[0].set_ylabel("axis std, deg")
    axes[1].bar(x, [k.lever_arm_std_m * 1e3 for _, k in fitted], color=colors)
    axes[1].set_ylabel("lever-arm std, mm")
    axes[1].set_xticks(x, [f"{n}\n{k.joint}" for n, k in fitted], fontsize=7)
    axes[0].set_title(title or "kinematics")
    save_figure(fig, path)
