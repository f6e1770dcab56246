"""Geometry drift: what the worker's drift comparison sees on every catalog robot, and what its drift
alerts raise on a healthy fleet over a long run.

Two parts, both on the simulated farm with the realistic ``robot`` sensing preset and MPU-6050 IMUs
(their errors drawn once per robot and kept, as a real IMU keeps its misalignment):

* **catalog**: every robot of ``--robots`` (default: the whole catalog) in 30 s windows as the worker
  reads them, each window's geometry estimated as the worker does
  (:func:`bodyschema.kinematics.estimate_kinematics` in the frame the service's settings set,
  ``kinematics_accelerometer_frame``, on the first window's tree with each window's encoder timing).
  The first window's geometry is the baseline; the next ``--nominal`` windows are compared with it
  (:func:`bodyschema.kinematic_drift.kinematic_findings`: any finding is false). Then each drift
  damage of the simulators' catalog is injected on a fork of the farm, and the first window wholly
  after it is compared: a turn of ``--angle-deg`` of one IMU (about a direction perpendicular to its
  joint's axis in its frame: a turn about the axis itself leaves the axis where it was), a bend of
  ``--angle-deg`` of that IMU's joint, a dead band of ``--backlash-deg`` in that joint, slides of
  ``--slide-mm`` of that IMU. Reported per robot and damage: the findings, whether the first is the
  damage's kind on its part, the change against its limit.
* **service**: the worker's real cycle (:class:`service.worker.Worker`, production settings: fast
  estimator, sensor networks retrained every ``--networks`` cycles in the worker's thread and the
  authority for baselines, hysteresis M = 2, geometry every 6 cycles) on a healthy farm of ``--fleet``
  robots for ``--hours`` of simulated time, unpaced, on an SQLite file. Every alert it raises is false;
  reported with the geometry comparisons made, the network retrains and the CPU seconds.
* **pooled** (between the two): slides of one robot's IMUs judged on lever arms pooled over windows,
  as the worker judges them (:func:`_pooled`).

Writes ``drift.md``, ``drift.json`` and ``drift.png``. The parts are independent (each its own farm,
from ``--seed``): ``--parts`` runs some of them, and ``--from`` takes the others from the
``drift.json`` of earlier runs with the same arguments, so that the long service part can run in a
process of its own beside the others; ``--jobs`` splits the service part's fleet over processes
(:func:`_service`). CPU seconds are each part's own processes'.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note, write_results
from bodyschema.progress import progress
from sim2real.figures import save_figure

__all__ = ["Watch", "add_arguments", "elsewhere", "finding_change", "run", "service_text", "window_tree"]

#: An empty argument, as a shell takes it.
_EMPTY = "''"
#: Device seconds of one window, as the worker's default.
WINDOW = 30.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default="", help="catalog robots of the catalog part (default: all)")
    parser.add_argument("--nominal", type=int, default=6, help="healthy windows compared per robot")
    parser.add_argument("--angle-deg", type=float, default=2.0, help="turn and bend injected, deg")
    parser.add_argument("--slide-mm", default="5,20", help="IMU slides injected, mm")
    parser.add_argument("--backlash-deg", type=float, default=1.0, help="dead band injected, deg")
    parser.add_argument("--fleet", default="ur5e,paper-1,quadruped", help="robots of the service part")
    parser.add_argument("--hours", type=float, default=1.0, help="simulated hours of the service part")
    parser.add_argument(
        "--jobs", type=int, default=1, help="service part: processes the fleet's robots are split over"
    )
    parser.add_argument("--pool-robot", default="ur5e", help="robot of the pooled-slides part ('' skips it)")
    parser.add_argument("--pool-slides-mm", default="5,10,20", help="slides of the pooled part, mm")
    parser.add_argument("--pool-after", type=int, default=30, help="windows judged after each slide")
    parser.add_argument(
        "--networks",
        type=int,
        default=None,
        help="service part: network retrain every N worker cycles (default: the service's; 0: off)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument("--parts", default=",".join(PARTS), help="parts to run (module docstring)")
    parser.add_argument(
        "--from",
        dest="from_dirs",
        default="",
        help="folders whose drift.json, of a run with the same arguments, hold the parts not run",
    )


#: The benchmark's parts, in the order they run.
PARTS = ("catalog", "pooled", "service")


def window_tree(rec: Any, tree: Any = None, last_lag: float = 0.0) -> Any:
    """The tree a window's geometry is estimated on, as the worker takes it: ``tree`` (the baseline's;
    None: the one the fast estimator learns from the window) with the encoder timing the fast
    estimator finds in the window, its lag search centred on ``last_lag`` (s), the lag the window
    before measured, as the worker centres it (:func:`bodyschema.timing.lag_search_centre`): two
    clocks 30 ppm apart leave the ±100 ms search within an hour."""
    from dataclasses import replace

    from bodyschema.estimate import estimate_topology
    from bodyschema.fast import FastOptions
    from bodyschema.impacts import drop_impacts
    from bodyschema.timing import lag_hinted, lag_search_centre

    hint = lag_search_centre(last_lag, FastOptions.max_lag)
    topo = lag_hinted(lambda r: estimate_topology(r, method="fast"), drop_impacts(rec), hint)
    return topo if tree is None else replace(tree, timing=dict(topo.timing))


@dataclass
class Watch:
    """One robot's farm as the worker follows it window by window: the baseline's tree once the first
    window has given it, and the lag last measured (kept where a window measures none, as the worker
    keeps it)."""

    farm: Any
    tree: Any = None
    lag: float = 0.0

    def tree_of(self, rec: Any) -> Any:
        """The tree ``rec``, the robot's next window, is estimated on (:func:`window_tree`); the first
        sets the tree."""
        from bodyschema.timing import measured_lag

        topo = window_tree(rec, self.tree, self.lag)
        lag = measured_lag(topo)
        self.lag = self.lag if lag is None else lag
        self.tree = self.tree or topo
        return topo

    def geometry(self) -> Any:
        """The next window's geometry, in the frame the service's settings set
        (``kinematics_accelerometer_frame``)."""
        from bodyschema.kinematics import KinematicsOptions, estimate_kinematics

        rec = _window(self.farm)
        return estimate_kinematics(rec, self.tree_of(rec), KinematicsOptions(accelerometer_frame=_frame()))

    def fork(self) -> Watch:
        """A fork of the farm, followed from where this one is."""
        return Watch(self.farm.fork(), self.tree, self.lag)


def _window(farm: Any, seconds: float = WINDOW) -> Any:
    """The next ``seconds`` of the farm's one robot, as one recording."""
    return farm.advance(seconds)["r"]


