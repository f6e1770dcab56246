"""Topology learning: exact-tree rate and CPU cost per catalog robot and method (fast, networks, MLP).

For every robot and seed: simulate ``--seconds`` of data (MPU-6050 preset, observable excitation; cached
under ``var/bench-topology/``), run each method, and count the runs whose joint parents *and* IMU
placement equal the truth. Also: the shortest prefix of the recording on which ``fast`` is exact for
every seed, and each method's CPU seconds as a ratio to ``fast`` measured in the same run. The sensor
networks are trained once per recording for ``network`` and ``network-paper`` (same networks, two
statistics); each of the two is charged the full training time.

Per-run results are kept in ``var/bench-topology/results.json`` so that an interrupted run resumes;
``--fresh`` discards them.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run"]

log = logging.getLogger(__name__)

ALL_ROBOTS = (
    "paper-1",
    "paper-2",
    "paper-3",
    "paper-4",
    "paper-5",
    "paper-6",
    "ur5e",
    "quadruped",
    "humanoid",
    "dual-arm",
)
METHODS = ("fast", "network", "network-paper", "mlp")
CACHE = Path("var/bench-topology")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default=",".join(ALL_ROBOTS), help="comma-separated catalog robots")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per robot (default 5)")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    parser.add_argument("--seconds", type=float, default=60.0, help="recording length (default 60)")
    parser.add_argument(
        "--durations",
        default="1,1.5,2,3,5,7.5,10,15,20,30,45,60",
        help="prefix lengths tried for the shortest exact recording of fast",
    )
    parser.add_argument("--epochs", type=int, default=40, help="training epochs of network and mlp")
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="training processes run side by side (CPU seconds are still per run)",
    )
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "topology.md")
    parser.add_argument("--fresh", action="store_true", help="ignore per-run results kept from earlier runs")
    parser.add_argument(
        "--no-train",
        action="store_true",
        help="report network/mlp results only where kept from earlier runs (no training)",
    )
    parser.add_argument(
        "--reextract",
        action="store_true",
        help="redo the dependency extraction from the cached trained-network Jacobians",
    )


@dataclass
class _Store:
    path: Path
    data: dict[str, Any] = field(default_factory=dict)

    def load(self) -> _Store:
        if self.path.exists():
            self.data = json.loads(self.path.read_text())
        return self

    def get(self, key: str) -> Any:
        return self.data.get(key)

    def put(self, key: str, value: Any) -> None:
        self.data[key] = value
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.data, indent=1))
        tmp.replace(self.path)


def _recording(robot: str, seconds: float, seed: int) -> Any:
    from simulators.recording_io import load_recording, save_recording
    from simulators.simulation import simulate

    path = CACHE / f"{robot}-{seconds:g}s-seed{seed}.npz"
    if path.exists():
        return load_recording(path)
    rec = simulate(robot, seconds=seconds, seed=seed, imu_model="mpu6050", excitation="observable")
    save_recording(rec, path)
    return rec


def _kept(robot: str, seed: int, method: str, epochs: int) -> bool:
    """Whether trained-network Jacobians for this run are cached (``--no-train`` reports only those)."""
    kind = "mlp" if method == "mlp" else "network"
    return (CACHE / f"jbar-{robot}-{seed}-{kind}-e{epochs}.npz").exists()


def _exact(topo: Any, rec: Any) -> bool:
    return bool(topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map)


def _separation(res: Any, rec: Any) -> dict[str, float | int]:
    """How well a run's dependency features split true from false entries (decided joints only):
    the entries the extraction got wrong, the smallest true feature and the largest false one."""
    truth = rec.truth_dependency
    decided = np.ones(truth.shape[1], dtype=bool)
    decided[res.undetermined] = False
    feats, truth = res.features[:, decided], truth[:, decided]
    return {
        "wrong": int((res.dependency[:, decided] != truth).sum()),
        "true_min": float(feats[truth].min()) if truth.any() else float("nan"),
        "false_max": float(feats[~truth].max()) if (~truth).any() else float("nan"),
    }


def _run_networks(
    rec: Any, methods: list[str], epochs: int, seed: int, key: str
) -> dict[str, dict[str, Any]]:
    """network / network-paper from one training, mlp from its own; CPU seconds and exactness each."""
    from bodyschema.dependency import dependency_from_jacobian, network_jacobian
    from bodyschema.estimate import topology_from_dependency
    from bodyschema.fast import insufficient_excitation

    out: dict[str, dict[str, Any]] = {}
    derived = rec.derived()
    und = insufficient_excitation(derived.qd, rec.gyro)

    def finish(name: str, jbar: np.ndarray, statistic: str, train_s: float) -> None:
        t0 = time.process_time()
        res = dependency_from_jacobian(jbar, statistic, und, rng=np.random.default_rng(seed + 1))
        try:
            topo = topology_from_dependency(
                res.dependency,
                rec.imu_names,
                rec.joint_names,
                undetermined=[rec.joint_names[j] for j in res.undetermined],
                method=name,
                evidence=res.evidence,
            )
            exact = _exact(topo, rec)
        except ValueError as err:  # no tree fits the extracted matrix at all
            log.info("%s: no tree (%s)", name, err)
            exact = False
        out[name] = {
            "exact": exact,
            "seconds": train_s + time.process_time() - t0,
            "delta": res.delta,
            **_separation(res, rec),
        }

    def trained(kind: str) -> tuple[np.ndarray, float]:
        """Jacobian norms of the trained networks, cached with their training CPU time."""
        path = CACHE / f"jbar-{key}-{kind}-e{epochs}.npz"
        if path.exists():
            with np.load(path) as z:
                return z["jbar"], float(z["seconds"])
        t0 = time.process_time()
        jbar = network_jacobian(rec, kind=kind, epochs=epochs, seed=seed).jbar
        secs = time.process_time() - t0
        np.savez_compressed(path, jbar=jbar.astype(np.float32), seconds=secs)
        return jbar, secs

    if "network" in methods or "network-paper" in methods:
        jbar, train_s = trained("network")
        for name, stat in (("network", "moment"), ("network-paper", "variance")):
            if name in methods:
                finish(name, jbar, stat, train_s)
    if "mlp" in methods:
        jbar, train_s = trained("mlp")
        finish("mlp", jbar, "moment", train_s)
    return out


def _network_job(robot: str, seconds: float, seed: int, todo: list[str], epochs: int) -> dict[str, Any]:
    """One recording's network/MLP runs (in a worker process with ``--jobs`` > 1)."""
    from bodyschema.threads import set_torch_threads

    set_torch_threads()
    return _run_networks(_recording(robot, seconds, seed), todo, epochs, seed, f"{robot}-{seed}")


