"""Body schemas of robots the simulators did not build, in both shapes a recording comes in.

``--robots`` random robots from :mod:`bench.generator` (which shares no code with :mod:`simulators`),
``--joints`` hinges each, ``--seconds`` (60 s) at 100 Hz, MPU-6050 errors at the datasheet's limits;
robot ``i`` gets its sensing from a fixed pattern so that every combination turns up: skew (odd
``i``: 2-10 ms), encoder quantization (none, 14 or 12 bits per turn by ``i // 2``) and the 42 Hz
low-pass (``i // 6`` odd).
Each robot is estimated twice, as the same samples in two shapes (docs/recording-format.md):
multi-rate (encoders on their own stamps ``t_q``) and single-clock (one ``t``, positions only).

Per shape: the fast estimator's verdict (exact, undetermined, confidently wrong as in ``bench
realism``), the joints an undetermined answer names to move, and what the data say about joints that
hardly moved (:func:`still_joints`: true rate RMS in the comparison band, over the span the estimator
fits, under 0.05 rad/s: jammed against a link or a limit, so undeterminable by this motion), and the
exact count over the robots whose joints all moved. Then
:func:`bodyschema.kinematics.estimate_kinematics` on the true tree: the angle between each IMU's
answered axis and the model's (``axis``, the accelerometer-frame answer; ``gyro axis``, the gyro's
reading) and the distance between its lever arm and the model's, both in the IMU's frame. CPU seconds on
one thread, estimates only. Writes ``shapes.json``, ``shapes.md`` and ``shapes.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, fmt, machine_note, map_jobs, write_results
from sim2real.figures import save_figure

__all__ = ["SHAPES", "add_arguments", "conditions", "run", "still_joints"]

SHAPES = ("multi-rate", "single-clock")

#: What the results page says about the robots and the columns.
ABOUT = (
    "Random robots from `bench/generator.py`, which shares no code with `simulators/`: random labelled "
    "hinge trees on a fixed base, colliding links, torque-limited velocity servos on slow sines, one to "
    "three IMUs per link with MPU-6050 errors at the datasheet's limits, 100 Hz. Robot i's sensing follows "
    "a fixed pattern: skew 2-10 ms for odd i; no quantization, 14 or 12 bits per turn by i // 2; the 42 Hz "
    "low-pass (4.8 ms) where i // 6 is odd. Each robot's samples are estimated in both shapes: multi-rate "
    "(encoders on `t_q`) and single-clock (one `t`, positions only). *Hardly moved*: true rate RMS in the "
    "comparison band, over the span the estimator fits (a joint that settles into a jam in the first "
    "tenths of a second counts as jammed), under 0.05 rad/s (jammed against a link or a limit): "
    "undeterminable by this motion, so *all moved* counts the robots without such a joint. Kinematics "
    "run on the true tree; errors are against "
    "the model in each IMU's frame: *axis* is the accelerometer-frame answer, *gyro axis* the gyro's "
    "reading, *lever arm* the perpendicular one; the *accelerometer cross-axis floor* is the angle by "
    "which each IMU's drawn accelerometer cross-axis terms turn its axis once the gains are fitted "
    "(`axis_floor_deg`): the answer is in the accelerometer's frame, taken as square."
)

#: A joint whose true rate RMS stays under this hardly moved (rad/s).
STILL_RAD_S = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, default=20, help="random robots")
    parser.add_argument("--joints", default="5,20", help="joint count range LOW,HIGH")
    parser.add_argument("--seconds", type=float, default=60.0, help="recording length, s")
    parser.add_argument(
        "--kinematics",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also estimate axes and lever arms on the true tree (a few CPU s per robot)",
    )
    parser.add_argument("--jobs", type=int, default=1, help="robots generated and estimated in parallel")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def conditions(index: int, rng: np.random.Generator) -> dict[str, Any]:
    """Robot ``index``'s sensing: skew, encoder bits and low-pass from a fixed pattern.

    >>> [conditions(i, np.random.default_rng(0))["encoder_bits"] for i in range(6)]
    [None, None, 14, 14, 12, 12]
    """
    skew = round(float(rng.uniform(2e-3, 10e-3)), 4) if index % 2 else 0.0
    bits = (None, 14, 12)[(index // 2) % 3]
    return {"skew": skew, "encoder_bits": bits, "dlpf": bool((index // 6) % 2)}


def still_joints(qd_true: np.ndarray, names: Any, rate: float, dlpf: bool) -> list[str]:
    """The joints whose true rate ``qd_true`` (T, N), sampled at ``rate``, hardly moved where the fast
    estimator looks: RMS under :data:`STILL_RAD_S` in its comparison band
    (:func:`bodyschema.timing.choose_band`, the stated low-pass's band when ``dlpf``), over the samples
    it fits (``max_lag`` plus the band's edge margin in from each end).

    >>> t = np.arange(3000) / 100
    >>> qd = np.stack([np.sin(t), 0.01 * np.sin(t), np.where(t < 0.2, 5.0, 0.0)], axis=1)
    >>> still_joints(qd, ["a", "b", "c"], 100.0, False)
    ['b', 'c']
    """
    from bodyschema import timing as tm
    from bodyschema.fast import FastOptions

    fc = tm.choose_band(rate, rate, tm.DLPF_GYRO[3][0] if dlpf else None)
    cut = int(np.ceil((FastOptions().max_lag + tm.edge_margin(fc)) * rate))
    band = tm.lowpass(qd_true, rate, fc)[cut : len(qd_true) - cut]
    rms = np.sqrt(np.mean(band**2, axis=0))
    return [n for n, r in zip(names, rms, strict=True) if r < STILL_RAD_S]


def _verdict(topo: Any, rec: Any) -> str:
    if not topo.unique or topo.undetermined:
        return "undetermined"
    right = topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map
    return "exact" if right else "wrong"


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def axis_floor_deg(acc_S: np.ndarray, axis: np.ndarray) -> float:
    """The angle (deg) by which an accelerometer with sensitivity matrix ``acc_S`` shows a joint axis
    ``axis`` (unit, in the IMU's frame) once its gains are fitted: its cross-axis terms alone.

    Each reading divided by its own gain is ``f + C f`` (``C`` the cross-axis terms over the gains);
    gravity turns about ``axis`` in the IMU's frame, so in the reading it keeps constant the component
    along ``(I + C)⁻ᵀ axis``: the axis the accelerometer's frame can show, taken as square.

    >>> round(axis_floor_deg(np.eye(3) + 0.02 * np.eye(3)[[1, 2, 0]], np.array([1.0, 0, 0])), 2)
    1.15
    """
    Sg = np.asarray(acc_S, dtype=float) / np.diag(acc_S)[:, None]
    return _angle_deg(np.linalg.solve(Sg.T, axis), axis)


def _kinematics(rec: Any, acc_S: np.ndarray) -> dict[str, Any]:
    """Axis and lever-arm errors of every IMU the kinematics answers, on the true tree, and the axis
    floor its accelerometer's cross-axis terms set (:func:`axis_floor_deg`)."""
    from bodyschema.kinematics import estimate_kinematics
    from bodyschema.topology import Topology

    truth = Topology(joint_parent=rec.truth_parent_map, imu_joint=rec.truth_imu_map)
    start = time.process_time()
    kin = estimate_kinematics(rec, truth)
    cpu = time.process_time() - start
    axis, gyro, lever, conv, floor = [], [], [], [], []
    for k, name in enumerate(rec.imu_names):
        e = kin.imus.get(name)
        if e is None or e.axis is None:
            continue
        axis.append(round(_angle_deg(e.axis, rec.extra["truth_axis"][k]), 3))
        floor.append(round(axis_floor_deg(acc_S[k], rec.extra["truth_axis"][k]), 3))
        gyro.append(
            round(_angle_deg(e.gyro_axis, rec.extra["truth_axis"][k]), 3) if e.gyro_axis is not None else None
        )
        d = (
            np.nan
            if e.lever_arm is None
            else 1e3 * np.linalg.norm(e.lever_arm - rec.extra["truth_lever_arm"][k])
        )
        lever.append(None if np.isnan(d) else round(float(d), 2))
        conv.append(bool(e.converged))
    return {
        "axis_deg": axis,
        "axis_floor_deg": floor,
        "gyro_axis_deg": gyro,
        "lever_mm": lever,
        "converged": conv,
        "kin_cpu_s": round(cpu, 3),
    }


def _robot_task(
    index: int, seed: int, joints: tuple[int, int], seconds: float, kinematics: bool
) -> list[dict]:
    """Generate robot ``index`` and estimate it in both shapes (runs in a worker process)."""
    from bench.generator import GeneratorOptions, generate
    from bench.generator_sensing import SensingSpec
    from bodyschema.estimate import estimate_topology
    from bodyschema.threads import blas_threads, set_torch_threads

    set_torch_threads(1)
    cond = conditions(index, np.random.default_rng([seed, index, 1]))
    opts = GeneratorOptions(joints=joints, seconds=seconds, sensing=SensingSpec(**cond))
    gen = generate(seed * 100_003 + index, opts)
    still = still_joints(gen.qd_true, gen.multi.joint_names, opts.rate, cond["dlpf"])
    rows = []
    for shape, rec in zip(SHAPES, (gen.multi, gen.single), strict=True):
        row: dict[str, Any] = {
            "robot": index,
            "shape": shape,
            "joints": rec.n_joints,
            "imus": rec.n_imus,
            **cond,
            "still_joints": still,
        }
        with blas_threads(1):
            start = time.process_time()
            try:
                topo = estimate_topology(rec, "fast")
                row["verdict"], row["named"] = _verdict(topo, rec), list(topo.undetermined)
                if topo.timing:
                    row["skew_err_ms"] = round(topo.timing["skew_ms"] - 1e3 * gen.skew, 3)
            except ValueError as exc:  # refused data is an honest answer, not a crash
                row["verdict"], row["named"], row["error"] = "undetermined", [], str(exc)
            row["cpu_s"] = round(time.process_time() - start, 3)
            if kinematics:
                row.update(_kinematics(rec, gen.imu_errors.acc_S))
        rows.append(row)
    return rows


def _median(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return round(float(np.median(v)), 3) if v else None


def _summary(rows: list[dict]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for shape in SHAPES:
        sel = [r for r in rows if r["shape"] == shape]
        if not sel:
            continue
        skew = [abs(r["skew_err_ms"]) for r in sel if r["verdict"] == "exact" and "skew_err_ms" in r]
        moved = [r for r in sel if not r["still_joints"]]
        s: dict[str, Any] = {
            "robots": len(sel),
            **{v: sum(r["verdict"] == v for r in sel) for v in ("exact", "undetermined", "wrong")},
            "robots_all_moved": len(moved),
            "exact_all_moved": sum(r["verdict"] == "exact" for r in moved),
            "named_joints": sum(len(r["named"]) for r in sel),
            "still_joints": sum(len(r["still_joints"]) for r in sel),
            "max_abs_skew_err_ms_where_exact": round(max(skew), 3) if skew else None,
            "cpu_s_mean": round(float(np.mean([r["cpu_s"] for r in sel])), 3),
        }
        if "axis_deg" in sel[0]:
            axis = [a for r in sel for a in r["axis_deg"]]
            conv = [c for r in sel for c in r["converged"]]
            s.update(
                imus=len(axis),
                converged=sum(conv),
                axis_deg_median=_median(axis),
                axis_floor_deg_median=_median([a for r in sel for a in r["axis_floor_deg"]]),
                gyro_axis_deg_median=_median([a for r in sel for a in r["gyro_axis_deg"]]),
                lever_mm_median=_median([x for r in sel for x in r["lever_mm"]]),
                axis_deg_median_converged=_median(
                    [a for r in sel for a, c in zip(r["axis_deg"], r["converged"], strict=True) if c]
                ),
                lever_mm_median_converged=_median(
                    [x for r in sel for x, c in zip(r["lever_mm"], r["converged"], strict=True) if c]
                ),
                kin_cpu_s_mean=round(float(np.mean([r["kin_cpu_s"] for r in sel])), 3),
            )
        out[shape] = s
    return out


def run(args: argparse.Namespace) -> Path:
    lo, hi = (int(x) for x in args.joints.split(","))
    if not 1 <= lo <= hi:
        raise SystemExit(f"--joints wants LOW,HIGH with 1 <= LOW <= HIGH, got {args.joints}")
    jobs = [(i, args.seed, (lo, hi), args.seconds, args.kinematics) for i in range(args.robots)]
    rows = [r for part in map_jobs(_robot_task, jobs, args.jobs, "bench shapes", "robot") for r in part]
    command = (
        f"bodyhealth bench shapes --robots {args.robots} --joints {args.joints} --seconds {args.seconds:g} "
        f"{'--kinematics' if args.kinematics else '--no-kinematics'} --seed {args.seed}"
    )
    summary = _summary(rows)
    data = {"machine": machine_note(), "command": command, "summary": summary, "rows": rows}
    return write_results(
        args.out, "shapes", data, _markdown(summary, rows, command), lambda p: _plot(rows, summary, p)
    )


def _markdown(summary: dict, rows: list[dict], command: str) -> str:
    lines = [
        "# Benchmark: robots the simulators did not build, in both recording shapes",
        "",
        f"`{command}`",
        "",
        f"Machine: {machine_note()}. One CPU thread per estimate.",
        "",
        ABOUT,
        "",
        "| shape | exact | undetermined | **confidently wrong** | exact where all moved | joints named to "
        "move | joints that hardly moved | max skew error where exact, ms | CPU s (mean) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for shape, s in summary.items():
        lines.append(
            f"| {shape} | {s['exact']} | {s['undetermined']} | **{s['wrong']}** | "
            f"{s['exact_all_moved']} of {s['robots_all_moved']} | {s['named_joints']} | "
            f"{s['still_joints']} | {fmt(s['max_abs_skew_err_ms_where_exact'])} | {s['cpu_s_mean']:.2f} |"
        )
    if any("axis_deg_median" in s for s in summary.values()):
        lines += [
            "",
            "Kinematics on the true tree (errors against the model, in each IMU's frame):",
            "",
            "| shape | IMUs answered | converged | axis median, deg | accelerometer cross-axis floor, "
            "deg | gyro axis median, deg | lever arm median, mm | converged: axis, deg | converged: "
            "lever arm, mm | CPU s (mean) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for shape, s in summary.items():
            lines.append(
                f"| {shape} | {s['imus']} | {s['converged']} | {fmt(s['axis_deg_median'])} | "
                f"{fmt(s['axis_floor_deg_median'])} | {fmt(s['gyro_axis_deg_median'])} | "
                f"{fmt(s['lever_mm_median'], '.1f')} | "
                f"{fmt(s['axis_deg_median_converged'])} | {fmt(s['lever_mm_median_converged'], '.1f')} | "
                f"{s['kin_cpu_s_mean']:.1f} |"
            )
    lines += [
        "",
        "## Robot by robot",
        "",
        "| robot | joints | IMUs | skew, ms | encoder bits | DLPF | hardly moved | multi-rate "
        "| single-clock |",
        "|---:|---:|---:|---:|---|---|---|---|---|",
    ]
    for i in sorted({r["robot"] for r in rows}):
        m, s = (next(r for r in rows if r["robot"] == i and r["shape"] == sh) for sh in SHAPES)
        lines.append(
            f"| {i} | {m['joints']} | {m['imus']} | {1e3 * m['skew']:.1f} | {m['encoder_bits'] or '—'} | "
            f"{'42 Hz' if m['dlpf'] else 'off'} | {', '.join(m['still_joints']) or '—'} | "
            f"{_cell(m)} | {_cell(s)} |"
        )
    errors = sorted({r["error"] for r in rows if "error" in r})
    if errors:
        lines += ["", "Refused inputs (counted as undetermined):", "", *(f"- {e}" for e in errors)]
    return "\n".join([*lines, "", "![shapes](shapes.png)", ""])


def _cell(row: dict) -> str:
    if row["verdict"] == "undetermined" and row["named"]:
        still = [j for j in row["named"] if j in row["still_joints"]]
        move = [j for j in row["named"] if j not in still]
        parts = ([f"move {', '.join(move)}"] if move else []) + (
            [f"{', '.join(still)} undeterminable by this motion"] if still else []
        )
        return f"undetermined ({'; '.join(parts)})"
    return "**wrong**" if row["verdict"] == "wrong" else row["verdict"]


def _plot(rows: list[dict], summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shapes = list(summary)
    kin = any("axis_deg" in r for r in rows)
    fig, axes = plt.subplots(1, 3 if kin else 1, figsize=(13 if kin else 4.5, 4), squeeze=False)
    ax = axes[0][0]
    bottom = np.zeros(len(shapes))
    for verdict, colour in (("exact", "tab:green"), ("undetermined", "0.7"), ("wrong", "tab:red")):
        h = np.array([summary[s][verdict] for s in shapes])
        ax.bar(shapes, h, bottom=bottom, color=colour, label=verdict)
        bottom += h
    ax.set_ylabel("robots")
    ax.set_title("fast estimator's verdict")
    ax.legend(fontsize=8)
    if kin:
        for ax, key, label in (
            (axes[0][1], "axis_deg", "axis error, deg"),
            (axes[0][2], "lever_mm", "lever-arm error, mm"),
        ):
            data = [[x for r in rows if r["shape"] == s for x in r[key] if x is not None] for s in shapes]
            ax.boxplot([d or [np.nan] for d in data], showfliers=True)
            ax.set_xticks(range(1, len(shapes) + 1), shapes)
            ax.set_yscale("log")
            ax.set_ylabel(label)
            ax.set_title(f"{label.split(',')[0]} per IMU (true tree)")
            ax.grid(True, alpha=0.3, which="both")
    save_figure(fig, path, dpi=100)
