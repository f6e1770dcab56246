"""Body schemas from data logged the way real robots log it: exact, undetermined, confidently wrong.

Random MuJoCo robots (:mod:`simulators.random_robot`: random trees, random joint axes, IMUs at random
surface poses, MPU-6050-like errors; servo excitation) are simulated once each at 1 kHz for
``--seconds``; each sensing condition (:mod:`simulators.sensing`) is then applied to that same motion,
so the cells of one robot differ only in how it was sensed. Every estimate is classified:

* **exact**: the answer claims one tree and it is the true one;
* **undetermined**: the answer says it cannot decide (several trees fit, or joints without
  excitation), whatever its best guess;
* **confidently wrong**: it claims one tree, decides every joint, and is wrong. A health monitor must
  never do this.

Every cell is estimated a second time in its **single-clock** form: the same samples as a logger with
one clock writes them, one ``t`` (the IMU stamps) and positions only, each IMU sample paired with the
encoder sample nearest in time (what an approximate-time synchroniser logs); no ``t_q``, no ``qd``
(:func:`single_clock`). Its counts are the table's last column; its skew is not compared (the pairing
adds up to half an encoder period of its own).

Skew error: for timed data, the estimated IMU-to-encoder skew (the lag less the stated on-chip filter
delay) against the true skew plus the drift accumulated to the middle of the fit, in ms. CPU seconds
are measured on one thread (BLAS, FFT and torch limited to one), estimate only (not the simulation).
Writes ``realism.json``, ``realism.md`` and ``realism.png``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note, process_pool, write_results
from bodyschema.progress import progress
from sim2real.figures import save_figure
from simulators.sensing import PRESETS, SensingOptions

__all__ = ["CELLS", "SHAPES", "add_arguments", "run", "single_clock"]

#: The two forms each cell is estimated in: as the sensing model logs it, and single-clock.
SHAPES = ("sensed", "single-clock")

#: Every non-ideal cell starts here: position-only 14-bit encoders and IMUs, both at 100 Hz, with the
#: robot preset's clock imperfections (30 ppm drift, 0.2 ms stamp jitter), and changes one thing.
_BASE = SensingOptions(
    name="base",
    imu_rate=100.0,
    encoder_rate=100.0,
    encoder_velocity=False,
    encoder_bits=14,
    drift_ppm=30.0,
    jitter=0.2e-3,
)

#: Sensing conditions, in the order of the table. ``None``: the simulator's ideal output (synced,
#: exact joint velocities at 100 Hz).
CELLS: dict[str, SensingOptions | None] = {
    "ideal": None,
    "pos 16 bit": replace(_BASE, encoder_bits=16),
    "pos 14 bit": _BASE,
    "pos 12 bit": replace(_BASE, encoder_bits=12),
    "skew 5 ms": replace(_BASE, skew=5e-3),
    "skew 15 ms": replace(_BASE, skew=15e-3),
    "DLPF 42 Hz": replace(_BASE, dlpf_cfg=3),
    "DLPF 20 Hz": replace(_BASE, dlpf_cfg=4),
    "IMU 50 Hz, enc 500 Hz": replace(_BASE, imu_rate=50.0, encoder_rate=500.0),
    "1 % drops": replace(_BASE, drop=0.01),
    "robot preset": PRESETS["robot"],
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--joints", default="5,10,15,20,25", help="robot sizes (joints)")
    parser.add_argument("--robots", type=int, default=5, help="random robots per size")
    parser.add_argument("--seconds", type=float, default=60.0, help="recording length, s")
    parser.add_argument("--methods", default="fast,network", help="estimators to run")
    parser.add_argument(
        "--cells",
        default="all",
        help="sensing conditions to run, comma-separated ('all': every one); a cell run alone gets the "
        "same robots and the same sensing draws as in a run of all",
    )
    parser.add_argument(
        "--network-cells",
        default="ideal,pos 14 bit,robot preset",
        help="cells the network method runs on (it costs tens of CPU s per robot); 'all' for every cell",
    )
    parser.add_argument(
        "--network-robots", type=int, default=2, help="robots per size the network method runs on"
    )
    parser.add_argument(
        "--catalog-seeds",
        type=int,
        default=5,
        help="seeds per catalog robot run on the robot preset with the fast method (0: none)",
    )
    parser.add_argument(
        "--single-clock",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also estimate every cell in its single-clock form (one t, positions only)",
    )
    parser.add_argument("--jobs", type=int, default=1, help="robots simulated and estimated in parallel")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def single_clock(rec: Any) -> Any:
    """``rec`` as a one-clock logger would write it: the IMU stamps, each IMU sample with the encoder
    sample nearest in time (IMU samples outside the encoder stream's span dropped), positions only.

    >>> from bodyschema.recording import Recording
    >>> t, tq = np.arange(5) * 0.01, np.arange(9) * 0.005 + 0.001
    >>> rec = Recording(t=t, t_q=tq, joint_names=["j"], q=tq[:, None], imu_names=["i"],
    ...                 acc=np.zeros((5, 1, 3)), gyro=np.zeros((5, 1, 3)))
    >>> one = single_clock(rec)
    >>> one.t_q is None, one.t.tolist(), one.q[:, 0].tolist()
    (True, [0.01, 0.02, 0.03, 0.04], [0.011, 0.021, 0.031, 0.041])
    """
    if rec.t_q is None:
        return replace(rec, qd=None, qdd=None)
    keep = (rec.t >= rec.t_q[0]) & (rec.t <= rec.t_q[-1])
    t = rec.t[keep]
    hi = np.clip(np.searchsorted(rec.t_q, t), 1, len(rec.t_q) - 1)
    near = np.where(t - rec.t_q[hi - 1] <= rec.t_q[hi] - t, hi - 1, hi)
    extra = {k: (v[keep] if v.shape[:1] == rec.t.shape else v) for k, v in rec.extra.items()}

    def pick(v: np.ndarray | None) -> np.ndarray | None:
        return None if v is None else v[keep]

    return replace(
        rec,
        t=t,
        t_q=None,
        q=rec.q[near],
        qd=None,
        qdd=None,
        acc=rec.acc[keep],
        gyro=rec.gyro[keep],
        ref_quat=pick(rec.ref_quat),
        ref_pos=pick(rec.ref_pos),
        extra=extra,
    )


def _classify(topo: Any, truth_parent: dict, truth_imu: dict) -> str:
    decided = topo.unique and not topo.undetermined
    right = topo.joint_parent == truth_parent and topo.imu_joint == truth_imu
    if not decided:
        return "undetermined"
    return "exact" if right else "wrong"


def _robot_task(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Simulate one robot and estimate it under every cell, in both shapes (runs in a worker process)."""
    from bodyschema.threads import set_torch_threads
    from simulators.random_robot import random_robot
    from simulators.sensing import apply_sensing
    from simulators.simulation import Simulation

    set_torch_threads(1)
    n, index, seed = job["joints"], job["index"], job["seed"]
    ss = np.random.SeedSequence([seed, n, index])
    robot_ss, sim_ss, sense_ss = ss.spawn(3)
    robot = random_robot(np.random.default_rng(robot_ss), n, rate=1000.0)
    fine = Simulation(robot, seed=sim_ss, rate=1000.0).advance(seconds=job["seconds"])
    rows = []
    for c, (cell, opts) in enumerate(CELLS.items()):
        if cell not in job.get("cells", CELLS):
            continue
        if opts is None:
            rec = fine.select(slice(None, None, 10))  # 100 Hz, synced, exact velocities
        else:
            rec = apply_sensing(fine, opts, np.random.default_rng(_cell_seed(sense_ss, c)))
        shapes = (rec, single_clock(rec)) if job.get("single_clock", True) else (rec,)
        for method in job["methods"]:
            if method != "fast" and (cell not in job["network_cells"] or index >= job["network_robots"]):
                continue
            for shape, one in zip(SHAPES, shapes, strict=False):
                row = {"joints": n, "robot": index, "imus": fine.n_imus, "cell": cell, "method": method}
                row.update(_estimate(one, method, fine, opts if shape == "sensed" else None))
                if shape != "sensed":
                    row["shape"] = shape
                rows.append(row)
    return rows


def _cell_seed(sense: np.random.SeedSequence, c: int) -> np.random.SeedSequence:
    """The sensing draws of cell ``c``, whichever cells run: the ones a run of every cell has always
    used (there cell ``c`` took child ``c`` of the ``c``-th ``spawn(len(CELLS))``, whose spawn key is
    ``c·len(CELLS) + c``), so a cell rerun alone reproduces its rows of the full run.

    >>> ss = np.random.SeedSequence(7)
    >>> full = [ss.spawn(len(CELLS))[c] for c in range(len(CELLS))]
    >>> all(_cell_seed(np.random.SeedSequence(7), c).generate_state(2).tolist()
    ...     == full[c].generate_state(2).tolist() for c in range(len(CELLS)))
    True
    """
    key = (*sense.spawn_key, c * (len(CELLS) + 1))
    return np.random.SeedSequence(sense.entropy, spawn_key=key, pool_size=sense.pool_size)


def _estimate(rec: Any, method: str, fine: Any, opts: SensingOptions | None) -> dict[str, Any]:
    """One estimate's verdict, CPU s, training and (``opts`` given, timed data) skew error."""
    from bodyschema.estimate import estimate_topology
    from bodyschema.threads import blas_threads

    kw = {"seed": 1} if method != "fast" else {}
    with blas_threads(1):
        start = time.process_time()
        try:
            topo = estimate_topology(rec, method, **kw)
            verdict, err = _classify(topo, fine.truth_parent_map, fine.truth_imu_map), None
        except ValueError as exc:  # refused data is an honest answer, not a crash
            topo, verdict, err = None, "undetermined", str(exc)
        cpu = time.process_time() - start
    row: dict[str, Any] = {"verdict": verdict, "cpu_s": round(cpu, 3)}
    if err:
        row["error"] = err
    if topo is not None and topo.training:  # network methods: epochs trained, converged or not
        row["epochs"] = int(topo.training["epochs"])
        row["converged"] = bool(topo.training["converged"])
    if topo is not None and topo.timing and opts is not None:
        truth_ms = 1e3 * (opts.skew + 1e-6 * opts.drift_ppm * topo.timing["at_s"])
        row["skew_ms"] = round(topo.timing["skew_ms"], 3)
        row["skew_err_ms"] = round(topo.timing["skew_ms"] - truth_ms, 3)
    return row


def _catalog_task(job: dict[str, Any]) -> dict[str, Any]:
    """One catalog robot on the robot preset, estimated by ``fast`` (runs in a worker process)."""
    from bodyschema.estimate import estimate_topology
    from bodyschema.threads import blas_threads
    from simulators.simulation import simulate

    rec = simulate(job["robot"], seconds=job["seconds"], seed=job["seed"], sensing="robot")
    with blas_threads(1):
        start = time.process_time()
        topo = estimate_topology(rec, "fast")
        cpu = time.process_time() - start
    robot = PRESETS["robot"]
    truth_ms = 1e3 * (robot.skew + 1e-6 * robot.drift_ppm * topo.timing["at_s"])
    return {
        "robot": job["robot"],
        "seed": job["seed"],
        "joints": rec.n_joints,
        "imus": rec.n_imus,
        "verdict": _classify(topo, rec.truth_parent_map, rec.truth_imu_map),
        "cpu_s": round(cpu, 3),
        "skew_err_ms": round(topo.timing["skew_ms"] - truth_ms, 3),
    }


def run(args: argparse.Namespace) -> Path:
    sizes = [int(x) for x in args.joints.split(",") if x.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    net_cells = (
        list(CELLS) if args.network_cells == "all" else [c.strip() for c in args.network_cells.split(",")]
    )
    cells = list(CELLS) if args.cells == "all" else [c.strip() for c in args.cells.split(",")]
    unknown = [c for c in [*net_cells, *cells] if c not in CELLS]
    if unknown:
        raise SystemExit(f"unknown cells {unknown}; cells are {list(CELLS)}")
    jobs = [
        {
            "joints": n,
            "index": i,
            "seed": args.seed,
            "seconds": args.seconds,
            "methods": methods,
            "cells": cells,
            "network_cells": net_cells,
            "network_robots": args.network_robots,
            "single_clock": args.single_clock,
        }
        for n in sizes
        for i in range(args.robots)
    ]
    rows: list[dict[str, Any]] = []
    with process_pool(max(1, args.jobs)) as pool:
        for part in progress(
            pool.map(_robot_task, jobs), total=len(jobs), desc="bench realism", unit="robot"
        ):
            rows.extend(part)
    single = [r for r in rows if r.get("shape") == "single-clock"]
    rows = [r for r in rows if "shape" not in r]
    catalog: list[dict[str, Any]] = []
    if args.catalog_seeds > 0:
        from simulators.catalog import CATALOG

        cjobs = [
            {"robot": name, "seed": seed, "seconds": args.seconds}
            for name in CATALOG
            for seed in range(args.catalog_seeds)
        ]
        with process_pool(max(1, args.jobs)) as pool:
            runs = pool.map(_catalog_task, cjobs)
            catalog = list(progress(runs, total=len(cjobs), desc="catalog, robot preset", unit="run"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = (
        f"bodyhealth bench realism --joints {args.joints} --robots {args.robots} --seconds {args.seconds:g} "
        f"--methods {args.methods}"
        + ("" if args.cells == "all" else f" --cells '{args.cells}'")
        + f" --network-cells '{args.network_cells}' "
        f"--network-robots {args.network_robots} --catalog-seeds {args.catalog_seeds} --seed {args.seed}"
        + ("" if args.single_clock else " --no-single-clock")
    )
    summary = _summary(rows, sizes, methods)
    for m in methods:
        summary[m]["single_clock"] = _single_summary([r for r in single if r["method"] == m])
    data = {"machine": machine_note(), "command": command, "summary": summary, "rows": rows}
    data["single_clock_rows"] = single
    data["catalog"] = catalog
    text = _markdown(summary, sizes, methods, command, rows) + _catalog_markdown(catalog)
    return write_results(out, "realism", data, text, lambda path: _plot(summary, sizes, methods, path))


def _catalog_markdown(catalog: list[dict[str, Any]]) -> str:
    """The catalog section: exact / undetermined / wrong per robot on the robot preset."""
    if not catalog:
        return ""
    lines = [
        "",
        "## The catalog on the robot preset (`fast`)",
        "",
        f"{sum(c['verdict'] == 'exact' for c in catalog)} of {len(catalog)} exact, "
        f"{sum(c['verdict'] == 'undetermined' for c in catalog)} undetermined, "
        f"**{sum(c['verdict'] == 'wrong' for c in catalog)} confidently wrong**; skew error at most "
        f"{max(abs(c['skew_err_ms']) for c in catalog):.2f} ms.",
        "",
        "| robot | joints | IMUs | exact | CPU s (mean) | max skew error, ms |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in dict.fromkeys(c["robot"] for c in catalog):
        runs = [c for c in catalog if c["robot"] == name]
        lines.append(
            f"| {name} | {runs[0]['joints']} | {runs[0]['imus']} | "
            f"{sum(c['verdict'] == 'exact' for c in runs)}/{len(runs)} | "
            f"{np.mean([c['cpu_s'] for c in runs]):.2f} | {max(abs(c['skew_err_ms']) for c in runs):.2f} |"
        )
    return "\n".join([*lines, ""])


def _summary(rows: list[dict], sizes: list[int], methods: list[str]) -> dict[str, Any]:
    """Counts per (method, cell, size), plus per-method totals and the skew error where exact."""
    out: dict[str, Any] = {}
    for m in methods:
        cells: dict[str, Any] = {}
        for cell in CELLS:
            per: dict[str, Any] = {}
            for n in sizes:
                sel = [r for r in rows if r["method"] == m and r["cell"] == cell and r["joints"] == n]
                if not sel:
                    continue
                per[str(n)] = {
                    "robots": len(sel),
                    "exact": sum(r["verdict"] == "exact" for r in sel),
                    "undetermined": sum(r["verdict"] == "undetermined" for r in sel),
                    "wrong": sum(r["verdict"] == "wrong" for r in sel),
                    "cpu_s_mean": round(float(np.mean([r["cpu_s"] for r in sel])), 3),
                    "cpu_s_max": round(float(np.max([r["cpu_s"] for r in sel])), 3),
                }
            if per:
                cells[cell] = per
        mine = [r for r in rows if r["method"] == m]
        skew = [abs(r["skew_err_ms"]) for r in mine if r["verdict"] == "exact" and "skew_err_ms" in r]
        out[m] = {
            "cells": cells,
            "robots": len(mine),
            "exact": sum(r["verdict"] == "exact" for r in mine),
            "undetermined": sum(r["verdict"] == "undetermined" for r in mine),
            "wrong": sum(r["verdict"] == "wrong" for r in mine),
            "max_abs_skew_err_ms_where_exact": round(max(skew), 3) if skew else None,
        }
    return out


def _counts(sel: list[dict]) -> dict[str, int]:
    return {
        "robots": len(sel),
        "exact": sum(r["verdict"] == "exact" for r in sel),
        "undetermined": sum(r["verdict"] == "undetermined" for r in sel),
        "wrong": sum(r["verdict"] == "wrong" for r in sel),
    }


def _single_summary(sel: list[dict]) -> dict[str, Any]:
    """Single-clock counts over every size, per cell and in all."""
    cells = {c: _counts([r for r in sel if r["cell"] == c]) for c in CELLS}
    return {**_counts(sel), "cells": {c: v for c, v in cells.items() if v["robots"]}}


def _markdown(summary: dict, sizes: list[int], methods: list[str], command: str, rows: list[dict]) -> str:
    lines = [
        "# Benchmark: body schemas from realistically sensed data",
        "",
        f"`{command}`",
        "",
        f"Machine: {machine_note()}. One CPU thread per estimate.",
        "",
        "Each cell: exact / undetermined / **confidently wrong** of the robots run, and the mean CPU s "
        "per robot (estimate only). Cells other than `ideal` start from position-only 14-bit encoders and "
        "IMUs at 100 Hz with 30 ppm drift and 0.2 ms jitter, and change one thing; `robot preset` is the "
        "default preset of the simulators (250 Hz encoders, DLPF 42 Hz, 8 ms skew, 0.5 % drops). "
        "*Single-clock*: the same samples with one `t` and positions only, each IMU sample paired with "
        "the nearest encoder sample; exact / undetermined / **wrong** over every size.",
        "",
    ]
    for m in methods:
        s = summary[m]
        if not s["robots"]:
            continue
        lines += [
            f"## `{m}`",
            "",
            f"Overall: {s['exact']} exact, {s['undetermined']} undetermined, **{s['wrong']} confidently "
            f"wrong** of {s['robots']} estimates"
            + (
                f"; skew within {s['max_abs_skew_err_ms_where_exact']:.2f} ms wherever exact."
                if s["max_abs_skew_err_ms_where_exact"] is not None
                else "."
            ),
            *_single_line(s.get("single_clock")),
            "",
            "| cell | " + " | ".join(f"{n} joints" for n in sizes) + " | single-clock |",
            "|---|" + "---|" * (len(sizes) + 1),
        ]
        for cell, per in s["cells"].items():
            parts = []
            for n in sizes:
                c = per.get(str(n))
                parts.append(
                    ""
                    if c is None
                    else f"{c['exact']}/{c['undetermined']}/**{c['wrong']}** ({c['cpu_s_mean']:.1f} s)"
                )
            one = (s.get("single_clock") or {}).get("cells", {}).get(cell)
            parts.append("" if one is None else f"{one['exact']}/{one['undetermined']}/**{one['wrong']}**")
            lines.append(f"| {cell} | " + " | ".join(parts) + " |")
        lines.append("")
        epochs = sorted(r["epochs"] for r in rows if r["method"] == m and "epochs" in r)
        if epochs:
            done = sum(bool(r.get("converged")) for r in rows if r["method"] == m and "epochs" in r)
            lines += [
                f"Training ran to a flat loss (no fixed epoch count): {epochs[0]}–{epochs[-1]} epochs, "
                f"median {epochs[len(epochs) // 2]}; converged in {done} of {len(epochs)} estimates.",
                "",
            ]
    errors = sorted({r["error"] for r in rows if "error" in r})
    if errors:
        lines += ["Refused inputs (counted as undetermined):", ""] + [f"- {e}" for e in errors] + [""]
    lines += ["![realism](realism.png)", ""]
    return "\n".join(lines)


def _single_line(one: dict | None) -> list[str]:
    if not one or not one["robots"]:
        return []
    return [
        "",
        f"Single-clock: {one['exact']} exact, {one['undetermined']} undetermined, **{one['wrong']} "
        f"confidently wrong** of {one['robots']} estimates.",
    ]


def _plot(summary: dict, sizes: list[int], methods: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [m for m in methods if summary[m]["robots"]]
    fig, axes = plt.subplots(
        1,
        len(shown) + 1,
        figsize=(5.5 * len(shown) + 0.8, 5.2),
        squeeze=False,
        gridspec_kw={"width_ratios": [1.0] * len(shown) + [0.05]},
    )
    for ax, m in zip(axes[0][:-1], shown, strict=True):
        cells = list(summary[m]["cells"])
        share = np.full((len(cells), len(sizes)), np.nan)
        for i, cell in enumerate(cells):
            for j, n in enumerate(sizes):
                c = summary[m]["cells"][cell].get(str(n))
                if c:
                    share[i, j] = c["exact"] / c["robots"]
                    label = f"{c['exact']}/{c['robots']}" + (f"\n{c['wrong']} wrong" if c["wrong"] else "")
                    ax.text(j, i, label, ha="center", va="center", fontsize=7)
        im = ax.imshow(share, vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
        ax.set_xticks(range(len(sizes)), [str(n) for n in sizes])
        ax.set_yticks(range(len(cells)), cells, fontsize=8)
        ax.set_xlabel("joints")
        ax.set_title(f"{m}: share exact")
    fig.colorbar(im, cax=axes[0][-1], label="share exact")
    save_figure(fig, path)