def run(args: argparse.Namespace) -> Path:
    from bodyschema.threads import set_torch_threads

    set_torch_threads()
    robots, methods, durations = _parse(args)
    store = _Store(CACHE / "results.json")
    if not args.fresh:
        store.load()
    # pass 1, in this process: recordings, fast and its prefixes (cheap), and the list of trainings
    shape, shortest_ok, jobs = _fast_pass(args, robots, methods, durations, store)
    # pass 2: the trainings, one process per core asked for; only this process writes the results
    _train(args, jobs, store)
    rows = [
        _row(args, robot, methods, durations, shape[robot], shortest_ok[robot], store) for robot in robots
    ]
    return _write(rows, methods, args)


def _parse(args: argparse.Namespace) -> tuple[list[str], list[str], list[float]]:
    """Robots, methods (checked) and prefix durations (ascending) from the command line."""
    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
    durations = sorted(float(d) for d in args.durations.split(",") if d.strip())
    return robots, methods, durations


def _fast_pass(
    args: argparse.Namespace, robots: list[str], methods: list[str], durations: list[float], store: _Store
) -> tuple[dict[str, tuple[int, int]], dict[str, dict[float, int]], list[tuple[str, int, list[str]]]]:
    """Per robot: its size, per prefix duration the seeds on which ``fast`` is exact, and the network
    trainings still to run as (robot, seed, methods)."""
    from bodyschema.progress import progress

    net_methods = [m for m in methods if m != "fast"]
    shape: dict[str, tuple[int, int]] = {}
    shortest_ok: dict[str, dict[float, int]] = {}
    jobs: list[tuple[str, int, list[str]]] = []
    for robot in progress(robots, desc="bench topology: recordings and fast", unit="robot"):
        shortest_ok[robot] = {d: 0 for d in durations}
        for seed in range(args.seeds):
            rec = _recording(robot, args.seconds, seed)
            shape[robot] = (rec.n_joints, rec.n_imus)
            key = f"{robot}|{args.seconds:g}|{seed}"
            if "fast" in methods and store.get(f"{key}|fast") is None:
                _run_fast(rec, key, store)
            for d in durations:
                shortest_ok[robot][d] += int(bool(_fast_prefix_exact(rec, key, d, store)))
            todo = [
                m for m in net_methods if args.reextract or store.get(f"{key}|{m}|e{args.epochs}") is None
            ]
            if todo and args.no_train:
                todo = [m for m in todo if _kept(robot, seed, m, args.epochs)]
            if todo:
                jobs.append((robot, seed, todo))
    return shape, shortest_ok, jobs


