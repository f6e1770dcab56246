"""Alerts in time on a busy machine: baseline, pending and active alerts, false alerts, approvals.

Each run starts ``--busy`` processes spinning ``while True: pass``, each pinned to a core of its own,
then the demo as ``make run`` starts it (``bodyhealth serve --demo``, a process of its own on port 0,
its own data folder and SQLite file; ``--speed`` passed on), and polls its alerts route from the
start. Measured per run, on the bench's clock:

* from the service's start until every demo robot has a baseline (target 3 min);
* a healthy phase of ``--healthy-seconds``: ``--approvals`` operator approvals
  (``POST …/baseline``) spread over it, the first half on their own, the second half while a retrain
  flood (``POST …/topology/retrain`` at ``--flood-rps``) is answered, mostly with 429; with
  ``--restart`` the service is stopped with SIGTERM between the halves and started again on the same
  data;
* then the ``--damage`` injections over ``POST …/simulate/damage`` (by default one per demo robot,
  together) and, for each, the time until its alert (kind and part as injected) is seen pending
  (target 90 s) and active (target 5 min); a damage the route refuses is reported as not injectable;
* false alerts: every alert of the run whose robot, kind and part is no damage injected before it
  (those raised after the restart counted apart).

A drift damage (``imu_rotated``, ...) is judged against the geometry the worker learns under the
baseline; one injected before that geometry is learned would become part of it. So the injections wait
(``--geometry-limit``) until every robot to get one has its geometry, and the approvals go to the other
robots (an approval has the geometry learned afresh). Every wait ends at its own limit and at the
run's ``--max-run-seconds``; a value not seen by then is reported as missed. Results: ``alerts.json``,
``alerts.md``, ``alerts.png``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import httpx

from bench import RESULTS_DIR, machine_note, write_results
from bench.alerts_report import (
    TARGETS,
    Injection,
    classify,
    damage_latency,
    key_str,
    markdown,
    parse_damage,
    percentiles_ms,
    plot,
    summarize,
)
from bench.alerts_service import AlertWatch, Api, Approver, BusyLoops, RetrainFlood, Service

__all__ = ["DEFAULT_DAMAGES", "Options", "add_arguments", "run", "run_once"]

#: One damage per demo robot: an IMU moved to the next link (paper-3), a locked wrist (UR5e) and an
#: IMU mount turned 2 degrees (quadruped).
DEFAULT_DAMAGES: tuple[str, ...] = (
    "paper-3-1:imu_moved:imu=imu0,to=j2",
    "ur5e-1:joint_locked:joint=wrist_2",
    "quadruped-1:imu_rotated:imu=imu25,angle_deg=2",
)
#: The damage kinds judged on the robot's geometry (kinematics), which a fresh baseline relearns.
GEOMETRY_KINDS = frozenset({"imu_rotated", "imu_shifted", "axis_changed", "backlash"})
#: Full-bench values below which the report says it is a short run: 5 runs, the first of them with a
#: 1-hour healthy phase (the false-alert check), the others with a shorter one (the timing checks).
FULL_RUNS, FULL_HEALTHY_S, FULL_OTHER_HEALTHY_S = 5, 3600.0, 300.0


@dataclass(frozen=True)
class Options:
    """What one invocation measures (the command line's options)."""

    runs: int = FULL_RUNS
    busy: int = 2
    speed: float = 1.0
    healthy_seconds: float = FULL_OTHER_HEALTHY_S
    first_healthy_seconds: float | None = FULL_HEALTHY_S
    restart: bool = False
    damages: tuple[str, ...] = DEFAULT_DAMAGES
    approvals: int = 50
    flood_rps: float = 5.0
    poll_seconds: float = 2.0
    startup_limit: float = 120.0
    baseline_limit: float = 2 * TARGETS["baseline_s"]
    geometry_limit: float = 300.0
    alert_limit: float = 2 * TARGETS["active_s"]
    max_run_seconds: float | None = None
    token: str | None = field(default=None, repr=False)
    out: Path = RESULTS_DIR
    name: str = "alerts"

    def __post_init__(self) -> None:
        for name in ("runs", "poll_seconds", "speed", "startup_limit"):
            if not getattr(self, name) > 0:
                raise ValueError(f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}")
        numbers = (self.busy, self.approvals, self.flood_rps, self.healthy_seconds, self.first_healthy_s)
        if min(numbers) < 0:
            raise ValueError(
                "--busy, --approvals, --flood-rps and the healthy phases' seconds must not be negative"
            )
        for spec in self.damages:
            parse_damage(spec)

    @property
    def first_healthy_s(self) -> float:
        """The first run's healthy phase (``--first-healthy-seconds``, else ``--healthy-seconds``)."""
        return self.healthy_seconds if self.first_healthy_seconds is None else self.first_healthy_seconds

    def for_run(self, index: int) -> Options:
        """The options of run ``index`` (1-based): the first has its own healthy phase."""
        return replace(self, healthy_seconds=self.first_healthy_s) if index == 1 else self

    @property
    def run_seconds(self) -> float:
        """The run's time bound: ``--max-run-seconds``, else every phase's limit added up."""
        if self.max_run_seconds is not None:
            return self.max_run_seconds
        starts = self.startup_limit * (2 if self.restart else 1)
        return (
            starts + self.baseline_limit + self.healthy_seconds + self.geometry_limit + self.alert_limit + 60
        )

    @classmethod
    def of(cls, args: argparse.Namespace) -> Options:
        known = {f.name for f in fields(cls)}
        kw = {k: v for k, v in vars(args).items() if k in known}
        if kw.get("damages") is not None:
            kw["damages"] = tuple(d for d in kw["damages"] if d != "none")
        else:
            kw.pop("damages", None)
        return cls(**kw)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=FULL_RUNS, help="repeats, each with a fresh service")
    p.add_argument("--busy", type=int, default=2, help="busy-loop processes beside the service, one per core")
    p.add_argument("--speed", type=float, default=1.0, help="demo farm speed, x real time")
    p.add_argument(
        "--healthy-seconds", type=float, default=FULL_OTHER_HEALTHY_S, help="healthy phase of runs 2 on"
    )
    p.add_argument(
        "--first-healthy-seconds",
        type=float,
        default=FULL_HEALTHY_S,
        help="healthy phase of the first run (the long false-alert check)",
    )
    p.add_argument("--restart", action="store_true", help="SIGTERM and restart the service mid healthy phase")
    p.add_argument(
        "--damage",
        dest="damages",
        action="append",
        metavar="ROBOT:KIND[:k=v,...]",
        help="a damage to inject (repeatable; 'none' for none); default: " + " ".join(DEFAULT_DAMAGES),
    )
    p.add_argument(
        "--approvals", type=int, default=50, help="baseline approvals spread over the healthy phase"
    )
    p.add_argument("--flood-rps", type=float, default=5.0, help="retrain requests/s in the flood (0: none)")
    p.add_argument("--poll-seconds", type=float, default=2.0, help="alerts and robots polled this often")
    p.add_argument("--startup-limit", type=float, default=120.0, help="s for the service to bind its port")
    p.add_argument(
        "--baseline-limit", type=float, default=2 * TARGETS["baseline_s"], help="s to wait for baselines"
    )
    p.add_argument("--geometry-limit", type=float, default=300.0, help="s to wait for geometries to relearn")
    p.add_argument("--alert-limit", type=float, default=2 * TARGETS["active_s"], help="s to wait for alerts")
    p.add_argument("--max-run-seconds", type=float, help="bound of one run (default: the limits added up)")
    p.add_argument("--token", help="API token: the service requires it, the bench sends it")
    p.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    p.add_argument("--name", default="alerts", help="results file name (alerts-quiet for a quiet machine)")