def _perpendicular(axis: np.ndarray) -> list[float]:
    e = np.eye(3)[int(np.argmin(np.abs(axis)))]
    v = np.cross(axis, e)
    return [float(x) for x in v / np.linalg.norm(v)]


def _found(findings: tuple, kind: str, part: str) -> dict:
    """What a damaged window's comparison gave: its findings, and whether the first names the damage."""
    first = findings[0] if findings else None
    return {
        "findings": [{"kind": f.kind, "part": f.part, "detail": f.detail} for f in findings],
        "first_right": first is not None and (first.kind, first.part) == (kind, part),
        "found": any((f.kind, f.part) == (kind, part) for f in findings),
    }


def _catalog_robot(name: str, args: argparse.Namespace) -> dict:
    from bodyschema.kinematic_drift import kinematic_findings
    from simulators.farm import Farm
    from simulators.kinematics_truth import kinematics_truth

    cpu0 = time.process_time()
    watch = Watch(Farm({"r": name}, seed=args.seed, sensing="robot"))
    base = watch.geometry()
    nominal = [kinematic_findings(base, watch.geometry()) for _ in range(args.nominal)]
    sim = watch.farm.simulation("r")
    truth = kinematics_truth(sim.robot)
    # the damaged IMU: the robot's last IMU on a moving link whose axis converged in the baseline
    imu = next(
        k
        for k in reversed(sim.robot.imu_names)
        if base.imus.get(k) is not None and base.imus[k].axis_converged
    )
    joint = truth[imu].joint
    damages: list[tuple[str, str, dict]] = [
        (
            "imu_rotated",
            f"imu:{imu}",
            {"imu": imu, "angle_deg": args.angle_deg, "about": _perpendicular(truth[imu].axis)},  # type: ignore[arg-type]
        ),
        ("axis_changed", f"joint:{joint}", {"joint": joint, "angle_deg": args.angle_deg}),
        ("backlash", f"joint:{joint}", {"joint": joint, "deg": args.backlash_deg}),
    ]
    damages += [
        ("imu_shifted", f"imu:{imu}", {"imu": imu, "meters": float(mm) / 1e3})
        for mm in _floats(args.slide_mm)
    ]
    out = []
    for kind, part, kw in damages:
        branch = watch.fork()
        branch.farm.apply_damage("r", kind, **kw)
        got = _found(kinematic_findings(base, branch.geometry()), kind, part)
        magnitude = kw.get("angle_deg", kw.get("deg", 1e3 * kw.get("meters", 0.0)))
        out.append({"kind": kind, "part": part, "magnitude": magnitude, **got})
    return {
        "robot": name,
        "imus_on_links": sum(1 for t in truth.values() if t.joint is not None),
        "axis_converged": sum(1 for k in base.imus.values() if k.joint is not None and k.axis_converged),
        "nominal_windows": args.nominal,
        "nominal_findings": [
            [{"kind": f.kind, "part": f.part, "detail": f.detail} for f in n] for n in nominal
        ],
        "damages": out,
        "cpu_s": round(time.process_time() - cpu0, 1),
    }


