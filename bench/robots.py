"""Health and body schema on the two measured floating-base robots (iCub walking, Go1 trotting).

Per log: the stance chains of each contact phase (or why undetermined), findings per 10 s window
of the untouched log against its first half; for each injected fault (two joints or windows each,
offsets on two joints in two windows) whether it was found, with the right kind, and at which rank,
or undetermined where the recording cannot show it; the service's alerts on each untouched log
replayed in a loop (:mod:`bench.robots_replay`); CPU seconds throughout; the rigid model's held-out
gains (:func:`sim2real.robots.robot_sim2real`) beside them. Writes ``robots.{json,md,png}``.

Data: iCub walking log (github.com/ami-iit/kindyn-vio, LGPL-3.0 on its devel branch, Copyright IIT);
Go1 trot log (github.com/mrsp/serow, GPL-3.0). See data/robots/README.md.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import REPO_ROOT, RESULTS_DIR, fmt, machine_note, write_results

__all__ = ["add_arguments", "run"]

ROBOTS = Path(os.environ.get("BODYHEALTH_ROBOTS_DIR") or REPO_ROOT.parent / "shared" / "data" / "robots")
LOGS = {
    "icub": ("icub-walking/sync-walkingFrontAndBackGoodTrial.mat", "icub-walking.toml", "mat",
             "icub-walking/iCubGenova04.urdf", ("r_hip_roll", "l_knee")),
    "go1": ("go1-trot/go1.csv", "go1-trot.toml", "csv", "go1-trot/go1.urdf", ("RL_thigh", "FR_calf")),
}  # fmt: skip
#: fault -> the finding kind that must come first, and whether it names the joint or the IMU
FAULTS = {
    "encoder_frozen": ("encoder_fault", "joint={j},at=2"),
    "encoder_offset": ("encoder_fault", "joint={j},deg=2"),
    "encoder_sign": ("encoder_fault", "joint={j}"),
    "encoder_sign mid-window": ("encoder_fault", "joint={j},at=3"),
    "imu_rotated": ("imu_rotated", "imu={i},deg=2"),
    "imu_silent": ("imu_dead", "imu={i},seconds=2,at=3"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data", type=Path, default=ROBOTS, help="folder holding go1-trot/ and icub-walking/"
    )
    parser.add_argument("--no-sim2real", action="store_true", help="skip the rigid model's gains")
    parser.add_argument(
        "--replay-minutes", type=float, default=30.0, help="log minutes of looped service replay (0: skip)"
    )
    parser.add_argument("--replay-speed", type=float, default=10.0, help="replay speed (x real time)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _cpu(fn, *a):
    t0 = time.process_time()
    out = fn(*a)
    return out, time.process_time() - t0


def _faults(rec, base, wins, joints) -> list[dict[str, Any]]:
    from bodyschema.faults import inject, parse_fault
    from bodyschema.floating_health import floating_diff

    rows = []
    imu = rec.imu_names[0]
    for name, (kind, _) in FAULTS.items():
        fault = name.split()[0]
        if fault == "encoder_offset":  # the tilt it causes is judged per window: two of each
            targets = [(j, w) for j in joints for w in wins[:2]]
        elif fault.startswith("encoder"):
            targets = [(j, wins[0]) for j in joints]
        else:
            targets = [(imu, w) for w in wins[:2]]
        for part, win in targets:
            spec = _spec(name, part)
            d, cpu = _cpu(floating_diff, base, inject(win, parse_fault(spec)))
            ranks = [k + 1 for k, f in enumerate(d.findings) if f.kind == kind and _names(f, part)]
            why = None if ranks else _undetermined(name, base) or _between(d.findings, kind, part)
            rows.append({
                "fault": name, "spec": spec, "window_start_s": round(float(win.t[0] - rec.t[0]), 2),
                "expected": kind, "found": bool(ranks), "rank": ranks[0] if ranks else None,
                "first": d.findings[0].to_json() if d.findings else None, "cpu_s": round(cpu, 3),
                "undetermined": why,
            })  # fmt: skip
    return rows


def _spec(name: str, part: str) -> str:
    """The fault spec of :data:`FAULTS` entry ``name`` on ``part`` (a joint or the IMU)."""
    return f"{name.split()[0]}:" + FAULTS[name][1].format(j=part, i=part)


def _names(f, part: str) -> bool:
    """Whether finding ``f`` names ``part`` alone (no rival part fits as well)."""
    return part in (f.joint, f.imu) and not f.candidates


def _between(findings, kind: str, part: str) -> str | None:
    """Why ``part`` was left undetermined: a finding of the right kind holds it among parts the data
    fit equally well (None: none does)."""
    for f in findings:
        names = {p.split(":", 1)[1] for p in (f.part, *f.candidates)}
        if f.kind == kind and f.candidates and part in names:
            return f"{kind} on one of {', '.join(sorted(names))}: they fit alike"
    return None


def _undetermined(name: str, base) -> str | None:
    """Why a fault (a key of :data:`FAULTS`) the recording cannot show was not found (None: it could be)."""
    if name in ("encoder_offset", "imu_rotated") and base.tilt is None:
        return "no flat-foot stance chain: no leg predicts the gravity the IMU reads"
    if name == "encoder_sign" and not base.chains:
        return (
            "no stance chain: a reading flipped over the whole window shows only by the jump where the "
            "flip begins, outside the window"
        )
    return None


def _replay(rec, name: str, args: argparse.Namespace) -> dict[str, Any]:
    """The service's alerts on the untouched log replayed in a loop."""
    import tempfile

    from bench.robots_replay import replay_alerts
    from simulators.recording_io import save_recording

    with tempfile.TemporaryDirectory(prefix="bench-robots-") as tmp:
        path = Path(tmp) / f"{name}.npz"
        save_recording(rec, path)
        minutes, speed = args.replay_minutes, args.replay_speed
        return replay_alerts(path, name, minutes, speed, float(min(rec.t[0], rec.encoder_t[0])))


