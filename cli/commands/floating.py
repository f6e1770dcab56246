"""The floating-base branch of ``bodyhealth diff`` and ``bodyhealth topology``.

A recording of a walking robot (:func:`bodyschema.stance_chains.floating_base_rule`: a
``floating_base`` flag, or foot forces) has one IMU on a base that no encoder moves: the fixed-base
estimators have nothing to place. ``diff`` then runs :func:`bodyschema.floating_health.floating_diff`
and ``topology`` prints the stance chains (:func:`bodyschema.stance_chains.stance_chains`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bodyschema.recording import Recording

__all__ = ["diff_floating", "is_floating", "topology_floating"]


def is_floating(*recs: Recording) -> bool:
    """True when every recording is of a floating-base robot."""
    from bodyschema.stance_chains import floating_base_rule

    return all(floating_base_rule(r)[0] for r in recs)


def diff_floating(
    args: argparse.Namespace,
    base: Recording,
    cur: Recording,
    format_diff: Callable[[dict[str, Any]], str],
    exit_undetermined: int,
) -> int:
    """``bodyhealth diff`` on two floating-base recordings (``format_diff`` and the undetermined exit
    code come from the diff command, which calls this)."""
    from bodyschema.floating_health import floating_diff

    t0 = time.process_time()
    try:
        diff = floating_diff(base, cur)
    except ValueError as err:
        print(f"bodyhealth diff: {err}", file=sys.stderr)
        return 2
    out = {**diff.to_json(), "floating_base": True, "seconds": round(time.process_time() - t0, 3)}
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(f"floating base: {args.baseline} -> {args.current} ({out['seconds']:.2f} CPU s)")
        print(format_diff(out))
    if not args.exit_code:
        return 0
    return {True: 1, False: 0, None: exit_undetermined}[diff.changed]


def topology_floating(args: argparse.Namespace, rec: Recording) -> int:
    """``bodyhealth topology`` on a floating-base recording: the stance chain of each contact phase."""
    from bodyschema.stance_chains import stance_chains

    t0 = time.process_time()
    res = stance_chains(rec)
    out = {**res.to_json(), "method": "stance_chains", "seconds": round(time.process_time() - t0, 3)}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"floating base ({res.rule}); contacts from {res.contacts}")
    for p in res.chains:
        print(
            f"  {p.phase} ({p.phase_fraction:.0%}): {' -> '.join(p.joints)}  (confidence {p.confidence:.3f})"
        )
    for p in res.undetermined:
        print(f"  {p.phase} ({p.phase_fraction:.0%}): undetermined: {p.reason}; to decide: {p.decide}")
    print(f"method stance_chains, {out['seconds']:.2f} CPU s")
    return 0