def _pooled(args: argparse.Namespace) -> dict:
    """Slides judged on pooled lever arms, as the worker judges them (:mod:`bodyschema.lever_pool`):
    ``n_base`` windows under the baseline, then healthy windows until ``n_recent`` more have been
    judged (any finding is false), then each slide of ``--pool-slides-mm`` on a fork, of the IMU whose
    lever arm is longest and of the robot's last IMU (a wrist's, a few cm from its axis), judged window
    by window for ``--pool-after`` windows: the windows until the first finding on its part."""
    from bodyschema.lever_pool import POOL_KEY, LeverPool, stored_drift
    from service.settings import Settings
    from simulators.farm import Farm

    cpu0 = time.process_time()
    o = Settings().pool_options
    watch = Watch(Farm({"r": args.pool_robot}, seed=args.seed, sensing="robot"))
    first = watch.geometry()
    tree = first.topology
    pool = LeverPool().add(first)
    for _ in progress(range(o.n_base - 1), desc="bench drift: pooled baseline", unit="window"):
        pool = pool.add(watch.geometry())
    base = {**first.to_json(), POOL_KEY: pool.to_json()}

    def judged(w: Watch, n: int, recent: LeverPool) -> tuple[list[tuple], LeverPool]:
        out = []
        for _ in range(n):
            kin = w.geometry()
            recent = recent.add(kin, keep=o.n_recent)
            out.append(stored_drift(base, {**kin.to_json(), POOL_KEY: recent.to_json()}, tree, o))
        return out, recent

    warm, recent = judged(watch, o.n_recent, LeverPool())
    nominal, recent = judged(watch, args.nominal, recent)
    arms = {
        k: float(np.linalg.norm(v.lever_arm))
        for k, v in first.imus.items()
        if v.converged and v.lever_arm is not None and len(pool.arms(k)) >= o.min_share * o.n_base
    }
    imus = [
        max(arms, key=arms.__getitem__),
        max(arms, key=lambda k: watch.farm.simulation("r").robot.imu_names.index(k)),
    ]
    slides = []
    for imu in imus:
        for mm in _floats(args.pool_slides_mm):
            branch = watch.fork()
            branch.farm.apply_damage("r", "imu_shifted", imu=imu, meters=mm / 1e3)
            found, _ = judged(branch, args.pool_after, recent)
            hits = [i for i, fs in enumerate(found) if any(f.part == f"imu:{imu}" for f in fs)]
            first_hit = next((f for f in found[hits[0]] if f.part == f"imu:{imu}"), None) if hits else None
            slides.append(
                {
                    "imu": imu,
                    "lever_arm_mm": round(1e3 * arms[imu], 1),
                    "scatter_mm": _scatter(pool.arms(imu), first.imus[imu].axis),
                    "mm": mm,
                    "windows_to_finding": hits[0] + 1 if hits else None,
                    "finding": None if first_hit is None else first_hit.detail,
                    "other_findings": sum(1 for fs in found for f in fs if f.part != f"imu:{imu}"),
                }
            )
    return {
        "robot": args.pool_robot,
        "n_base": o.n_base,
        "n_recent": o.n_recent,
        "alpha": o.alpha,
        "nominal_windows": len(warm) + len(nominal),
        "nominal_findings": [[f.to_json() for f in fs] for fs in (*warm, *nominal)],
        "windows_after": args.pool_after,
        "slides": slides,
        "cpu_s": round(time.process_time() - cpu0, 1),
    }


