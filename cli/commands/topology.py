"""``bodyhealth topology REC.npz [--method M] [--json] [--plot tree.png]``: learn a robot's body schema.

Prints the learned joint tree with the IMUs on each link (or, with ``--json``, the topology JSON of
docs/design.md); ``--plot`` draws the tree, next to the ground truth when the recording carries one.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cli.commands.diff import METHODS  # bodyschema.estimate.METHODS, without importing the estimators

if TYPE_CHECKING:
    from bodyschema.topology import Topology

__all__ = ["format_tree", "plot_trees", "register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "topology",
        help="learn the joint tree and IMU placement from a recording",
        description="Learn which joint hangs under which and which IMU rides which link, from the "
        "encoders and IMUs of a recording (docs/recording-format.md).",
    )
    p.add_argument("recording", type=Path, metavar="REC.npz")
    p.add_argument(
        "--method",
        choices=METHODS,
        default="fast",
        help="fast (gyro tests, ~1 s), network (the paper's sensor networks), network-paper "
        "(with the paper's variance statistic), mlp (the paper's baseline); default fast",
    )
    p.add_argument("--json", action="store_true", help="print the topology JSON (docs/design.md)")
    p.add_argument("--plot", type=Path, metavar="tree.png", help="draw the learned tree (and the truth)")
    p.add_argument("--seed", type=int, default=0, help="seed of the network methods (default 0)")
    p.add_argument("--epochs", type=int, default=None, help="training epochs of the network methods")
    p.add_argument(
        "--imu-delay-ms",
        type=float,
        default=None,
        metavar="MS",
        help="stated group delay of the IMU's on-chip low-pass (MPU-6050 DLPF_CFG 3: 4.8), taken out "
        "of the estimated lag to report the clock skew alone; default: what the recording states, else 0",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bodyschema.estimate import estimate_topology
    from bodyschema.topology import Topology
    from simulators.recording_io import load_recording

    rec = load_recording(args.recording)
    from cli.commands.floating import is_floating, topology_floating

    if is_floating(rec):
        return topology_floating(args, rec)
    kw: dict[str, Any] = {}
    if args.method != "fast":
        kw["seed"] = args.seed
        kw["progress"] = not args.json
        if args.epochs is not None:
            kw["epochs"] = args.epochs
    delay = None if args.imu_delay_ms is None else 1e-3 * args.imu_delay_ms
    topo = estimate_topology(rec, method=args.method, timer=time.process_time, imu_delay=delay, **kw)
    if args.json:
        print(json.dumps(topo.to_json(), indent=2))
    else:
        print(format_tree(topo))
    if args.plot is not None:
        truth = None
        if rec.truth_parent_map is not None and rec.truth_imu_map is not None:
            truth = Topology(joint_parent=rec.truth_parent_map, imu_joint=rec.truth_imu_map)
        plot_trees(topo, args.plot, truth=truth, title=f"{args.recording.name} ({args.method})")
        if not args.json:
            print(f"plot written to {args.plot}")
    return 0


def _imus_by_joint(topo: Topology) -> dict[str | None, list[str]]:
    out: dict[str | None, list[str]] = {}
    for imu, j in topo.imu_joint.items():
        out.setdefault(j, []).append(imu)
    return out


def format_tree(topo: Topology) -> str:
    """The tree as indented text: one line per joint with its confidence and the IMUs on its link.

    >>> from bodyschema.topology import Topology
    >>> t = Topology({"j1": None, "j2": "j1"}, {"a": "j1", "b": "j2", "c": None},
    ...              confidence={"joint:j1": 1.0, "joint:j2": 0.5}, method="fast", seconds=0.1)
    >>> print(format_tree(t))
    base  [imus: c]
    └── j1  (1.00)  [imus: a]
        └── j2  (0.50)  [imus: b]
    method fast, 0.10 CPU s, unique
    """
    from bodyschema.diff import UNDETERMINED_HERE, open_parts

    open_ = open_parts(topo)  # parts the data did not place are listed apart, never as on a link
    imus = {j: [i for i in v if f"imu:{i}" not in open_] for j, v in _imus_by_joint(topo).items()}
    und = set(topo.undetermined)
    lines = ["base" + (f"  [imus: {', '.join(imus[None])}]" if imus.get(None) else "")]

    def walk(parent: str | None, prefix: str) -> None:
        kids = [j for j in topo.joint_parent if topo.joint_parent[j] == parent and j not in und]
        for i, j in enumerate(kids):
            last = i == len(kids) - 1
            conf = topo.confidence.get(f"joint:{j}")
            text = f"{j}" + (f"  ({conf:.2f})" if conf is not None else "")
            if imus.get(j):
                text += f"  [imus: {', '.join(imus[j])}]"
            lines.append(prefix + ("└── " if last else "├── ") + text)
            walk(j, prefix + ("    " if last else "│   "))

    walk(None, "")
    if und:
        lines.append("insufficient excitation (undetermined): " + ", ".join(sorted(und)))
    if open_:
        lines.append(f"{UNDETERMINED_HERE}: " + "; ".join(open_.values()))
    tail = f"method {topo.method}, {topo.seconds:.2f} CPU s, "
    tail += "unique" if topo.unique else f"not unique: {1 + len(topo.candidates)} trees fit the data"
    lines.append(tail)
    if not topo.unique:
        from bodyschema.diff import undetermined_reasons

        lines += list(undetermined_reasons(topo))[1:]  # the first repeats the count above
    if topo.timing:
        tm = topo.timing
        drift = f"drift {tm['drift_ppm']:.0f} ppm" if "drift_ppm" in tm else "drift not estimated (< 30 s)"
        unc = f" ± {tm['lag_unc_ms']:.2f}" if "lag_unc_ms" in tm else ""
        lines.append(
            f"IMU-to-encoder skew {tm['skew_ms']:.2f}{unc} ms (IMU lag {tm['lag_ms']:.2f} ms at "
            f"{tm['at_s']:.1f} s, {drift}, compared below {tm['band_hz']:.1f} Hz)"
        )
    if topo.training:
        tr = topo.training
        state = "converged" if tr.get("converged") else "stopped at its epoch bound"
        lines.append(f"networks trained {tr['epochs']:.0f} epochs ({state})")
    return "\n".join(lines)


def _layout(topo: Topology) -> tuple[dict[str, tuple[float, float]], list[tuple[str, str]]]:
    """Node positions (leaves spread on x, depth down y) and edges for a tree; node 'base' is the root."""
    children: dict[str, list[str]] = {"base": []}
    for j in topo.joint_parent:
        children.setdefault(j, [])
    for j, p in topo.joint_parent.items():
        children[p or "base"].append(j)
    pos: dict[str, tuple[float, float]] = {}
    counter = [0.0]

    def place(node: str, depth: int) -> float:
        kids = children[node]
        if not kids:
            x = counter[0]
            counter[0] += 1.0
        else:
            xs = [place(k, depth + 1) for k in kids]
            x = sum(xs) / len(xs)
        pos[node] = (x, -float(depth))
        return x

    place("base", 0)
    edges = [(p or "base", j) for j, p in topo.joint_parent.items()]
    return pos, edges


def plot_trees(topo: Topology, path: Path, truth: Topology | None = None, title: str = "") -> None:
    """Draw the learned tree (and the truth beside it); joints that differ from the truth in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    panels = [("learned", topo)] + ([("truth", truth)] if truth is not None else [])
    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 5.5), squeeze=False)
    for ax, (name, t) in zip(axes[0], panels, strict=True):
        pos, edges = _layout(t)
        imus = _imus_by_joint(t)
        for a, b in edges:
            ax.plot([pos[a][0], pos[b][0]], [pos[a][1], pos[b][1]], color="0.6", zorder=1)
        for node, (x, y) in pos.items():
            wrong = (
                name == "learned"
                and truth is not None
                and node != "base"
                and (
                    truth.joint_parent.get(node, "?") != t.joint_parent.get(node)
                    or sorted(imus.get(node, [])) != sorted(_imus_by_joint(truth).get(node, []))
                )
            )
            color = "tab:red" if wrong else ("0.85" if node in t.undetermined else "tab:blue")
            ax.scatter([x], [y], s=60, color=color, zorder=2)
            ax.annotate(
                node,
                (x, y),
                xytext=(5, 2),
                textcoords="offset points",
                ha="left",
                va="bottom",
                fontsize=7,
                color=color if wrong else "black",
                zorder=3,
            )
            riders = imus.get(None if node == "base" else node, [])
            if riders:
                label = ", ".join(riders[:3]) + (f" +{len(riders) - 3}" if len(riders) > 3 else "")
                ax.annotate(
                    label,
                    (x, y),
                    xytext=(5, -3),
                    textcoords="offset points",
                    ha="left",
                    va="top",
                    fontsize=6,
                    color="0.35",
                )
        sub = f"{name}" + ("" if t.unique else f" (not unique, {1 + len(t.candidates)} trees)")
        ax.set_title(sub)
        ax.axis("off")
    if title:
        fig.suptitle(title)
    save_figure(fig, path, dpi=120)