def _run_fast(rec: Any, key: str, store: _Store) -> None:
    from bodyschema.estimate import estimate_topology

    topo = estimate_topology(rec, method="fast", timer=time.process_time)
    store.put(f"{key}|fast", {"exact": _exact(topo, rec), "seconds": topo.seconds})


def _fast_prefix_exact(rec: Any, key: str, d: float, store: _Store) -> Any:
    """Whether ``fast`` is exact on the first ``d`` seconds of ``rec`` (kept in ``store``)."""
    from bodyschema.estimate import estimate_topology

    dk = f"{key}|fast-prefix|{d:g}"
    ok = store.get(dk)
    if ok is None:
        part = rec.select(slice(0, round(d * rec.sample_rate)))
        try:
            ok = _exact(estimate_topology(part, method="fast"), part)
        except ValueError:
            ok = False
        store.put(dk, ok)
    return ok


def _train(args: argparse.Namespace, jobs: list[tuple[str, int, list[str]]], store: _Store) -> None:
    """Run the network trainings (side by side with ``--jobs`` > 1) and keep their results."""
    from concurrent.futures import Future, as_completed

    from bench import process_pool
    from bodyschema.progress import progress

    bar = progress(total=len(jobs), desc="bench topology: networks", unit="run")

    def keep(robot: str, seed: int, res: dict[str, Any]) -> None:
        for m, r in res.items():
            store.put(f"{robot}|{args.seconds:g}|{seed}|{m}|e{args.epochs}", r)
        bar.update(1)

    if args.jobs > 1 and len(jobs) > 1:
        with process_pool(args.jobs) as pool:
            futures: dict[Future[dict[str, Any]], tuple[str, int]] = {
                pool.submit(_network_job, robot, args.seconds, seed, todo, args.epochs): (robot, seed)
                for robot, seed, todo in jobs
            }
            for fut in as_completed(futures):
                keep(*futures[fut], fut.result())
    else:
        for robot, seed, todo in jobs:
            keep(robot, seed, _network_job(robot, args.seconds, seed, todo, args.epochs))
    bar.close()


def _row(
    args: argparse.Namespace,
    robot: str,
    methods: list[str],
    durations: list[float],
    shape: tuple[int, int],
    shortest_ok: dict[float, int],
    store: _Store,
) -> dict[str, Any]:
    """One robot's line of the report: its size, the shortest exact prefix and each method's summary."""
    shortest = next((d for d in durations if shortest_ok[d] == args.seeds), None)
    n_joints, n_imus = shape
    row: dict[str, Any] = {"robot": robot, "joints": n_joints, "imus": n_imus, "shortest": shortest}
    for m in methods:
        row[m] = _method_summary(args, robot, m, store)
    return row


def _method_summary(args: argparse.Namespace, robot: str, m: str, store: _Store) -> dict[str, Any]:
    """Exact runs, runs and median CPU seconds of method ``m`` over the seeds (learned methods: also
    their feature separation, when every run recorded it)."""
    name = "fast" if m == "fast" else f"{m}|e{args.epochs}"
    runs = [
        r
        for seed in range(args.seeds)
        if (r := store.get(f"{robot}|{args.seconds:g}|{seed}|{name}")) is not None
    ]
    summary: dict[str, Any] = {
        "exact": sum(int(r["exact"]) for r in runs),
        "runs": len(runs),
        "seconds": float(np.median([r["seconds"] for r in runs])) if runs else float("nan"),
    }
    if m != "fast" and runs and all("wrong" in r for r in runs):
        summary["wrong"] = [int(r["wrong"]) for r in runs]
        summary["true_min"] = float(np.nanmin([r["true_min"] for r in runs]))
        summary["false_max"] = float(np.nanmax([r["false_max"] for r in runs]))
    return summary