def _scatter(arms: np.ndarray, axis: np.ndarray | None) -> list[float]:
    """The std (mm) of lever arms ``arms`` (k, 3) between windows along their mean (radial), across it
    in the plane perpendicular to ``axis`` (tangential) and along ``axis``: the components a slide and
    the axis's lean move."""
    mean = arms.mean(axis=0)
    radial = mean / np.linalg.norm(mean)
    along = radial if axis is None else np.asarray(axis, dtype=float)
    tangential = np.cross(along, radial)
    tangential /= max(float(np.linalg.norm(tangential)), 1e-12)
    e = arms - mean
    return [round(1e3 * float(np.std(e @ v, ddof=1)), 2) for v in (radial, tangential, along)]


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def _service(args: argparse.Namespace) -> dict:
    """The worker's real cycle on a healthy farm for ``args.hours`` of simulated time.

    The worker judges each robot on its own (its own baseline, windows, pools and stagger), and the
    farm draws each robot's data from the farm's seed and the robot's name alone, so the fleet can be
    split over ``args.jobs`` processes, one SQLite file each, and the counts added: every robot gets
    the data and the judgements it gets in one process. CPU seconds are the processes' sum.
    """
    fleet = [x for x in args.fleet.split(",") if x.strip()]
    robots = {f"{name}-{i}": name for i, name in enumerate(fleet)}
    jobs = max(1, min(args.jobs, len(robots)))
    if jobs == 1:
        return _service_robots(args, robots)
    from bench import process_pool

    plain = argparse.Namespace(**{k: v for k, v in vars(args).items() if not callable(v)})
    with process_pool(jobs) as pool:
        parts = list(pool.map(_service_robots, [plain] * len(robots), [{k: v} for k, v in robots.items()]))
    out = dict(parts[0])
    for key in ("cycles", "interval_s", "kinematics_interval_cycles", "network_interval_cycles"):
        if any(p[key] != out[key] for p in parts):
            raise RuntimeError(f"bench drift: the service processes disagree on {key}")
    out["fleet"] = robots
    for key in ("baseline_cycle", "geometry_kept"):
        out[key] = {k: v for p in parts for k, v in p[key].items()}
    for key in ("network_retrains", "geometry_comparisons", "slide_comparisons", "drift_findings"):
        out[key] = sum(p[key] for p in parts)
    for key in ("drift_finding_details", "alerts_raised"):
        out[key] = sorted((x for p in parts for x in p[key]), key=lambda x: (x["cycle"], x["robot"]))
    out["cpu_s"] = round(sum(p["cpu_s"] for p in parts), 1)
    out["processes"] = jobs
    return out


def _service_robots(args: argparse.Namespace, robots: dict[str, str]) -> dict:
    """:func:`_service` for ``robots`` (name: catalog robot) in this process."""
    from bodyschema.findings import KINEMATIC_KINDS
    from bodyschema.threads import blas_threads, set_torch_threads
    from service.ingest.replay import recording_batch
    from service.settings import Settings
    from service.store import open_store
    from service.worker import Worker
    from simulators.farm import Farm

    set_torch_threads()
    cpu0 = time.process_time()
    with tempfile.TemporaryDirectory() as tmp, blas_threads(1):
        url = f"sqlite:///{Path(tmp) / 'drift.db'}"
        settings = Settings(database_url=url, network_interval_cycles=_networks(args))
        store = open_store(url, settings=settings)
        worker = Worker(store, settings)
        farm = Farm(robots, seed=args.seed, sensing="robot")
        interval = settings.worker_interval_seconds
        cycles = round(args.hours * 3600.0 / interval)
        raised: list[dict] = []
        drift: list[dict] = []
        judged = slides = retrains = 0
        baselines: dict[str, int] = {}
        desc = "bench drift: service" + (f" {','.join(robots)}" if len(robots) == 1 else "")
        for cycle in progress(range(cycles), desc=desc, unit="cycle"):
            for name, rec in farm.advance(interval).items():
                store.write(recording_batch(name, rec))
            for name, res in worker.run_cycle().items():
                if res.baseline_set:
                    baselines[name] = cycle + 1
                judged += res.drift_judged
                slides += res.slides_judged
                retrains += "network" in res.methods
                if res.drift_judged and res.diff is not None:
                    drift += [
                        {
                            "robot": name,
                            "cycle": cycle + 1,
                            "kind": f.kind,
                            "part": f.part,
                            "detail": f.detail,
                        }
                        for f in res.diff.findings
                        if f.kind in KINEMATIC_KINDS
                    ]
                raised += [
                    {"robot": name, "kind": t.kind, "part": t.part, "cycle": cycle + 1}
                    for t in res.transitions
                    if t.state == "active"
                ]
            if cycle % 60 == 59:
                store.prune()
        kept = {
            name: store.kinematics_baseline(name, store.baseline(name).id) is not None
            for name in robots
            if store.baseline(name)
        }
        store.close()
    return {
        "fleet": robots,
        "hours": args.hours,
        "cycles": cycles,
        "interval_s": interval,
        "kinematics_interval_cycles": settings.kinematics_interval_cycles,
        "network_interval_cycles": settings.network_interval_cycles,
        "pool_sizes": [settings.kinematics_pool_base, settings.kinematics_pool_recent],
        "network_retrains": retrains,
        "baseline_cycle": baselines,
        "geometry_kept": kept,
        "geometry_comparisons": judged,
        "slide_comparisons": slides,
        "drift_findings": len(drift),
        "drift_finding_details": drift,
        "alerts_raised": raised,
        "cpu_s": round(time.process_time() - cpu0, 1),
    }