def _one(name: str, data: Path, sim2real: bool) -> dict[str, Any]:
    from bodyschema.floating_health import floating_baseline, floating_diff
    from bodyschema.stance_chains import stance_chains
    from sim2real.robot_logs import import_log

    path, mp, fmt, urdf, joints = LOGS[name]
    rec = import_log(data / path, REPO_ROOT / "examples" / "import" / mp, fmt)[0]
    chains, chain_cpu = _cpu(stance_chains, rec)
    half = rec.t[0] + rec.duration / 2
    base, base_cpu = _cpu(floating_baseline, rec.window(rec.t[0], half))
    starts = np.arange(rec.t[0], rec.t[-1] - 10 + 1e-9, 10.0)
    untouched = []
    for s in starts:
        d, cpu = _cpu(floating_diff, base, rec.window(s, s + 10))
        untouched.append(
            {"start_s": round(float(s - rec.t[0]), 2), "findings": len(d.findings), "cpu_s": round(cpu, 3)}
        )
    halves = floating_diff(base, rec.window(half, rec.t[-1] + 1))
    wins = [rec.window(s, s + 10) for s in np.arange(half, rec.t[-1] - 10 + 1e-9, 10.0)]
    out: dict[str, Any] = {
        "log": path, "samples": rec.n_samples, "seconds": round(rec.duration, 2),
        "stance_chains": chains.to_json(), "stance_chains_cpu_s": round(chain_cpu, 2),
        "baseline_cpu_s": round(base_cpu, 2), "half_vs_half_findings": len(halves.findings),
        "untouched_windows": untouched, "faults": _faults(rec, base, wins, joints),
    }  # fmt: skip
    if sim2real:
        try:
            from sim2real.robots import robot_sim2real

            s2r, cpu = _cpu(robot_sim2real, rec, data / urdf)
            out["sim2real"] = {"result": _jsonable(s2r), "cpu_s": round(cpu, 2)}
        except Exception as err:  # the other model's failure must not lose this bench's figures
            out["sim2real"] = {"error": f"{type(err).__name__}: {err}"}
        out["foot_plane"] = _foot_plane(rec, data / urdf, joints)
    return out


def _foot_plane(rec: Any, urdf: Path, joints: tuple[str, ...]) -> dict[str, Any]:
    """The feet's plane against the IMU's gravity, and the shift of the 2° offsets and mount turn."""
    from sim2real.foot_plane import foot_plane_tilt
    from sim2real.robots import read_robot

    specs = [_spec("encoder_offset", j) for j in joints] + [_spec("imu_rotated", rec.imu_names[0])]
    return foot_plane_tilt(rec, read_robot(urdf, rec.joint_names), specs)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x if isinstance(x, (str, int, float, bool, type(None))) else str(x)


