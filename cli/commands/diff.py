"""``bodyhealth diff BASELINE.npz CURRENT.npz [--json]``: the monitoring diff, offline.

Both recordings are estimated with the same method, the current one's signal health is judged with the
baseline as layout, and :func:`bodyschema.diff.diff_bodies` names the differences: the diff JSON
(docs/design.md, exchange formats) with ``--json``, a readable listing otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

__all__ = ["EXIT_UNDETERMINED", "format_diff", "register", "run"]

METHODS = ("fast", "network", "network-paper", "mlp")
#: ``--exit-code`` answer when several bodies fit (0 = unchanged, 1 = changed, 2 = usage error)
EXIT_UNDETERMINED = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diff",
        help="compare the body learned from two recordings (baseline, current): typed damage findings",
        description="Learn the body from each recording and list what changed (with --json: the diff JSON "
        "of docs/design.md, exchange formats).",
    )
    p.add_argument("baseline", help="recording (.npz) of the healthy body")
    p.add_argument("current", help="recording (.npz) to check")
    p.add_argument("--json", action="store_true", help="print the diff JSON (docs/design.md)")
    p.add_argument("--method", choices=METHODS, default="fast", help="topology estimator (default fast)")
    p.add_argument(
        "--exit-code",
        action="store_true",
        help=f"exit 0 when the body is unchanged, 1 when a damage is found (like git diff), "
        f"{EXIT_UNDETERMINED} when the data cannot decide (several bodies fit)",
    )
    p.set_defaults(func=run)


def format_diff(diff: dict[str, Any]) -> str:
    """A readable listing of a diff JSON (docs/design.md, exchange formats).

    >>> print(format_diff({"changed": True, "findings": [
    ...     {"kind": "imu_moved", "imu": "imu3", "from": "j2", "to": "j4", "confidence": 0.97}]}))
    body changed: 1 finding
      imu_moved                imu:imu3      j2 -> j4  (confidence 0.97)
    >>> print(format_diff({"changed": False, "findings": []}))
    no change: the current body matches the baseline
    >>> print(format_diff({"changed": None, "findings": [], "reasons": ["2 trees fit the data"]}))
    undetermined: 2 trees fit the data
    """
    findings = diff.get("findings", [])
    reasons = [f"undetermined: {r}" for r in diff.get("reasons", [])] if diff.get("changed") is None else []
    if not findings:
        return "\n".join(reasons) or "no change: the current body matches the baseline"
    head = "body changed" if diff.get("changed") else "no damage"
    lines = [f"{head}: {len(findings)} finding{'s' if len(findings) != 1 else ''}"]
    for f in findings:
        part = f"imu:{f['imu']}" if f.get("imu") is not None else f"joint:{f.get('joint')}"
        what = ""
        if "from" in f or "to" in f:
            what = f"{f.get('from') or 'base'} -> {f.get('to') or 'base'}"
        elif f.get("detail"):
            what = str(f["detail"])
        lines.append(f"  {f['kind']:<24} {part:<13} {what}  (confidence {float(f.get('confidence', 1)):.2f})")
    return "\n".join(lines + reasons)


def run(args: argparse.Namespace) -> int:
    from bodyschema.diff import diff_bodies
    from bodyschema.estimate import estimate_topology
    from bodyschema.health import signal_health
    from simulators.recording_io import load_recording

    base_rec = load_recording(args.baseline)
    cur_rec = load_recording(args.current)
    from cli.commands.floating import diff_floating, is_floating

    if is_floating(base_rec, cur_rec):
        return diff_floating(args, base_rec, cur_rec, format_diff, EXIT_UNDETERMINED)
    base = estimate_topology(base_rec, method=args.method, timer=time.process_time)
    cur = estimate_topology(cur_rec, method=args.method, timer=time.process_time)
    health = signal_health(cur_rec, base, expected_imus=base_rec.imu_names)
    diff = diff_bodies(base, cur, health)
    out = diff.to_json()
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(
            f"baseline {args.baseline}: {len(base.joint_parent)} joints, {len(base.imu_joint)} IMUs "
            f"({base.method}, {base.seconds:.2f} s)"
        )
        print(
            f"current  {args.current}: {len(cur.joint_parent)} joints, {len(cur.imu_joint)} IMUs "
            f"({cur.method}, {cur.seconds:.2f} s)"
        )
        print(format_diff(out))
    if not args.exit_code:
        return 0
    return {True: 1, False: 0, None: EXIT_UNDETERMINED}[diff.changed]