def run(args: argparse.Namespace) -> Path:
    from bodyschema.threads import blas_threads
    from simulators.catalog import CATALOG

    names = [x for x in args.robots.split(",") if x.strip()] or sorted(CATALOG)
    parts = [x.strip() for x in args.parts.split(",") if x.strip()]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        raise SystemExit(f"bench drift: unknown parts {unknown}; the parts are {', '.join(PARTS)}")
    command = (
        f"bodyhealth bench drift --robots {','.join(names)} --nominal {args.nominal} "
        f"--angle-deg {args.angle_deg:g} --slide-mm {args.slide_mm} --backlash-deg {args.backlash_deg:g} "
        f"--pool-robot {args.pool_robot or _EMPTY} --pool-slides-mm {args.pool_slides_mm} "
        f"--pool-after {args.pool_after} --fleet {args.fleet} "
        f"--hours {args.hours:g} --networks {_networks(args)} --seed {args.seed}"
    )
    earlier = _earlier(args.from_dirs, command)
    with blas_threads(1):
        catalog = (
            [_catalog_robot(n, args) for n in progress(names, desc="bench drift: catalog", unit="robot")]
            if "catalog" in parts
            else earlier.get("catalog") or []
        )
        if "pooled" in parts:
            pooled = _pooled(args) if args.pool_robot else None
        else:
            pooled = earlier.get("pooled")
        if "service" in parts:
            service = _service(args) if args.hours > 0 else None
        else:
            service = earlier.get("service")
    here = machine_note()
    machines = {k: here if k in parts else earlier["machines"].get(k, here) for k in PARTS}
    data = {
        # where the catalog part ran, the table's CPU column: the others name theirs where it differs
        "machine": machines["catalog"],
        "machines": machines,
        "command": command,
        "accelerometer_frame": _frame(),
        "window_s": WINDOW,
        "catalog": catalog,
        "pooled": pooled,
        "service": service,
    }
    return write_results(args.out, "drift", data, _markdown(data), lambda path: _plot(catalog, path))


def _frame() -> bool:
    """The frame the service's settings set for the worker's geometry (``kinematics_accelerometer_frame``)."""
    from service.settings import Settings

    return Settings().kinematics_accelerometer_frame


def _earlier(dirs: str, command: str) -> dict:
    """The parts of the ``drift.json`` files under the folders ``dirs`` (comma-separated; later ones
    win), each checked to come from ``command`` in the frame now set (a file written before the frame
    was recorded used the gyros'), and under ``"machines"`` the machine each part ran on."""
    out: dict = {"machines": {}}
    for folder in [x for x in dirs.split(",") if x.strip()]:
        path = Path(folder) / "drift.json"
        d = json.loads(path.read_text(encoding="utf-8"))
        if d.get("command") != command or d.get("accelerometer_frame", False) != _frame():
            raise SystemExit(f"bench drift: {path} comes from another command or frame: {d.get('command')}")
        for k in PARTS:
            if d.get(k):
                out[k] = d[k]
                out["machines"][k] = d.get("machines", {}).get(k, d["machine"])
    return out


