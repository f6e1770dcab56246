"""API load: latency of mixed reads at a given request rate while the demo farm ingests (locust).

``bodyhealth serve --demo`` runs as its own process (embedded SQLite, the simulated farm streaming in
real time, the worker learning every cycle); locust (``bench/locustfile.py``, the read mix a dashboard
and REST clients make) offers each rate of ``--rps`` for ``--seconds`` after a warm-up, from a second
process. Per rate: requests/s achieved, failures, p50/p95/p99 (locust's percentiles: 1 ms resolution
below 100 ms), the service's CPU seconds per second, and the frames the farm got stored meanwhile
(ingest must keep up: no drops). Target: p99 at most 20 ms at 200 rps.

Both processes share the machine: the load generator's own CPU is part of what the service competes
with, as it would be for a dashboard on the robot's computer.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import httpx

from bench import REPO_ROOT, RESULTS_DIR, fmt, machine_note
from bench.read_mix import READ_MIX, READY
from bodyschema.progress import progress
from service.api.timing import server_timings
from sim2real.figures import save_figure

__all__ = ["TARGET_P99_MS", "TARGET_RPS", "add_arguments", "read_mix", "run"]

TARGET_RPS = 200.0
TARGET_P99_MS = 20.0
LOCUSTFILE = Path(__file__).with_name("locustfile.py")
#: requests per second of one locust user by default, and of the comparison run at the target rate
USER_RPS = 50.0
DASHBOARD_USER_RPS = 10.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rps", default="50,100,200", help="offered request rates (comma list)")
    p.add_argument("--seconds", type=float, default=60.0, help="measured seconds per rate")
    p.add_argument("--warmup", type=float, default=30.0, help="seconds the farm runs before the first rate")
    p.add_argument(
        "--user-rps",
        type=float,
        default=USER_RPS,
        help="requests/s of one locust user (users = rate / this); the target rate is also measured with "
        f"{DASHBOARD_USER_RPS:g} rps users, to show what the load generator's own concurrency adds",
    )
    p.add_argument("--out", type=Path, default=RESULTS_DIR)


@dataclass
class Row:
    offered_rps: float
    users: int
    #: "locust", or "threads": :func:`read_mix`, the comparison client
    client: str
    achieved_rps: float
    requests: int
    failures: int
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    service_cpu_per_s: float
    frames_stored_per_s: float
    frames_dropped: int
    #: sensor-network retrains that finished on the training cluster during the run
    network_retrains: int = 0
    #: the service's own time (its ``Server-Timing`` app duration) at the 50th and 99th percentile,
    #: beside the round trip: the threads client reads it (None for locust rows)
    app_p50_ms: float | None = None
    app_p99_ms: float | None = None


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _metric(text: str, name: str, skip: str | None = None) -> float:
    """The sum of metric ``name`` over its label sets (those containing ``skip`` left out)."""
    return sum(
        float(m.group(2))
        for m in re.finditer(rf"^{name}(?:{{([^}}]*)}})? (\S+)$", text, re.M)
        if skip is None or skip not in (m.group(1) or "")
    )


def _locust(host: str, rps: float, users: int, seconds: float, prefix: Path) -> dict[str, str]:
    env = {**os.environ, "BODYHEALTH_LOAD_USER_RPS": f"{rps / users:g}"}
    cmd = [
        sys.executable,
        "-m",
        "locust",
        "-f",
        str(LOCUSTFILE),
        "--headless",
        "--host",
        host,
        "-u",
        str(users),
        "-r",
        str(users),
        "-t",
        f"{seconds:g}s",
        "--csv",
        str(prefix),
        "--only-summary",
        "--reset-stats",
        "--loglevel",
        "WARNING",
    ]
    done = subprocess.run(cmd, env=env, check=False, capture_output=True, text=True, timeout=seconds + 120)
    return _aggregate(Path(f"{prefix}_stats.csv"), f"{rps:g} rps from {users} locust users", done.stderr)


def _aggregate(stats: Path, what: str, stderr: str = "") -> dict[str, str]:
    r"""The ``Aggregated`` row of a locust stats CSV, or a RuntimeError that says why there is none.

    Locust writes ``N/A`` percentiles when no request completed (a client starved of CPU, a service
    that never answered); that is a failed run, said in words, not a number to plot.

    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "s.csv"
    >>> _ = p.write_text("Type,Name,Request Count,50%\n,Aggregated,0,N/A\n")
    >>> _aggregate(p, "50 rps")
    Traceback (most recent call last):
    ...
    RuntimeError: locust completed no request at 50 rps; nothing to report for that run
    """
    try:
        with open(stats, newline="") as fh:
            rows = {r["Name"]: r for r in csv.DictReader(fh)}
    except FileNotFoundError:
        raise RuntimeError(f"locust wrote no statistics at {what}: {stderr.strip()[-2000:]}") from None
    agg = rows.get("Aggregated")
    if agg is None or agg.get("Request Count", "0") in ("", "0") or "N/A" in agg.values():
        raise RuntimeError(f"locust completed no request at {what}; nothing to report for that run")
    return agg


def read_mix(
    host: str,
    rps: float,
    users: int,
    seconds: float,
    stop: threading.Event | None = None,
    ready: bool = True,
) -> dict[str, str]:
    """The comparison client: ``users`` threads, each with its own keep-alive connection (the standard
    library's ``http.client``), each asking the read mix (:data:`bench.read_mix.READ_MIX`) at
    ``rps / users`` requests per second from a random phase, for ``seconds`` or until ``stop`` is set
    (``ready`` False leaves ``/readyz`` out, for an app without a worker); the same summary fields as
    locust's CSV (ms), and ``App 50%`` and ``App 99%``: the service's own time of the same requests,
    from their ``Server-Timing`` (``nan`` when it sends none), to tell time inside the service from
    time queued before or after it."""
    import http.client
    import random
    from urllib.parse import urlsplit

    import numpy as np

    where = urlsplit(host)
    lat: list[float] = []
    app: list[float] = []
    fails = [0]
    lock = threading.Lock()
    start = time.perf_counter() + 1.0

    def user(seed: int) -> None:
        rng = random.Random(seed)
        conn = http.client.HTTPConnection(where.hostname, where.port, timeout=10)

        def get(path: str) -> tuple[bytes, str | None]:
            """The answer's body and its ``Server-Timing`` header (read after the round trip's clock
            stops)."""
            conn.request("GET", path)
            resp = conn.getresponse()
            body = resp.read()
            if resp.status != 200:
                with lock:
                    fails[0] += 1
            return body, resp.getheader("server-timing")

        names = [r["name"] for r in json.loads(get("/api/v1/robots")[0])] or ["none"]
        paths = [p for w, p, _ in READ_MIX if ready or p != READY for _ in range(w)]
        period = users / rps
        t_next, end, mine, own = start + rng.uniform(0.0, period), start + seconds, [], []
        while t_next < end and not (stop is not None and stop.is_set()):
            time.sleep(max(0.0, t_next - time.perf_counter()))
            path = rng.choice(paths).format(robot=rng.choice(names))
            t0 = time.perf_counter()
            timing = get(path)[1]
            mine.append(time.perf_counter() - t0)
            own.append(server_timings(timing).get("app", float("nan")))
            t_next += period
        with lock:
            lat.extend(mine)
            app.extend(own)
        conn.close()

    threads = [threading.Thread(target=user, args=(k,)) for k in range(users)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    took = min(seconds, max(1e-9, time.perf_counter() - start))
    ms = np.array(lat) * 1000.0
    pct = {f"{q}%": f"{np.percentile(ms, q):.1f}" for q in (50, 95, 99)}
    own_ms = np.array(app) if app and not np.isnan(app).any() else np.full(1, np.nan)
    pct |= {f"App {q}%": f"{np.percentile(own_ms, q):.1f}" for q in (50, 99)}
    return {
        "Requests/s": f"{ms.size / took:.2f}",
        "Request Count": str(ms.size),
        "Failure Count": str(fails[0]),
        "Max Response Time": f"{ms.max():.1f}",
        **pct,
    }


def run(args: argparse.Namespace) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rates = [float(x) for x in args.rps.split(",") if x.strip()]
    runs = [(rps, max(1, round(rps / args.user_rps)), "locust") for rps in rates]
    if TARGET_RPS in rates:
        dashboards = max(1, round(TARGET_RPS / DASHBOARD_USER_RPS))
        runs += [(TARGET_RPS, dashboards, "locust"), (TARGET_RPS, dashboards, "threads")]
        runs = list(dict.fromkeys(runs))
    port = _free_port()
    host = f"http://127.0.0.1:{port}"
    rows: list[Row] = []
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-load-") as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("BODYHEALTH_API_")}
        cmd = [sys.executable, "-m", "cli", "serve", "--demo", "--port", str(port)]
        cmd += ["--database-url", f"sqlite:///{tmp}/load.db"]
        err = open(Path(tmp) / "serve.err", "w")
        proc = subprocess.Popen(cmd, cwd=REPO_ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err)
        try:
            with httpx.Client(base_url=host, timeout=10) as c:
                deadline = time.monotonic() + 120
                while True:
                    if proc.poll() is not None:
                        raise RuntimeError((Path(tmp) / "serve.err").read_text()[-3000:])
                    try:
                        if len(c.get("/api/v1/robots").json()) >= 3:
                            break
                    except (httpx.HTTPError, ValueError):
                        pass
                    if time.monotonic() > deadline:
                        raise RuntimeError("the demo service did not come up within 120 s")
                    time.sleep(0.5)
                time.sleep(args.warmup)
                for i, (rps, users, client) in enumerate(progress(runs, desc="bench load", unit="run")):
                    m0, c0, t0 = c.get("/metrics").text, _cpu_seconds(proc.pid), time.monotonic()
                    if client == "locust":
                        agg = _locust(host, rps, users, args.seconds, Path(tmp) / f"rate{i}")
                    else:
                        agg = read_mix(host, rps, users, args.seconds)
                    m1, c1, t1 = c.get("/metrics").text, _cpu_seconds(proc.pid), time.monotonic()
                    stored = _metric(m1, "bodyhealth_frames_stored_total") - _metric(
                        m0, "bodyhealth_frames_stored_total"
                    )
                    dropped = _metric(m1, "bodyhealth_frames_dropped_total") - _metric(
                        m0, "bodyhealth_frames_dropped_total"
                    )
                    trained = _metric(m1, "bodyhealth_retrains_total", 'method="fast"') - _metric(
                        m0, "bodyhealth_retrains_total", 'method="fast"'
                    )
                    rows.append(
                        Row(
                            offered_rps=rps,
                            users=users,
                            client=client,
                            achieved_rps=float(agg["Requests/s"]),
                            requests=int(agg["Request Count"]),
                            failures=int(agg["Failure Count"]),
                            p50_ms=float(agg["50%"]),
                            p95_ms=float(agg["95%"]),
                            p99_ms=float(agg["99%"]),
                            max_ms=float(agg["Max Response Time"]),
                            service_cpu_per_s=(c1 - c0) / (t1 - t0),
                            frames_stored_per_s=stored / (t1 - t0),
                            frames_dropped=int(dropped),
                            network_retrains=int(trained),
                            app_p50_ms=_finite(agg.get("App 50%")),
                            app_p99_ms=_finite(agg.get("App 99%")),
                        )
                    )
        finally:
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
            err.close()
    _write(out, rows, args, load)
    return out / "load.md"


def _finite(value: str | None) -> float | None:
    """A summary field as a number, None when absent or not a number (no ``Server-Timing``)."""
    x = float("nan") if value is None else float(value)
    return None if math.isnan(x) else x


_CLIENT_NOTE = {"locust": "", "threads": " (threads)"}


def _write(out: Path, rows: list[Row], args: argparse.Namespace, load: float) -> None:
    note = machine_note()
    (out / "load.json").write_text(
        json.dumps(
            {
                "machine": note,
                "load_average": load,
                "seconds": args.seconds,
                "warmup": args.warmup,
                "user_rps": args.user_rps,
                "target_rps": TARGET_RPS,
                "target_p99_ms": TARGET_P99_MS,
                "rows": [asdict(r) for r in rows],
            },
            indent=2,
        )
        + "\n"
    )
    lines = [
        "# API load",
        "",
        f"`bodyhealth bench load`: `bodyhealth serve --demo` (embedded SQLite, the simulated farm "
        f"ingesting in real time, the worker learning) under locust's mixed reads "
        f"(`bench/locustfile.py`) at each offered rate for {args.seconds:g} s, after {args.warmup:g} s "
        f"of warm-up. Target: p99 at most {TARGET_P99_MS:g} ms at {TARGET_RPS:g} rps.",
        "",
        f"Machine: {note}; load average {load:.1f} when the run started. The load generator runs on the "
        "same machine. The sensor networks are on (the service's default): network retrains is how many "
        "finished on the embedded Dask cluster during the run (nice 10 and Linux's idle scheduling class: "
        "they yield the CPU to the API).",
        "",
        "| offered rps | users | achieved rps | requests | failures | p50 | p95 | p99 | max "
        "| service's own p50 / p99 | service CPU s/s | frames stored/s | frames dropped | network retrains |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.offered_rps:g} | {r.users}{_CLIENT_NOTE[r.client]} | {r.achieved_rps:.1f} | {r.requests} "
            f"| {r.failures} "
            f"| {r.p50_ms:g} ms | {r.p95_ms:g} ms | {r.p99_ms:g} ms | {r.max_ms:.0f} ms "
            f"| {fmt(r.app_p50_ms, 'g', ' ms')} / {fmt(r.app_p99_ms, 'g', ' ms')} "
            f"| {r.service_cpu_per_s:.2f} "
            f"| {r.frames_stored_per_s:.0f} | {r.frames_dropped} | {r.network_retrains} |"
        )
    lines += [
        "",
        f"Users: locust users at {args.user_rps:g} requests/s each. The last two rows offer the target "
        f"rate from {DASHBOARD_USER_RPS:g} requests/s users (dashboards polling), through locust and "
        "through threads with one keep-alive connection each (`http.client`, the same read mix): the "
        "difference is what locust's own client adds, many gevent users in one process on the machine "
        "it measures. The threads client also reads each answer's `Server-Timing`: the service's own "
        "time, from the request reaching its application to the answer leaving it; the rest of a round "
        "trip is spent queued for the event loop, the interpreter or a core, or in the client.",
        "",
        "![API latency against request rate](load.png)",
        "",
    ]
    (out / "load.md").write_text("\n".join(lines))
    _plot(out / "load.png", rows, note, args.user_rps)


def _plot(path: Path, rows: list[Row], note: str, user_rps: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    main = [r for r in rows if r.client == "locust" and r.users == max(1, round(r.offered_rps / user_rps))]
    extra = [r for r in rows if r not in main]
    rows = main
    x = [r.achieved_rps for r in rows]
    for key, label in (("p50_ms", "p50"), ("p95_ms", "p95"), ("p99_ms", "p99")):
        ax.plot(x, [getattr(r, key) for r in rows], "o-", label=label)
    for r, marker in zip(extra, "sD", strict=False):
        ax.plot(
            [r.achieved_rps],
            [r.p99_ms],
            marker,
            color="k",
            mfc="none",
            label=f"p99, {r.users} {r.client} users",
        )
    ax.axhline(TARGET_P99_MS, color="red", ls="--", lw=1, label=f"p99 target {TARGET_P99_MS:g} ms")
    ax.axvline(TARGET_RPS, color="grey", ls=":", lw=1)
    ax.set_xlabel("achieved requests/s (mixed reads)")
    ax.set_ylabel("latency, ms")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title(f"API latency while the farm ingests\n{note}", fontsize=8)
    save_figure(fig, path)
