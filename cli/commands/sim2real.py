"""``bodyhealth sim2real REC.npz``: what the simulation gets wrong about a measured IMU, and why.

Prints the causes in order with parameters, uncertainty and held-out gain (``--json``: the discrepancy
JSON of docs/design.md), writes the extended IMU model in the simulator's format (``--out``), and a report
with residual plots before/after (``--report DIR``). ``--transfer OTHER.npz ...`` checks the fitted
model end to end on recordings that were not used for the fit.

``--encoders`` (robot recordings, with ``--model``) names what the robot's encoders get wrong, seen
through all its IMUs at once: the encoder-to-IMU time offset, per joint zero offsets, gear ratios and
dead bands, each with its value and interval, or its detection limit where it is not named
(:mod:`bodyschema.discrepancy.encoders`; ``--json``: the report as JSON).

``--model ROBOT.urdf`` on a walking robot's log (joint positions, foot forces, no reference motion; a
URDF with ``*_sole`` or ``*_foot`` links) predicts the base IMU by the rigid model over the stance feet,
and from motion capture of the base where the log has it, and names what the rigid model gets wrong
(:func:`sim2real.robots.robot_sim2real`; docs/robots.md). ``--cutoff`` then defaults to the band the
encoders' quantization allows.

``--gravity-case`` (robot recordings, ``q`` with gravity) also trains the paper's sensor networks without
gravity (Eq. 11) and with it (Eq. 24), and adds their residuals, the cause the analysis names for the
Eq. 11 residual and each form's topology accuracy (``gravity_case`` in the JSON; ``gravity_case.*`` in
the report). With ``--model`` the cause is also analysed on the robot's exact kinematics; without it
only the gravity case runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bodyschema.discrepancy import DiscrepancyReport
    from bodyschema.discrepancy.network_gravity import GravityCase
    from bodyschema.recording import Recording
    from bodyschema.rigid_motion import ReferenceMotion
    from simulators.imu_model import ImuModel

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim2real",
        help="name the effects that make a measured IMU differ from the simulation; fit an IMU model",
    )
    p.add_argument("recording", type=Path, help="recording (.npz) with a reference motion (ref_quat/ref_pos)")
    p.add_argument(
        "--model",
        default=None,
        help="robot (catalog name or MJCF file) for recordings of a robot (q instead of ref_quat)",
    )
    p.add_argument("--imu", default=None, help="IMU name (default: every IMU of the recording)")
    p.add_argument("--json", action="store_true", help="print the discrepancy JSON")
    p.add_argument("--out", type=Path, default=None, help="write the fitted IMU model (simulator JSON)")
    p.add_argument(
        "--kalibr",
        type=Path,
        default=None,
        help="write the IMU's noise densities, bias random walks and rate as a Kalibr imu.yaml",
    )
    p.add_argument("--report", type=Path, default=None, help="write report.md, JSON and PNG plots here")
    p.add_argument("--transfer", type=Path, nargs="*", default=(), help="recordings to test the fit on")
    p.add_argument(
        "--cutoff",
        type=float,
        default=None,
        help="common low-pass of both sides, Hz (10; a walking robot's URDF: from its encoder quantization)",
    )
    p.add_argument("--blocks", type=int, default=8, help="held-out time blocks")
    p.add_argument("--alpha", type=float, default=0.01, help="family significance level of a round's tests")
    p.add_argument(
        "--min-gain", type=float, default=0.005, help="least held-out gain to accept (share of the channel)"
    )
    p.add_argument(
        "--gravity-case",
        action="store_true",
        help="train the sensor networks without (Eq. 11) and with (Eq. 24) gravity: residuals, named cause, "
        "topology accuracy",
    )
    p.add_argument(
        "--encoders",
        action="store_true",
        help="with --model: the encoder effects (time offset, zero offsets, gear ratios, backlash) instead",
    )
    p.add_argument("--epochs", type=int, default=40, help="sensor-network epochs (--gravity-case)")
    p.add_argument("--seed", type=int, default=0, help="sensor-network seed (--gravity-case)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from simulators.recording_io import load_recording

    rec = load_recording(args.recording)
    if _floating_base(rec, args):
        return _robot(rec, args)
    if args.cutoff is None:
        args.cutoff = 10.0
    if args.encoders:
        return _encoders(rec, args)
    refs = _robot_references(rec, args)
    imus = _chosen_imus(rec, args)
    case = _gravity_case(rec, args, refs) if args.gravity_case else None
    if case is not None and rec.ref_quat is None and refs is None:
        imus = []  # nothing to compare the IMUs with but the networks
    results = _analyze_imus(rec, args, refs, imus)
    if case is not None and args.report:
        from sim2real.report import write_gravity_case

        write_gravity_case(case, args.report, title=args.recording.stem)
    if args.out and imus:
        _save_models(args, imus, results)
    if args.kalibr and imus:
        _save_kalibr(args, imus, results)
    if args.json:
        _print_json(imus, results, case)
    else:
        _print_summaries(args, results, case)
    return 0


def _encoders(rec: Recording, args: argparse.Namespace) -> int:
    """``--encoders``: the encoder effects of a robot recording against ``--model``."""
    from bodyschema.discrepancy.encoders import EncoderOptions
    from sim2real.encoders import encoder_analysis

    if args.model is None:
        raise ValueError("--encoders compares the recording with a robot model: give --model")
    report = encoder_analysis(rec, args.model, EncoderOptions(alpha=args.alpha, min_gain=args.min_gain))
    if args.json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        print(f"== {args.recording.name} encoders against {args.model}")
        print("\n".join(report.summary()))
    return 0


def _floating_base(rec: Recording, args: argparse.Namespace) -> bool:
    """A walking robot's log against its URDF: ``--model`` names a ``.urdf`` file, the recording has
    joint positions and no reference motion, and neither ``--encoders`` nor ``--gravity-case`` asks
    for the fixed-base analyses."""
    model = str(args.model or "")
    return (
        model.lower().endswith(".urdf")
        and Path(model).is_file()
        and rec.q is not None
        and rec.ref_quat is None
        and not args.encoders
        and not args.gravity_case
        and _has_feet(model)
    )


def _has_feet(model: str) -> bool:
    """Whether the URDF has feet (``*_sole`` or ``*_foot`` links) for the floating-base analysis."""
    import re

    return re.search(r'<link\s+name="[^"]*_(sole|foot)"', Path(model).read_text(errors="replace")) is not None


def _robot(rec: Recording, args: argparse.Namespace) -> int:
    """A floating-base robot's base IMU against its rigid model (:func:`sim2real.robots.robot_sim2real`)."""
    from sim2real.robots import RobotOptions, robot_sim2real
    from sim2real.robots_report import format_robot

    imu = rec.imu_names.index(args.imu) if args.imu else 0
    opts = RobotOptions(cutoff=args.cutoff, n_blocks=args.blocks, alpha=args.alpha, min_gain=args.min_gain)
    out = robot_sim2real(rec, args.model, opts, imu)
    if args.report:
        args.report.mkdir(parents=True, exist_ok=True)
        (args.report / "robot_sim2real.json").write_text(json.dumps(out, indent=2))
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"== {args.recording.name} {out['imu']} against {args.model}")
        print("\n".join(format_robot(out)))
    return 0