def _networks(args: argparse.Namespace) -> int:
    """The service part's network interval, in cycles, as it ran (the command line states it)."""
    from service.settings import Settings

    return Settings().network_interval_cycles if args.networks is None else int(args.networks)


def finding_change(detail: str) -> tuple[float, float] | None:
    """The change and its limit in a finding's detail ("... 1.99 deg (limit 0.23)")."""
    import re

    m = re.search(r"([0-9.]+) (?:deg|mm) \(limits? ([0-9.]+)", detail)
    return (float(m.group(1)), float(m.group(2))) if m else None


_change = finding_change  # the name the drift bench's tests read it by


def _markdown(d: dict) -> str:
    """The drift bench's markdown: its catalog table, the pooled slides and the service part."""
    lines = _catalog_lines(d)
    p = d.get("pooled")
    if p is not None:
        lines += _pooled_lines(d, p)
    s = d["service"]
    if s is not None:
        lines += _service_lines(d, s)
    lines += ["", "![drift](drift.png)", ""]
    return "\n".join(lines)


def _catalog_lines(d: dict) -> list[str]:
    """The heading, the setup and the table of the catalog robots' nominal and damaged windows."""
    lines = [
        "# Benchmark: geometry drift",
        "",
        f"`{d['command']}`",
        "",
        f"Machine: {d['machine']}. Simulated farm, `robot` sensing preset, MPU-6050 IMUs kept across "
        f"the run; {d['window_s']:g} s windows; each window's geometry as the worker estimates it ("
        + (
            "axes in the accelerometers' frame, `BODYHEALTH_KINEMATICS_ACCELEROMETER_FRAME=true`"
            if d.get("accelerometer_frame")
            else "the axes the gyros read, `BODYHEALTH_KINEMATICS_ACCELEROMETER_FRAME=false`"
        )
        + ", on the first window's tree learned by `fast`). "
        "Nominal: healthy windows compared with the first (any finding is false). Damages: injected on "
        "a fork, the first window wholly after compared with the first; *first right*: the first "
        "finding is the damage's kind on its part. Here two estimates are compared by their stated stds "
        "(`kinematic_findings`), slides too; the service judges slides against the baseline's pool "
        "instead (below), and raises no `imu_shifted` from two estimates alone.",
        "",
        "| robot | axes converged | false findings (windows) | damage | first right | findings | CPU s |",
        "|---|---:|---:|---|---|---|---:|",
    ]
    for r in d["catalog"]:
        false = sum(len(n) for n in r["nominal_findings"])
        for i, g in enumerate(r["damages"]):
            unit = "mm" if g["kind"] == "imu_shifted" else "°"
            shown = "; ".join(f"{f['kind']} {f['part']}: {f['detail']}" for f in g["findings"][:2]) or "none"
            if len(g["findings"]) > 2:
                shown += f" (+{len(g['findings']) - 2})"
            lead = (
                [
                    r["robot"],
                    f"{r['axis_converged']} / {r['imus_on_links']}",
                    f"{false} ({r['nominal_windows']})",
                ]
                if i == 0
                else ["", "", ""]
            )
            cells = [
                *lead,
                f"{g['kind']} {g['magnitude']:g} {unit} {g['part']}",
                "yes" if g["first_right"] else "no",
                shown,
                f"{r['cpu_s']:.0f}" if i == 0 else "",
            ]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return lines


def _pooled_lines(d: dict, p: dict) -> list[str]:
    """The pooled-slides part: its setup and one row per slide."""
    false = sum(len(n) for n in p["nominal_findings"])
    lines = [
        "",
        f"Pooled slides ({p['robot']}): the lever arms of the first {p['n_base']} windows against the "
        f"mean of the newest k, for every k up to {p['n_recent']}, each without its farthest "
        "(Hotelling's T² in the plane "
        f"perpendicular to the axis, false-alarm rate {p['alpha']:g} per comparison: half for the look "
        f"at all {p['n_recent']}, half shared by the others), as the worker judges them. "
        f"Healthy: {false} findings in {p['nominal_windows']} "
        f"windows judged{elsewhere(d, 'pooled')}. Each slide judged for {p['windows_after']} windows "
        "after it:",
        "",
        "| IMU | lever arm | its scatter per window (radial, tangential, along the axis) | slide | "
        "windows to its finding | "
        "finding | other findings |",
        "|---|---:|---|---:|---:|---|---:|",
    ]
    for g in p["slides"]:
        scatter = ", ".join(f"{x:g}" for x in g["scatter_mm"])
        lines.append(
            f"| {g['imu']} | {g['lever_arm_mm']:g} mm | {scatter} mm "
            f"| {g['mm']:g} mm | {g['windows_to_finding'] or 'not found'} | {g['finding'] or ''} "
            f"| {g['other_findings']} |"
        )
    return lines