def _log(msg: str) -> None:
    print(f"[bench alerts] {msg}", flush=True)


class _Run:
    """One run: the processes, the phases in order, and what they measured."""

    def __init__(self, opts: Options, index: int, data_dir: Path) -> None:
        self.o = opts
        self.index = index
        self.service = Service(data_dir, opts.speed, opts.token)
        self.api = Api(self.service, opts.token)
        self.t0 = time.monotonic()
        self.deadline = self.t0 + opts.run_seconds
        self.notes: list[str] = []
        self.robots: list[str] = []
        self.baselines: dict[str, float | None] = {}
        self.injections: list[Injection] = []
        self.approvals: dict[str, dict[str, Any]] = {}
        self.flood: dict[str, Any] = {"rps": opts.flood_rps, "requests": 0, "statuses": {}}
        self.restart: dict[str, Any] | None = None
        self.last_approval_wall: dict[str, float] = {}
        self.watch: AlertWatch | None = None
        self.phases: dict[str, list[float]] = {}
        self.list_errors = 0
        self.approved = 0
        self.limits: dict[str, float] = {}
        self.baseline_sources: dict[str, str | None] = {}
        self.waiting: dict[str, str] = {}

    # ------------------------------------------------------------------ helpers
    def now(self) -> float:
        """Seconds since the service was started."""
        return time.monotonic() - self.t0

    def left(self, limit: float) -> float:
        return max(0.0, min(limit, self.deadline - time.monotonic()))

    def check_alive(self) -> None:
        if not self.service.alive():
            raise RuntimeError(f"the service ended at {self.now():.0f} s:\n{self.service.tail()}")

    def ticks(self, until: float, every: float) -> Iterator[int]:
        """Yield now and then every ``every`` s until monotonic ``until`` (and the run's bound), at
        most as often as that time allows, the service checked alive before each."""
        until = min(until, self.deadline)
        for k in range(int(max(0.0, until - time.monotonic()) / every) + 2):
            if time.monotonic() >= until:
                return
            self.check_alive()
            yield k
            time.sleep(max(0.0, min(every, until - time.monotonic())))

    def sleep_until(self, until: float) -> None:
        """Sleep to monotonic ``until`` (bounded by the run), checking the service every second."""
        for _ in self.ticks(until, 1.0):
            pass

    def readiness(self) -> str:
        """``/readyz`` in a few words (a dead worker or database shows there), for a run that missed."""
        try:
            r = self.api.get("/readyz")
        except httpx.HTTPError as err:
            return type(err).__name__
        return f"{r.status_code} {r.text[:300]}"

    def phase(self, name: str, start: float) -> None:
        self.phases[name] = [round(start, 1), round(self.now(), 1)]

    # ------------------------------------------------------------------ phases
    def start(self) -> None:
        self.t0 = time.monotonic()
        self.deadline = self.t0 + self.o.run_seconds
        url = self.service.start(self.left(self.o.startup_limit))
        _log(f"run {self.index}: service at {url} after {self.now():.1f} s (data in {self.service.data_dir})")
        self.watch = AlertWatch(self.api, self.t0, self.o.poll_seconds, self.deadline)
        self.watch.start()

    def wait_baselines(self) -> None:
        """Poll the robot list until every demo robot has a baseline, or the limit."""
        from service.daemon import DEMO_ROBOTS

        self.limits["baseline_s"] = self.now() + self.left(self.o.baseline_limit)
        until = time.monotonic() + self.left(self.o.baseline_limit)
        last_log = 0.0
        for _ in self.ticks(until, self.o.poll_seconds):
            try:
                listed = self.api.get("/api/v1/robots").json()
            except (httpx.HTTPError, ValueError):  # busy or still starting: poll again
                listed, self.list_errors = [], self.list_errors + 1
            for r in listed:
                self.baselines.setdefault(r["name"], None)
                status = r.get("status") or {}
                if r.get("has_baseline") and self.baselines[r["name"]] is None:
                    self.baselines[r["name"]] = self.now()
                    self.baseline_sources[r["name"]] = status.get("baseline_source")
                    _log(f"run {self.index}: baseline of {r['name']} at {self.now():.0f} s")
                waits = [w.get("what") for w in status.get("waiting") or [] if isinstance(w, dict)]
                self.waiting[r["name"]] = "; ".join(map(str, waits))
            done = len(self.baselines) >= len(DEMO_ROBOTS) and all(
                v is not None for v in self.baselines.values()
            )
            if done:
                break
            if time.monotonic() - last_log > 30:
                last_log = time.monotonic()
                got = {k: v if v is None else round(v) for k, v in self.baselines.items()}
                _log(f"run {self.index}: {self.now():.0f} s, baselines {got}")
        self.robots = sorted(self.baselines)
        if not self.baselines or None in self.baselines.values():
            waits = {k: self.waiting.get(k) for k, v in self.baselines.items() if v is None}
            self.notes.append(f"baselines missed; the worker waited on {waits}; /readyz: {self.readiness()}")
        if self.watch is not None:
            self.watch.robots = self.robots
        self.phase("baseline", 0.0)

    def client_approvals(self, robots: list[str], n: int, seconds: float) -> list[list[Any]]:
        """The rows of :class:`Approver`: ``n`` approvals over ``seconds`` from its start."""
        client = Approver(self.service.url, self.o.token)
        try:
            client.start(robots, self.approved, n, seconds, self.deadline)
            start = time.monotonic()
            client.go()
            self.sleep_until(start + seconds)
            return client.rows()
        finally:
            client.kill()

    def approve_spread(self, n: int, seconds: float, label: str) -> None:
        """``n`` approvals spaced evenly over ``seconds``, the robots in turn (those no geometry damage
        is planned for, where there are such), sent and timed by a client process of their own
        (:mod:`bench.approver`: this process's poller and flood would queue the timer behind them);
        latency per request, and each one's time, robot, milliseconds, the service's own milliseconds
        (its ``Server-Timing``; what is left is the network, the server's parsing and the scheduling of
        both processes) and of those the milliseconds its store write waited for the lock, held it and
        committed."""
        robots = [r for r in self.robots if self.baselines.get(r) is not None]
        robots = [r for r in robots if r not in self.geometry_robots()] or robots
        rows = []
        if robots and n:
            rows = self.client_approvals(robots, n, seconds)
        else:
            self.sleep_until(time.monotonic() + seconds)
        lat, statuses, each = [], {}, []
        for t, robot, ms, app_ms, status, wall, *store in rows:
            self.approved += 1
            self.last_approval_wall[robot] = max(wall, self.last_approval_wall.get(robot, 0.0))
            lat.append(ms / 1e3)
            each.append([round(t - self.t0, 1), robot, ms, app_ms, *store])
            statuses[status] = statuses.get(status, 0) + 1
        self.approvals[label] = {**percentiles_ms(lat), "statuses": statuses}
        _log(f"run {self.index}: approvals ({label}) {self.approvals[label]}")
        self.approvals[label]["each"] = each

    def healthy(self) -> None:
        """The healthy phase: quiet approvals, the restart, approvals under the retrain flood."""
        half = self.o.healthy_seconds / 2
        n_quiet = self.o.approvals // 2
        t = self.now()
        _log(f"run {self.index}: healthy phase of {self.o.healthy_seconds:g} s from {t:.0f} s")
        self.approve_spread(n_quiet, half, "quiet")
        if self.o.restart:
            self.restart_service()
        flood = None
        if self.o.flood_rps > 0 and self.robots:
            end = time.monotonic() + half
            flood = RetrainFlood(
                self.api, self.robots, self.o.flood_rps, end, int(half * self.o.flood_rps) + 1
            )
            flood.start()
        try:
            self.approve_spread(self.o.approvals - n_quiet, half, "flood")
        finally:
            if flood is not None:
                flood.stop()
                self.flood = flood.result()
                _log(f"run {self.index}: retrain flood {self.flood}")
        self.phase("healthy", t)

    def restart_service(self) -> None:
        t = self.now()
        _log(f"run {self.index}: SIGTERM at {t:.0f} s")
        code = self.service.stop(timeout=120)
        stopped = self.now()
        self.service.start(self.left(self.o.startup_limit))
        for _ in self.ticks(self.deadline, 0.5):
            try:
                if self.api.get("/livez").status_code == 200:
                    break
            except httpx.HTTPError:  # not answering yet
                pass
        self.restart = {"t_s": t, "exit_code": code, "stop_s": stopped - t, "down_s": self.now() - t}
        _log(f"run {self.index}: restarted, {self.restart}")

    def geometry_robots(self) -> set[str]:
        return {robot for robot, kind, _ in map(parse_damage, self.o.damages) if kind in GEOMETRY_KINDS}

    def wait_geometry(self, robots: set[str]) -> None:
        """Until each of ``robots`` has a geometry learned under its baseline, after its last approval
        if it had one (or the limit)."""
        until = time.monotonic() + self.left(self.o.geometry_limit)
        t = self.now()
        waiting = {r for r in robots if self.baselines.get(r) is not None}
        for _ in self.ticks(until, self.o.poll_seconds):
            if not waiting:
                break
            for r in sorted(waiting):
                try:
                    base = (self.api.get(f"/api/v1/robots/{r}/kinematics").json() or {}).get("baseline")
                except (httpx.HTTPError, ValueError):  # busy: ask again
                    continue
                if base and float(base.get("wall_time", 0)) > self.last_approval_wall.get(r, 0.0):
                    waiting.discard(r)
        if waiting:
            self.notes.append(f"injected before a geometry was learned under the baseline: {sorted(waiting)}")
        self.phase("geometry", t)

    def inject(self) -> None:
        specs = [parse_damage(s) for s in self.o.damages]
        self.wait_geometry(self.geometry_robots())
        late = self.left(self.o.alert_limit) < self.o.poll_seconds  # no time left to see an alert
        for robot, kind, params in specs:
            skip = (
                "the run's bound came" if late else "no baseline" if self.baselines.get(robot) is None else ""
            )
            if skip:
                self.injections.append(Injection(robot, kind, params, detail=f"not injected: {skip}"))
                continue
            t = self.now()
            try:
                r = self.api.post(f"/api/v1/robots/{robot}/simulate/damage", {"kind": kind, **params})
            except httpx.HTTPError as err:
                self.injections.append(Injection(robot, kind, params, detail=f"request failed: {err}"))
                continue
            if r.status_code == 201:
                found = r.json()["truth"]["findings"][0]
                part = f"imu:{found['imu']}" if found.get("imu") else f"joint:{found.get('joint')}"
                self.injections.append(Injection(robot, kind, params, t=t, part=part))
            else:
                detail = f"not injectable ({r.status_code}): {r.text[:300]}"
                self.injections.append(Injection(robot, kind, params, detail=detail))
            _log(f"run {self.index}: {robot} {kind} {params} at {t:.0f} s -> {r.status_code}")

    def wait_alerts(self) -> None:
        """Until every applied damage's alert is seen active (or the limit)."""
        assert self.watch is not None
        t = self.now()
        self.limits["alert_s"] = self.left(self.o.alert_limit)
        until = time.monotonic() + self.limits["alert_s"]
        applied = [i for i in self.injections if i.applied]
        last_log = 0.0
        for _ in self.ticks(until if applied else 0.0, self.o.poll_seconds):
            seen = self.watch.snapshot()
            lat = [damage_latency(seen, i) for i in applied]
            if all(x["active_s"] is not None for x in lat):
                break
            if time.monotonic() - last_log > 30:
                last_log = time.monotonic()
                states = {
                    f"{i.robot} {i.kind}": {k: round(v) for k, v in x["states"].items()}
                    for i, x in zip(applied, lat, strict=True)
                }
                _log(f"run {self.index}: {self.now():.0f} s, alerts {states}")
        self.phase("alerts", t)

    # ------------------------------------------------------------------ the run
    def result(self) -> dict[str, Any]:
        seen = self.watch.snapshot() if self.watch is not None else {}
        damages = []
        for i in self.injections:
            lat = damage_latency(seen, i)
            damages.append(
                {"robot": i.robot, "kind": i.kind, "params": i.params, "part": i.part, "t_s": i.t}
                | {"detail": i.detail}
                | lat
            )
        got = [v for v in self.baselines.values() if v is not None]
        all_in = bool(self.baselines) and len(got) == len(self.baselines)
        return {
            "run": self.index,
            "robots": self.robots,
            "baselines": self.baselines,
            "baseline_sources": self.baseline_sources,
            "baseline_s": max(got) if all_in else None,
            # the waits as they were: each phase's limit, cut short where the run's bound came first
            "baseline_limit_s": self.limits.get("baseline_s", self.o.baseline_limit),
            "alert_limit_s": self.limits.get("alert_s", self.o.alert_limit),
            "damages": damages,
            "false_alerts": classify(
                seen,
                self.injections,
                self.restart["t_s"] if self.restart else None,
                self.watch.details_snapshot() if self.watch is not None else None,
            ),
            "restart": self.restart,
            "approvals": self.approvals,
            "flood": self.flood,
            "robot_list_errors": self.list_errors,
            "polls": self.watch.steps if self.watch else 0,
            "poll_errors": self.watch.errors if self.watch else 0,
            "alerts_seen": {key_str(k): v for k, v in seen.items()},
            "phases": self.phases,
            "notes": self.notes,
        }