def _robot_references(rec: Recording, args: argparse.Namespace) -> dict[str, ReferenceMotion] | None:
    """The reference motion of each IMU site from the robot model, for a recording without ``ref_quat``
    (None when it has one, or when only the gravity case runs)."""
    if rec.ref_quat is not None:
        return None
    if args.model is None and not args.gravity_case:
        raise ValueError(f"{args.recording}: no reference motion (ref_quat); a robot recording needs --model")
    if args.model is None:
        return None
    from sim2real.report import robot_references

    return robot_references(rec, args.model, cutoff=args.cutoff)


def _chosen_imus(rec: Recording, args: argparse.Namespace) -> list[str]:
    imus = [args.imu] if args.imu else list(rec.imu_names)
    unknown = [i for i in imus if i not in rec.imu_names]
    if unknown:
        raise ValueError(f"IMUs {unknown} not in the recording ({list(rec.imu_names)})")
    return imus


#: Per IMU: its discrepancy report, the fitted IMU model, and the transfer checks by recording name.
_Result = tuple["DiscrepancyReport", "ImuModel", dict[str, dict[str, float]]]


def _analyze_imus(
    rec: Recording, args: argparse.Namespace, refs: dict[str, ReferenceMotion] | None, imus: list[str]
) -> dict[str, _Result]:
    """Per IMU: the discrepancy report, the fitted IMU model and its transfers (written as a report
    under ``--report`` as each IMU finishes)."""
    from sim2real.report import to_imu_model, write_report

    results: dict[str, _Result] = {}
    kw = {
        "n_blocks": args.blocks,
        "alpha": args.alpha,
        "min_gain": args.min_gain,
        "progress": sys.stderr.isatty(),
    }
    for imu in imus:
        rep = _analyze_imu(rec, args, refs, imu, kw)
        model = to_imu_model(rep.params, name=f"{args.recording.stem}:{imu}")
        transfers = _transfers(args, refs, imu, model)
        results[imu] = (rep, model, transfers)
        if args.report:
            out = args.report if len(imus) == 1 else args.report / imu
            write_report(rep, out, title=f"{args.recording.stem} {imu}", transfers=transfers or None)
    return results


