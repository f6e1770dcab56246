"""``bodyhealth robots``: the simulator catalog with joint and IMU counts."""

from __future__ import annotations

import argparse
import json

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("robots", help="list the simulated robots (catalog names, joints, IMUs)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=_robots)


def _robots(args: argparse.Namespace) -> int:
    from simulators.catalog import CATALOG, describe

    rows = []
    for name in CATALOG:
        d = describe(name)
        rows.append({"name": name, "joints": d.n_joints, "imus": d.n_imus, "summary": d.summary})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    width = max(len(r["name"]) for r in rows)
    print(f"{'robot':<{width}}  joints  imus  description")
    for r in rows:
        print(f"{r['name']:<{width}}  {r['joints']:>6}  {r['imus']:>4}  {r['summary']}")
    return 0