def run_once(opts: Options, index: int) -> dict[str, Any]:
    """One run, every child process ended before it returns (also on Ctrl-C or an error)."""
    data_dir = Path(tempfile.mkdtemp(prefix="bench-alerts-"))
    load_before = os.getloadavg()[0]
    busy = BusyLoops()
    r = _Run(opts, index, data_dir)
    code = busy_alive = None
    try:
        busy.start(opts.busy)
        _log(f"run {index}: {opts.busy} busy loops on cores {busy.cores[: max(1, opts.busy)]}")
        r.start()
        r.wait_baselines()
        if any(v is not None for v in r.baselines.values()):
            r.healthy()
        r.inject()  # a damage of a robot without a baseline is reported as not injected
        r.wait_alerts()
    except RuntimeError as err:
        r.notes.append(f"run ended early: {str(err)[:2000]}")
        _log(f"run {index}: ended early: {str(err)[:500]}")
    finally:
        try:
            if r.watch is not None:
                r.watch.stop_event.set()
            code = r.service.stop(timeout=120)
            busy_alive = busy.alive()
        finally:
            busy.stop()
            r.api.close()
        _log(f"run {index}: service stopped (exit code {code}); busy loops running at the end: {busy_alive}")
    out = r.result() | {
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
        "busy_running_at_end": busy_alive,
        "exit_code": code,
        "window_gone": r.service.tail(n=1 << 30).count("WindowGone"),
        "write_waits": r.service.write_waits(),
        "slow_holds": r.service.slow_holds(),
    }
    shutil.rmtree(data_dir, ignore_errors=True)
    return out