def _markdown(res: dict[str, Any]) -> str:
    lines = ["# Health and stance chains on the measured robots", "", f"Machine: {machine_note()}", ""]
    for name, r in res.items():
        sc = r["stance_chains"]
        lines += [f"## {name}: {r['log']} ({r['samples']} samples, {r['seconds']} s)", ""]
        lines += [f"Stance chains ({r['stance_chains_cpu_s']} CPU s), contacts from {sc['contacts']}:", ""]
        for c in sc["chains"]:
            lines.append(
                f"* {c['phase']} ({c['phase_fraction']:.0%}): {' -> '.join(c['joints'])} (confidence "
                f"{c['confidence']:.3f}, residual {c.get('floor_ratio')}x the error floor)"
            )
        for u in sc["undetermined"]:
            lines.append(f"* {u['phase']} ({u['phase_fraction']:.0%}): undetermined: {u['reason']}")
        n = [w["findings"] for w in r["untouched_windows"]]
        lines += ["", f"Untouched: first half vs second half {r['half_vs_half_findings']} findings; "
                  f"{len(n)} windows of 10 s vs the first half: {sum(n)} findings in all (max {max(n)} per "
                  f"window). Baseline learned in {r['baseline_cpu_s']} CPU s.", "",
                  "| fault | window start (s) | expected | found | rank | first finding | CPU s |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
        for f in r["faults"]:
            first = f["first"]
            fs = "—" if first is None else f"{first['kind']} {first.get('joint') or first.get('imu')}"
            found = "yes" if f["found"] else ("undetermined" if f.get("undetermined") else "no")
            lines.append(
                f"| `{f['spec']}` | {f['window_start_s']} | {f['expected']} | {found} "
                f"| {f['rank'] or '—'} | {fs} | {f['cpu_s']} |"
            )
        why = sorted({f["undetermined"] for f in r["faults"] if f.get("undetermined")})
        if why:
            lines += ["", *(f"Undetermined: {w}." for w in why)]
        if "service_replay" in r:
            lines += ["", _replay_line(r["service_replay"])]
        if "sim2real" in r:
            lines += ["", *_sim2real_lines(r["sim2real"])]
        if "foot_plane" in r:
            lines += ["", _foot_plane_line(r["foot_plane"])]
        lines.append("")
    return "\n".join(lines) + "\n"


def _replay_line(s: dict[str, Any]) -> str:
    """The service's replay of the untouched log, in one line."""
    kinds = ", ".join(s["alert_kinds"]) or "none"
    errs = sum(s["errors"].values())
    return (
        f"Service replay `{s['spec']}`: {s['log_seconds'] / 60:.1f} min of log time in {s['wall_seconds']} s "
        f"wall, fixed-base baseline learned: {'yes' if s['has_baseline'] else 'no'}, floating-base baseline "
        f"learned: {'yes' if s.get('floating_baseline') else 'no'}, alerts: {s['alerts']} ({kinds}); "
        f"worker errors logged: {errs}, exit code {s['exit_code']}."
    )


def _foot_plane_line(p: dict[str, Any]) -> str:
    """The point feet's plane against the IMU's gravity, in one line."""
    if "skipped" in p:
        return f"Feet's plane (sim2real/foot_plane.py): not measured: {p['skipped']}."
    shifts = ", ".join(f"`{k}` {v}°" for k, v in p["fault_shift_deg"].items())
    return (
        f"Feet's plane against the IMU's gravity (sim2real/foot_plane.py, URDF geometry), on "
        f"{p['plane_fraction']:.0%} of samples: healthy 1 s blocks spread {p['block_std_deg']}° (x, y), "
        f"the halves' means differ by {p['halves_change_norm_deg']}°; each fault shifts the mean by {shifts}."
    )


def _sim2real_lines(s: dict[str, Any]) -> list[str]:
    """The rigid model's residual before and after its named causes, per prediction."""
    if "error" in s:
        return [f"Rigid model (sim2real/robots.py): {s['error']}"]
    out = [
        f"Rigid model (sim2real/robots.py, {s['cpu_s']} CPU s), residual before -> after its causes:",
        "",
    ]
    for name, p in s["result"].get("predictions", {}).items():
        b, a = p.get("residual_before", {}), p.get("residual_after", {})
        causes = ", ".join(c.get("effect", "?") for c in p.get("causes", [])) or "none"
        out.append(
            f"* {name}: gyro {fmt(b.get('gyro_rms'), '.4f')} -> {fmt(a.get('gyro_rms'), '.4f')} rad/s, "
            f"acc {fmt(b.get('acc_rms'), '.3f')} -> {fmt(a.get('acc_rms'), '.3f')} m/s² ({causes})"
        )
    return out


def _plot(res: dict[str, Any]):
    def draw(path: Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(res), figsize=(6 * len(res), 3.5), squeeze=False)
        for ax, (name, r) in zip(axes[0], res.items(), strict=True):
            labels = sorted({f["fault"] for f in r["faults"]})
            found = [
                np.mean([f["found"] and f["rank"] == 1 for f in r["faults"] if f["fault"] == lab])
                for lab in labels
            ]
            ax.barh(labels, found, color="tab:green")
            ax.set_xlim(0, 1)
            ax.set_xlabel("share found first (2 joints or windows each)")
            ax.set_title(
                f"{name}: untouched windows {sum(w['findings'] for w in r['untouched_windows'])} findings"
            )
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)

    return draw


def run(args: argparse.Namespace) -> Path:
    res = {name: _one(name, args.data, not args.no_sim2real) for name in LOGS}
    if args.replay_minutes > 0:
        from sim2real.robot_logs import import_log

        for name, (path, mp, fm, _, _) in LOGS.items():
            rec = import_log(args.data / path, REPO_ROOT / "examples" / "import" / mp, fm)[0]
            res[name]["service_replay"] = _replay(rec, name, args)
    return write_results(args.out, "robots", res, _markdown(res), _plot(res))
