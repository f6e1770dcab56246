"""``bodyhealth inject REC.npz --fault KIND:key=value,... -o OUT.npz``: a recording with a sensor fault.

Faults and their parameters: :mod:`bodyschema.faults`. The fault is recorded in the written file's
``injected_faults`` extra, so a benchmark or test knows the truth; estimators never read it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inject",
        help="write a copy of a recording with a sensor fault injected (for testing health checks)",
        description="Inject encoder_frozen, encoder_offset, encoder_sign, imu_rotated or imu_silent "
        "into a recording, e.g. --fault encoder_offset:joint=r_hip_roll,deg=2,at=10 (at: seconds from "
        "the start, default 0; 'random' draws it from --seed).",
    )
    p.add_argument("recording", type=Path, metavar="REC.npz")
    p.add_argument("--fault", action="append", required=True, metavar="KIND:key=value,...", help="repeatable")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUT.npz")
    p.add_argument("--seed", type=int, default=0, help="seed for at=random (default 0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bodyschema.faults import FaultError, inject_all, parse_fault
    from bodyschema.recording import RecordingError
    from simulators.recording_io import load_recording, save_recording

    try:
        faults = [parse_fault(s) for s in args.fault]
        rec = inject_all(load_recording(args.recording), faults, seed=args.seed)
        save_recording(rec, args.out)
    except (FaultError, RecordingError, OSError) as err:
        print(f"bodyhealth inject: {err}", file=sys.stderr)
        return 2
    print(f"{args.out}: {', '.join(args.fault)}")
    return 0
