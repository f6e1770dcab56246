"""Are the confidences worth their number? Exact, undetermined and confidently wrong answers, and how
often a part reported at a given confidence is right, on robots this project did not build.

Random robots (``--joints``, default 5-25) from the independent generator (:mod:`bench.generator`:
velocity servos on sums of slow sines, links that collide so some joints jam, seized bearings,
MPU-6050 errors) are estimated in both forms it writes, single-clock (one ``t``, positions only) and
multi-rate (IMU and encoder stamps), by three answers:

* ``fast``: the fast method (:mod:`bodyschema.fast`);
* ``network``: the sensor networks with their held-out runner-up tests
  (:mod:`bodyschema.network_confidence`);
* ``combined``: :func:`bodyschema.verdict.combine` of the two.

Per robot and form each answer is **exact** (claims one tree, every part decided, and it is the true
one), **undetermined** (says it cannot decide, whatever its best guess), or **confidently wrong**
(claims one tree and it is not the true one). Per part (each joint's parent, each IMU's joint) the
reported confidence and whether the part's answer is right go into a reliability diagram: parts in a
confidence bin against the share of them that are right. An undetermined answer that names no joint
to move is counted too (it must be none). CPU seconds per robot are measured on one thread.
Writes ``calibration.json``, ``calibration.md`` and ``calibration.png``.

A hundred robots take hours on two cores, so each finished robot is saved to ``--checkpoint``
(default ``calibration.partial.jsonl`` in the results folder) and a rerun of the same command picks
up where the last one stopped. A saved robot is reused only while its job and the sources that decide
its rows (``bodyschema/``, the generator, this file) are byte for byte the same; the file is removed
once the results are written.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note, map_jobs, write_results

__all__ = ["ANSWERS", "BINS", "FORMS", "add_arguments", "run"]

#: What a calibration row depends on besides its job: a saved row is reused only while these hold.
_SOURCES = ("bodyschema", "bench/generator.py", "bench/generator_sensing.py", "bench/calibration.py")

ANSWERS = ("fast", "network", "combined")
FORMS = ("single-clock", "multi-rate")
#: Reliability diagram bins of reported confidence (the last is [0.99, 1]).
BINS = (0.0, 0.5, 0.9, 0.99, 1.0 + 1e-9)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, default=100, help="random robots")
    parser.add_argument("--joints", default="5,25", help="joint count range LOW,HIGH")
    parser.add_argument("--seconds", type=float, default=60.0, help="recording length, s")
    parser.add_argument("--forms", default=",".join(FORMS), help="recording forms to estimate")
    parser.add_argument("--jobs", type=int, default=1, help="robots estimated in parallel")
    parser.add_argument("--seed", type=int, default=0, help="first generator seed")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument(
        "--checkpoint",
        type=Path,
        default=None,
        help="finished robots, to resume a stopped run "
        "(default: calibration.partial.jsonl in the results folder)",
    )


def _source_digest() -> str:
    """One hash of every source file that decides a row, so a saved row from other code is not reused."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for name in _SOURCES:
        path = root / name
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            digest.update(str(file.relative_to(root)).encode())
            digest.update(file.read_bytes())
    return digest.hexdigest()


def _job_key(job: dict[str, Any], sources: str) -> str:
    return hashlib.sha256((json.dumps(job, sort_keys=True) + sources).encode()).hexdigest()[:24]


