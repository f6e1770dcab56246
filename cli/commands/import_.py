"""``bodyhealth import FORMAT FILE --out rec.npz``: convert measured data into a docs/design.md §2 recording.

Formats: ``broad`` (a BROAD trial, HDF5: one IMU plus optical motion capture; see :mod:`sim2real.broad`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="convert measured data (BROAD HDF5) into a recording (.npz)")
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