def _analyze_imu(
    rec: Recording,
    args: argparse.Namespace,
    refs: dict[str, ReferenceMotion] | None,
    imu: str,
    kw: dict[str, Any],
) -> DiscrepancyReport:
    """One IMU against the recording's reference motion, or against the robot's kinematics (``refs``)."""
    from bodyschema.discrepancy import analyze, analyze_recording

    if refs is None:
        return analyze_recording(rec, imu, cutoff=args.cutoff, **kw)
    if imu not in refs:
        raise ValueError(f"IMU {imu!r} is not a site of {args.model}")
    k = rec.imu_names.index(imu)
    rep = analyze(refs[imu], rec.gyro[:, k], rec.acc[:, k], cutoff=args.cutoff, **kw)
    rep.meta.update({"imu": imu, "robot": args.model, "source": str(args.recording)})
    return rep


def _transfers(
    args: argparse.Namespace, refs: dict[str, ReferenceMotion] | None, imu: str, model: ImuModel
) -> dict[str, dict[str, float]]:
    """The fitted model checked on each ``--transfer`` recording (only without robot references)."""
    from sim2real.report import transfer
    from simulators.recording_io import load_recording

    transfers = {}
    for other in args.transfer if refs is None else ():
        orec = load_recording(other)
        k = orec.imu_names.index(imu) if imu in orec.imu_names else 0
        transfers[other.stem] = transfer(orec, model, cutoff=args.cutoff, imu=k)
    return transfers


def _save_models(args: argparse.Namespace, imus: list[str], results: dict[str, _Result]) -> None:
    """``--out`` itself for one IMU; one file per IMU (``STEM_IMU.SUFFIX``) for several."""
    from simulators.imu_model import save_imu_model

    if len(imus) > 1:
        for imu, (_, model, _) in results.items():
            save_imu_model(model, args.out.with_name(f"{args.out.stem}_{imu}{args.out.suffix}"))
    else:
        save_imu_model(results[imus[0]][1], args.out)


def _save_kalibr(args: argparse.Namespace, imus: list[str], results: dict[str, _Result]) -> None:
    """``--kalibr`` itself for one IMU; one file per IMU (``STEM_IMU.SUFFIX``) for several."""
    from sim2real.kalibr import write_kalibr_imu

    for imu, (rep, _, _) in results.items():
        one = len(imus) == 1
        path = args.kalibr if one else args.kalibr.with_name(f"{args.kalibr.stem}_{imu}{args.kalibr.suffix}")
        write_kalibr_imu(rep, path, rostopic=f"/{imu}")


def _print_json(imus: list[str], results: dict[str, _Result], case: GravityCase | None) -> None:
    """One IMU's discrepancy JSON as it is, several keyed by IMU name."""
    docs = {}
    for imu, (rep, _, transfers) in results.items():
        d = rep.to_json()
        if transfers:
            d["transfer"] = transfers
        docs[imu] = d
    out = docs[imus[0]] if len(imus) == 1 else docs
    if case is not None:
        out["gravity_case"] = case.to_json()
    print(json.dumps(out, indent=2))


def _print_summaries(args: argparse.Namespace, results: dict[str, _Result], case: GravityCase | None) -> None:
    from sim2real.report import format_summary

    for imu, (rep, _, transfers) in results.items():
        print(f"== {args.recording.name} {imu}")
        print(format_summary(rep))
        for name, tr in transfers.items():
            print(
                f"transfer to {name}: gyro {tr['gyro_rms_default']:.4f} -> {tr['gyro_rms_model']:.4f} "
                f"rad/s, acc {tr['acc_rms_default']:.4f} -> {tr['acc_rms_model']:.4f} m/s², "
                f"gain {tr['gain']:.3f}"
            )
        if rep.meta.get("attribution"):
            print(f"data: {rep.meta['attribution']}")
    if case is not None:
        from sim2real.report import format_gravity_case

        print(f"== {args.recording.name} gravity case")
        print(format_gravity_case(case))


def _gravity_case(
    rec: Recording, args: argparse.Namespace, refs: dict[str, ReferenceMotion] | None
) -> GravityCase:
    from bodyschema.discrepancy.network_gravity import gravity_case

    imus = [args.imu] if args.imu else None
    return gravity_case(
        rec,
        epochs=args.epochs,
        seed=args.seed,
        imus=imus,
        references=refs,
        cutoff=args.cutoff,
        n_blocks=args.blocks,
        alpha=args.alpha,
        min_gain=args.min_gain,
        progress=sys.stderr.isatty(),
    )