def _write(rows: list[dict[str, Any]], methods: list[str], args: argparse.Namespace) -> Path:
    out: Path = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    head = ["robot", "joints", "IMUs"] + [f"{m} exact" for m in methods]
    head += ["shortest exact `fast` (s)", "`fast` CPU s"]
    head += [f"{m} CPU ×fast" for m in methods if m != "fast"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["robot"], str(r["joints"]), str(r["imus"])]
        cells += [f"{r[m]['exact']}/{r[m]['runs']}" if r[m]["runs"] else "not run" for m in methods]
        cells.append("—" if r["shortest"] is None else f"{r['shortest']:g}")
        fast_s = r["fast"]["seconds"] if "fast" in methods else float("nan")
        cells.append(f"{fast_s:.2f}")
        for m in methods:
            if m != "fast":
                sec = r[m]["seconds"]
                cells.append(f"{sec / fast_s:.0f}× ({sec:.0f} s)" if r[m]["runs"] else "—")
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    separation = _separation_table(rows, [m for m in methods if m != "fast"])
    png = out.with_suffix(".png")
    _plot(rows, methods, png)
    text = f"""# Benchmark: topology learning

`bodyhealth bench topology --robots {args.robots} --seeds {args.seeds} --methods {",".join(methods)} \
--seconds {args.seconds:g} --epochs {args.epochs} --jobs {args.jobs}`

Machine: {machine_note()}. CPU seconds are process time (all threads) of the process that ran
the method, medians over seeds; ratios are to `fast` on the same recordings in the same run. Data:
`mpu6050` IMU preset (bias, scale, cross-axis, noise), observable excitation, {args.seconds:g} s at
100 Hz. *Exact* = every joint's parent and every IMU's joint equal the truth. *Shortest exact*: the
shortest prefix (of {args.durations} s) on which `fast` is exact for all {args.seeds} seeds.{_note(args)}

{table}

![exact rate and CPU time per method]({png.name})
{separation}"""
    out.write_text(text)
    (out.with_suffix(".json")).write_text(json.dumps(rows, indent=1))
    return out


def _separation_table(rows: list[dict[str, Any]], methods: list[str]) -> str:
    """Why a learned method misses: its features (Eq. 16) against the truth, worst seed per robot."""
    methods = [m for m in methods if any("wrong" in r[m] for r in rows)]
    if not methods:
        return ""
    head = ["robot"] + [f"{m}: smallest true / largest false (wrong entries per seed)" for m in methods]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["robot"]]
        for m in methods:
            c = r[m]
            cells.append(
                f"{c['true_min']:.3f} / {c['false_max']:.3f} ({', '.join(map(str, c['wrong']))})"
                if "wrong" in c
                else "—"
            )
        lines.append("| " + " | ".join(cells) + " |")
    return f"""
## Feature separation

The dependency features (Eq. 16, normalized per IMU) of every learned method against the truth, over
the joints the data decides: the smallest feature of a true dependency and the largest of a false one,
worst over the seeds, and the matrix entries the extraction got wrong in each seed. A tree can only be
exact for every seed when the first number clears the second by a margin δ can sit in; the correction
repairs a few wrong entries, not a wide overlap.

{chr(10).join(lines)}
"""


def _note(args: argparse.Namespace) -> str:
    if not getattr(args, "no_train", False):
        return ""
    return (
        "\n\nNetwork and MLP columns count only the runs whose networks were trained in earlier "
        '(interrupted) runs of this benchmark (`--no-train`); "not run" means none was.'
    )


def _plot(rows: list[dict[str, Any]], methods: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 4.5))
    x = np.arange(len(rows))
    w = 0.8 / max(len(methods), 1)
    for i, m in enumerate(methods):
        rate = [r[m]["exact"] / r[m]["runs"] if r[m]["runs"] else np.nan for r in rows]
        secs = [r[m]["seconds"] for r in rows]
        a1.bar(x + i * w, rate, w, label=m)
        a2.bar(x + i * w, secs, w, label=m)
    for ax in (a1, a2):
        ax.set_xticks(x + 0.4 - w / 2, [r["robot"] for r in rows], rotation=30, ha="right")
    a1.set_ylabel("exact trees (share of seeds)")
    a2.set_ylabel("CPU seconds (median)")
    a2.set_yscale("log")
    a1.legend(fontsize=8)
    save_figure(fig, path, dpi=110)