def _command(args: argparse.Namespace) -> str:
    """The command line, options that differ from their defaults only (the token never)."""
    p = argparse.ArgumentParser()
    add_arguments(p)
    defaults = vars(p.parse_args([]))
    words = ["bodyhealth", "bench", "alerts"]
    for k, v in vars(args).items():
        if k not in defaults or k in ("token", "out", "func", "name") or v == defaults[k]:
            continue
        flag = "--" + ("damage" if k == "damages" else k.replace("_", "-"))
        if isinstance(v, bool):
            words.append(flag)
        elif isinstance(v, list):
            words += [w for d in v for w in (flag, d)]
        else:
            words += [flag, f"{v:g}" if isinstance(v, float) else str(v)]
    return " ".join(words)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def run(args: argparse.Namespace) -> Path:
    opts = Options.of(args)
    load = os.getloadavg()[0]
    runs = []
    # SIGTERM (a ``timeout`` around the bench, say) ends it as Ctrl-C does: through the finally blocks
    # that stop the service and the busy loops.
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        for k in range(1, opts.runs + 1):
            o = opts.for_run(k)
            _log(f"run {k} of {opts.runs} (bounded to {o.run_seconds:.0f} s)")
            runs.append(run_once(o, k))
    finally:
        signal.signal(signal.SIGTERM, previous)
    short = (
        opts.runs < FULL_RUNS
        or opts.first_healthy_s < FULL_HEALTHY_S
        or opts.healthy_seconds < FULL_OTHER_HEALTHY_S
    )
    options = {k: v for k, v in asdict(opts).items() if k not in ("token", "out", "name")}
    data = {
        "name": opts.name,
        "command": _command(args),
        "machine": machine_note(),
        "cores": sorted(os.sched_getaffinity(0)),
        "load_before": load,
        "options": options | {"damages": list(opts.damages), "run_seconds": opts.run_seconds},
        "settings_from_environment": {
            k: v for k, v in os.environ.items() if k.startswith("BODYHEALTH_") and "TOKEN" not in k
        },
        "targets": TARGETS,
        "approvals_from": "a client process of its own",
        "note": (
            f"Short run: {opts.runs} run(s), healthy phases {opts.first_healthy_s:g} s, then "
            f"{opts.healthy_seconds:g} s (the full bench: {FULL_RUNS} runs, {FULL_HEALTHY_S:g} s, then "
            f"{FULL_OTHER_HEALTHY_S:g} s); one measurement, not the bench's figures."
            if short
            else ""
        ),
        "runs": runs,
        "summary": summarize(runs),
    }
    path = write_results(opts.out, opts.name, data, markdown(data), lambda p: plot(p, data))
    _log(f"results in {path}")
    return path