def _service_lines(d: dict, s: dict) -> list[str]:
    """The service part: its summary, the alerts it raised and its drift findings."""
    lines = ["", service_text(d)]
    for a in s["alerts_raised"]:
        lines.append(f"- {a['robot']}: {a['kind']} {a['part']} at cycle {a['cycle']}")
    if s.get("drift_finding_details"):
        lines += ["", "Drift findings of the service run (a finding raises an alert after M cycles):", ""]
        lines += [
            f"- {f['robot']}, cycle {f['cycle']}: {f['kind']} {f['part']}: {f['detail']}"
            for f in s["drift_finding_details"]
        ]
    return lines


def elsewhere(d: dict, part: str) -> str:
    """' (run on MACHINE, ...)' where ``part`` of ``d`` ran on another machine than the catalog part."""
    there = d.get("machines", {}).get(part, d["machine"])
    return "" if there == d["machine"] else f" (run on {there}, taken with `--from`)"


def service_text(d: dict) -> str:
    """The service part of the results ``d`` in one sentence: the bench's table and the docs say it."""
    s = d["service"]
    robots = ", ".join(f"{k} ({v})" for k, v in s["fleet"].items())
    return (
        f"The worker's real cycle on a healthy fleet, {robots}, for {s['hours']:g} h of simulated time "
        f"({s['cycles']} cycles of {s['interval_s']:g} s, geometry every {s['kinematics_interval_cycles']} "
        f"cycles, {_pools_text(s)}, sensor {_networks_text(s)}): {_comparisons_text(s)}, "
        f"{s['drift_findings']} drift findings, {len(s['alerts_raised'])} alerts raised (on a healthy "
        f"fleet, any would be false), {s['cpu_s']:.0f} CPU s{_processes(s)}{elsewhere(d, 'service')}."
    )


def _processes(s: dict) -> str:
    n = s.get("processes", 1)
    return f" (the sum of {n} processes, the fleet's robots split over them)" if n > 1 else ""


def _pools_text(s: dict) -> str:
    """The pool sizes the service part judged slides with (runs written before they were recorded ran
    at the defaults of then: 40 and 20)."""
    n_base, n_recent = s.get("pool_sizes", (40, 20))
    return f"slides judged on pools of {n_base} and {n_recent} estimates"


def _comparisons_text(s: dict) -> str:
    """How many geometry comparisons the service part made, and how many of them judged lever arms (the
    baseline's pool full; runs written before that was recorded say nothing of it)."""
    text = f"{s['geometry_comparisons']} geometry comparisons"
    if "slide_comparisons" in s:
        text += f" ({s['slide_comparisons']} of them with the lever arms)"
    return text


def _networks_text(s: dict) -> str:
    """How the service part ran the sensor networks (runs written before they were on: off)."""
    n = int(s.get("network_interval_cycles", 0))
    if n <= 0:
        return "networks off"
    return f"networks every {n} cycles: {s.get('network_retrains', 0)} network retrains"


def _plot(catalog: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.8))
    kinds = ("imu_rotated", "axis_changed")
    for k, kind in enumerate(kinds):
        xs, ys, lims = [], [], []
        for i, r in enumerate(catalog):
            for g in r["damages"]:
                if g["kind"] != kind:
                    continue
                hit = next((f for f in g["findings"] if f["part"] == g["part"]), None)
                got = finding_change(hit["detail"]) if hit else None
                if got is not None:
                    xs.append(i + (k - 0.5) * 0.25)
                    ys.append(got[0])
                    lims.append(got[1])
        ax.bar(xs, ys, width=0.25, label=f"{kind}: change seen")
        ax.plot(xs, lims, "k_", markersize=12)
    ax.plot([], [], "k_", label="its limit (5 std + 0.2°)")
    ax.axhline(2.0, color="tab:red", lw=0.8, ls="--", label="injected, 2°")
    ax.set_xticks(range(len(catalog)))
    ax.set_xticklabels([r["robot"] for r in catalog], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("deg")
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", alpha=0.3)
    save_figure(fig, path, dpi=100)