def _saved(path: Path) -> dict[str, list[dict]]:
    """Rows of finished robots by job key; a line cut short by a kill is skipped."""
    saved: dict[str, list[dict]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            saved[entry["key"]] = entry["rows"]
    return saved


def _truth(rec: Any) -> tuple[dict, dict]:
    return rec.truth_parent_map, rec.truth_imu_map


def _classify(topo: Any, truth_parent: dict, truth_imu: dict) -> str:
    right = topo.joint_parent == truth_parent and topo.imu_joint == truth_imu
    if not (topo.unique and not topo.undetermined):
        return "undetermined"
    return "exact" if right else "wrong"


def _parts(topo: Any, truth_parent: dict, truth_imu: dict) -> list[tuple[float, bool]]:
    """(confidence, right) per part."""
    out = [
        (float(topo.confidence.get(f"joint:{j}", 0.0)), topo.joint_parent[j] == p)
        for j, p in truth_parent.items()
    ]
    out += [
        (float(topo.confidence.get(f"imu:{i}", 0.0)), topo.imu_joint[i] == j) for i, j in truth_imu.items()
    ]
    return out


def _robot_task(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Generate one robot and estimate it in each form by every answer (runs in a worker process)."""
    from bench.generator import GeneratorOptions, generate
    from bodyschema.estimate import estimate_topology
    from bodyschema.threads import blas_threads, set_torch_threads
    from bodyschema.verdict import combine

    set_torch_threads(1)
    lo, hi = job["joints"]
    gen = generate(job["seed"], GeneratorOptions(joints=(lo, hi), seconds=job["seconds"]))
    rows = []
    for form in job["forms"]:
        rec = gen.single if form == "single-clock" else gen.multi
        tp, ti = _truth(rec)
        row: dict[str, Any] = {"seed": job["seed"], "form": form, "joints": rec.n_joints, "imus": rec.n_imus}
        topos = {}
        with blas_threads(1):
            for method in ("fast", "network"):
                start = time.process_time()
                try:
                    topos[method] = estimate_topology(
                        rec, method, **({"seed": 1, "heldout_check": True} if method != "fast" else {})
                    )
                except ValueError as exc:  # refused data is an honest answer
                    topos[method] = None
                    row[f"{method}_error"] = str(exc)
                row[f"{method}_cpu_s"] = round(time.process_time() - start, 3)
        if topos["fast"] is not None and topos["network"] is not None:
            verdict = combine(topos["fast"], topos["network"])
            topos["combined"] = verdict.topology
            row["unnamed_undetermined"] = sum(
                1 for p in verdict.parts.values() if not p.decided and not p.move
            )
        else:
            topos["combined"] = None
        for answer in ANSWERS:
            topo = topos[answer]
            row[answer] = "undetermined" if topo is None else _classify(topo, tp, ti)
            row[f"{answer}_parts"] = [] if topo is None else _parts(topo, tp, ti)
            if topo is not None and answer != "combined" and topo.undetermined:
                row[f"{answer}_undetermined"] = list(topo.undetermined)
        rows.append(row)
    return rows


def _reliability(rows: list[dict], answer: str) -> list[dict[str, Any]]:
    parts = [p for r in rows for p in r[f"{answer}_parts"]]
    out = []
    for lo, hi in itertools.pairwise(BINS):
        sel = [ok for c, ok in parts if lo <= c < hi]
        out.append({"from": lo, "to": min(hi, 1.0), "parts": len(sel), "right": int(sum(sel))})
    return out


def _summary(rows: list[dict]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for answer in ANSWERS:
        per_form = {}
        for form in sorted({r["form"] for r in rows}):
            sel = [r[answer] for r in rows if r["form"] == form]
            per_form[form] = {v: sel.count(v) for v in ("exact", "undetermined", "wrong")}
        out[answer] = {"forms": per_form, "reliability": _reliability(rows, answer)}
    for method in ("fast", "network"):
        cpu = [r[f"{method}_cpu_s"] for r in rows]
        out[method]["cpu_s_median"] = float(np.median(cpu)) if cpu else None
        out[method]["cpu_s_max"] = float(np.max(cpu)) if cpu else None
    out["combined"]["unnamed_undetermined"] = int(sum(r.get("unnamed_undetermined", 0) for r in rows))
    return out


def run(args: argparse.Namespace) -> Path:
    lo, hi = (int(x) for x in args.joints.split(","))
    forms = [f.strip() for f in args.forms.split(",") if f.strip()]
    unknown = [f for f in forms if f not in FORMS]
    if unknown:
        raise SystemExit(f"unknown forms {unknown}; forms are {list(FORMS)}")
    jobs = [
        {"seed": args.seed + i, "joints": [lo, hi], "seconds": args.seconds, "forms": forms}
        for i in range(args.robots)
    ]
    checkpoint = Path(args.checkpoint or Path(args.out) / "calibration.partial.jsonl")
    sources = _source_digest()
    keys = [_job_key(job, sources) for job in jobs]
    saved = _saved(checkpoint)
    todo = [(job, key) for job, key in zip(jobs, keys, strict=True) if key not in saved]
    if len(todo) < len(jobs):
        print(f"bench calibration: {len(jobs) - len(todo)} robots reused from {checkpoint}", flush=True)
    pending = iter(key for _, key in todo)
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    start = time.time()
    with checkpoint.open("a") as log:

        def keep(part: list[dict]) -> None:
            key = next(pending)
            saved[key] = part
            log.write(json.dumps({"key": key, "rows": part}) + "\n")
            log.flush()

        map_jobs(_robot_task, [(job,) for job, _ in todo], args.jobs, "bench calibration", "robot", keep)
    wall = time.time() - start
    rows = [r for key in keys for r in saved[key]]
    summary = _summary(rows)
    command = (
        f"bodyhealth bench calibration --robots {args.robots} --joints {args.joints} "
        f"--seconds {args.seconds:g} --forms {','.join(forms)} --jobs {args.jobs} --seed {args.seed}"
    )
    data = {"machine": machine_note(), "command": command, "wall_s": round(wall, 1), "summary": summary}
    data["reused_robots"] = len(jobs) - len(todo)  # finished by an earlier, stopped run; not in wall_s
    data["rows"] = rows
    text = _markdown(summary, command, rows)
    out = write_results(Path(args.out), "calibration", data, text, lambda path: _plot(summary, path))
    checkpoint.unlink()
    return out


def _markdown(summary: dict, command: str, rows: list[dict]) -> str:
    n = len({r["seed"] for r in rows})
    lines = [
        "# Calibration: exact, undetermined, confidently wrong, and what a confidence is worth",
        "",
        f"`{command}` — {n} robots from the independent generator (bench/generator.py). "
        f"Machine: {machine_note()}. Regenerate with that command.",
        "",
        "| answer | form | exact | undetermined | confidently wrong |",
        "|---|---|---|---|---|",
    ]
    for answer in ANSWERS:
        for form, c in summary[answer]["forms"].items():
            tot = sum(c.values())
            lines.append(
                f"| {answer} | {form} | {c['exact']}/{tot} | {c['undetermined']}/{tot} | {c['wrong']}/{tot} |"
            )
    lines += ["", "Reliability (parts: each joint's parent, each IMU's joint):", ""]
    lines += ["| answer | confidence | parts | right |", "|---|---|---|---|"]
    for answer in ANSWERS:
        for b in summary[answer]["reliability"]:
            share = f"{b['right'] / b['parts']:.1%}" if b["parts"] else "—"
            lines.append(f"| {answer} | {b['from']:g}–{b['to']:g} | {b['parts']} | {b['right']} ({share}) |")
    lines += [
        "",
        f"Undetermined parts of the combined verdict naming no joint to move: "
        f"{summary['combined']['unnamed_undetermined']}.",
        f"CPU per robot and form (one thread): fast median {summary['fast']['cpu_s_median']:.1f} s, "
        f"networks median {summary['network']['cpu_s_median']:.1f} s "
        f"(max {summary['network']['cpu_s_max']:.1f} s).",
        "",
        "| seed | form | joints | IMUs | fast | network | combined | network undetermined |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        und = ", ".join(r.get("network_undetermined", [])) or "—"
        lines.append(
            f"| {r['seed']} | {r['form']} | {r['joints']} | {r['imus']} | {r['fast']} | {r['network']} | "
            f"{r['combined']} | {und} |"
        )
    return "\n".join(lines) + "\n"


def _plot(summary: dict, path: Path) -> None:
    import matplotlib

    from sim2real.figures import save_figure

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot([0, 1], [0, 1], color="0.7", lw=1, label="calibrated")
    for answer, marker in zip(ANSWERS, "osD", strict=True):
        pts = [b for b in summary[answer]["reliability"] if b["parts"]]
        x = [(b["from"] + b["to"]) / 2 for b in pts]
        y = [b["right"] / b["parts"] for b in pts]
        ax.plot(x, y, marker=marker, label=answer)
        for xi, yi, b in zip(x, y, pts, strict=True):
            ax.annotate(str(b["parts"]), (xi, yi), fontsize=7, xytext=(3, -9), textcoords="offset points")
    ax.set_xlabel("reported confidence (bin middle)")
    ax.set_ylabel("share of parts right")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right")
    ax.set_title("Reliability of per-part confidence (numbers: parts per bin)")
    save_figure(fig, path)
    plt.close(fig)
