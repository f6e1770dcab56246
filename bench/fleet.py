"""A fleet's sensor-network retrains on Dask: retrains per hour, ingest lag and API latency meanwhile.

For each fleet size (``--robots``) a SQLite store holds that many robots of one catalog model, each
with a window of data recorded on the ``robot`` sensing preset, a baseline and the weights of an
earlier training under it, as a running service has them after its first retrains. Then, for each
cluster size (``--workers``), a local Dask cluster of that many worker processes (one thread each, the
service's embedded cluster) retrains every robot once through the service's own path
(:class:`service.retrain.RemoteRetrains`: jobs naming robot and window, the task reads the window and
the weights from the store, the results and new weights are stored). Once every job is submitted (their
windows are then fixed: the robots' newest 30 s), this process runs beside the training:

* **ingest**: one second of frames per robot every second (robot time = wall time), as the robots
  stream, through the service's ingest pipeline (queue, coalescing writer, one transaction per commit
  interval); the lag is how late each robot's second is committed;
* **the API** (the service's app on uvicorn, in this process beside the ingest, as in the service)
  answers the read mix of ``bench load``, asked at ``--api-rps`` by threads with one connection each
  in a process of their own (without ``/readyz``: no monitoring worker runs here, so it would answer
  503 by design).

Measured: retrains per hour (robots / wall time of the round), the CPU seconds of each retrain, warm
(the service's steady state) and, once per recording, cold (the first training of a robot); ingest
lag; API p50/p99. Training runs at the service's ``training_nice`` and, with ``training_idle``, in
Linux's idle scheduling class, as the embedded cluster runs it.

For the fleet sizes in ``--alone`` the rounds run once more with nothing beside them: what the Dask
workers give when they have the machine to themselves, as workers on machines of their own do (the
distributed setup). On a machine with as many cores as workers, ingest and the API take their share
of the same cores, so the loaded rounds cannot show how training scales with workers; the rounds
alone can.

Writes ``fleet.json``, ``fleet.md`` and ``fleet.png``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import queue
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench import RESULTS_DIR, machine_note
from bodyschema.progress import progress

__all__ = ["ALONE", "LOADED", "TARGET_P99_MS", "TARGET_SPEEDUP", "add_arguments", "run", "speedups"]

#: 2 workers must give at least this many times the retrains per hour of 1
TARGET_SPEEDUP = 1.6
#: API p99 while training runs
TARGET_P99_MS = 50.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default="8,32,128", help="fleet sizes, comma-separated")
    parser.add_argument("--workers", default="1,2", help="Dask worker processes, comma-separated")
    parser.add_argument("--robot", default="ur5e", help="catalog model of every robot of the fleet")
    parser.add_argument("--recordings", type=int, default=2, help="distinct recordings the fleet shares")
    parser.add_argument(
        "--window", type=float, default=30.0, help="seconds of the window each retrain learns"
    )
    parser.add_argument("--api-rps", type=float, default=50.0, help="API read requests per second meanwhile")
    parser.add_argument(
        "--alone",
        default="32",
        help="fleet sizes also measured with the training alone (no ingest, no API), comma-separated",
    )
    parser.add_argument(
        "--alone-workers",
        default="",
        help="cluster sizes of the rounds with the training alone, comma-separated (default: --workers')",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _log(msg: str) -> None:
    print(f"[bench fleet] {msg}", flush=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Ingest:
    """The fleet streaming through the service's ingest pipeline: a source that, every second, yields
    one second of frames for every robot (its recording looped on, stamps going on), and the
    :class:`~service.ingest.pipeline.Pipeline` writing what is queued as the service does (coalesced,
    one transaction per commit interval). The lag of a batch is how late its second was committed."""

    def __init__(self, store: Any, fleet: list[tuple[str, Any]], start_t: float) -> None:
        from service.ingest.base import Source
        from service.ingest.pipeline import Pipeline

        outer = self
        self.lag: list[float] = []
        self._due: dict[int, float] = {}  # id(batch) -> monotonic time its second was complete

        class Fleet(Source):
            exhausted = False

            def __init__(self) -> None:
                super().__init__("fleet")
                self.k = 0
                self.t0: float | None = None

            def _read_raw(self, timeout: float) -> list[Any]:
                if self.t0 is None:
                    self.t0 = time.monotonic()
                due = self.t0 + self.k + 1.0  # the second [k, k+1) of robot time is complete then
                wait = due - time.monotonic()
                if wait > timeout:
                    time.sleep(timeout)
                    return []
                time.sleep(max(0.0, wait))
                out = outer._second(fleet, start_t + self.k, due)
                self.k += 1
                return out

        self.source = Fleet()
        self.pipeline = Pipeline(store, [self.source], prune_interval=0, on_commit=self._committed)

    def _second(self, fleet: list[tuple[str, Any]], lo: float, due: float) -> list[Any]:
        from service.ingest.replay import recording_batch

        out = []
        for name, rec in fleet:
            span = rec.t[-1] - rec.t[0]
            off = np.floor((lo - rec.t[0]) / span) * span  # the recording looped on
            a, b = np.searchsorted(rec.t + off, [lo, lo + 1.0])
            qa, qb = np.searchsorted(rec.encoder_t + off, [lo, lo + 1.0])
            if b > a and qb > qa:
                batch = recording_batch(name, rec, slice(a, b), off, slice(qa, qb))
                self._due[id(batch)] = due
                out.append(batch)
        return out

    def _committed(self, batches: list[Any]) -> None:
        now = time.monotonic()
        self.lag += [now - self._due.pop(id(b)) for b in batches if id(b) in self._due]

    @property
    def samples(self) -> int:
        return int(self.source.counters.as_dict()["stored"])

    def start(self) -> None:
        self.pipeline.start()

    def is_alive(self) -> bool:
        return self.pipeline.running

    def stop(self) -> None:
        self.pipeline.stop(timeout=30.0)


class _Api:
    """The service's app on uvicorn in a thread, over the fleet's store; the process's heap frozen
    before it serves, as the service's (:mod:`service.heap`)."""

    def __init__(self, store: Any) -> None:
        import uvicorn

        from service.api import create_app
        from service.heap import freeze_startup_heap
        from service.settings import Settings

        self.port = _free_port()
        app = create_app(store, settings=Settings(database_url=store.url))
        freeze_startup_heap()
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_config=None, access_log=False)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, name="bench-api", daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline:
                raise RuntimeError("the API did not start within 30 s")
            time.sleep(0.05)

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(10)


def _cold(robot: str, recs: list[Any], window: float, seed: int) -> tuple[list[Any], list[dict[str, Any]]]:
    """A cold training of each recording, as the task runs it (one thread): the weights the fleet
    starts from, and what a robot's first retrain costs."""
    from bodyschema.estimate import fit_topology
    from bodyschema.impacts import drop_impacts
    from bodyschema.threads import set_torch_threads

    set_torch_threads(1)
    fits, costs = [], []
    for i, rec in enumerate(recs):
        _log(f"cold training of recording {i + 1}/{len(recs)} ({robot}, {window:g} s)")
        c0 = time.process_time()
        fit = fit_topology(drop_impacts(rec.window(rec.t[-1] - window, np.inf)), "network", seed=seed)
        costs.append({"cpu_s": round(time.process_time() - c0, 2), "epochs": fit.topology.training["epochs"]})
        fits.append(fit)
    return fits, costs


def _fill(store: Any, names: list[str], recs: list[Any], fits: list[Any]) -> None:
    """Each robot's window, its baseline (the cold run's tree) and the weights trained under it."""
    from service.ingest.replay import recording_batch

    for i, name in enumerate(names):
        rec, fit = recs[i % len(recs)], fits[i % len(fits)]
        store.write(recording_batch(name, rec))
        base = store.set_baseline(name, fit.topology, "auto", wall_time=time.time())
        store.save_network_weights(
            name,
            "network",
            fit.weights,
            rec.imu_names,
            rec.joint_names,
            baseline_id=base,
            wall_time=time.time(),
        )


def _round(
    store: Any,
    names: list[str],
    workers: int,
    window: float,
    options: Any,
    submitted: Callable[[], None],
) -> dict[str, Any]:
    """Every robot retrained once on a local cluster of ``workers`` processes; wall time and costs.
    ``submitted()`` is called once every job is on the cluster (their windows are fixed then)."""
    from service.cluster import ClusterOptions, TrainingCluster, local_cluster
    from service.metrics import Metrics
    from service.retrain import RemoteRetrains, RetrainLimits

    cluster = local_cluster(workers)
    tc = TrainingCluster(ClusterOptions(scheduler=cluster.scheduler_address))
    try:
        tc.start()
        deadline = time.monotonic() + 60
        while tc.client is None:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no client for the local cluster: {tc.fault}")
            time.sleep(0.1)
        # every job on the cluster at once: the round measures the cluster, not the service's queue
        limits = RetrainLimits(max_queued=len(names))
        remote = RemoteRetrains(tc, store, window, options=options, metrics=Metrics(), limits=limits)
        for name in names:
            remote.want(name, "network")
        t0 = time.monotonic()
        results = []
        bar = progress(total=len(names), desc=f"retrains on {workers} worker(s)", unit="retrain")
        while remote.wanted():
            remote.submit_wanted()
        submitted()
        while len(results) < len(names):
            remote.submit_wanted()
            new = remote.collect(time.time)
            results += new
            bar.update(len(new))
            if time.monotonic() - t0 > 3 * 3600:
                raise RuntimeError("the round did not end within 3 hours")
            time.sleep(0.2)
        bar.close()
        wall = time.monotonic() - t0
    finally:
        tc.close()
        cluster.close()
    cpu = np.array([r.cpu_seconds for r in results])
    return {
        "wall_s": round(wall, 1),
        "retrains_per_hour": round(len(names) / wall * 3600.0, 1),
        "cpu_s_median": round(float(np.median(cpu)), 2),
        "cpu_s_max": round(float(cpu.max()), 2),
        "warm": int(sum(r.warm_from is not None for r in results)),
        "epochs_median": float(np.median([r.topology["training"]["epochs"] for r in results])),
    }


def _training(seed: int) -> Any:
    """The embedded cluster's training options for ``seed``: the service's priority settings."""
    from service.retrain import TrainingOptions
    from service.settings import Settings

    s = Settings(database_url="sqlite://")
    return TrainingOptions(seed=seed, nice=s.training_nice, idle=s.training_idle)


#: What ran beside the training in a round.
LOADED, ALONE = "ingest+api", "none"


def _alone(store: Any, names: list[str], args: argparse.Namespace, workers: int) -> dict:
    """One round with nothing beside the training."""
    row = _round(store, names, workers, args.window, _training(args.seed + 1), lambda: None)
    return {**row, "robots": len(names), "workers": workers, "beside": ALONE}


def _client(host: str, rps: float, users: int, stop: Any, out: Any) -> None:
    """The API's read mix (:func:`bench.load.read_mix`) until ``stop``; its summary onto ``out``."""
    from bench.load import read_mix

    out.put(read_mix(host, rps, users, 3 * 3600.0, stop, ready=False))


def _measured(store: Any, names: list[str], recs: list[Any], args: argparse.Namespace, workers: int) -> dict:
    """One round with ingest and API load running beside it."""
    from service.children import CHILDREN

    training = _training(args.seed + 1)
    fleet = [(n, recs[i % len(recs)]) for i, n in enumerate(names)]
    last = max(float(store.robot(n).last_frame_t) for n in names)
    ingest = _Ingest(store, fleet, last + 1e-6)
    api = _Api(store)
    # the load generator in a process of its own: its threads would otherwise wait on the service's
    # interpreter lock, and their waits would count as the API's latency
    stop, out = CHILDREN.Event(), CHILDREN.Queue()
    users = max(1, round(args.api_rps / 10.0))
    client = CHILDREN.Process(
        target=_client,
        args=(f"http://127.0.0.1:{api.port}", args.api_rps, users, stop, out),
        name="bench-fleet-client",
        daemon=True,
    )
    answers: dict[str, str] = {}

    def start() -> None:
        ingest.start()
        client.start()

    try:
        row = _round(store, names, workers, args.window, training, start)
    finally:
        stop.set()
        if client.pid is not None:
            with contextlib.suppress(queue.Empty):
                answers = out.get(timeout=60)
            client.join(30)
        if ingest.is_alive():
            ingest.stop()
        api.close()
    lag = np.array(ingest.lag) if ingest.lag else np.zeros(1)
    row.update(
        robots=len(names),
        workers=workers,
        beside=LOADED,
        ingest_samples_per_s=round(ingest.samples / max(row["wall_s"], 1e-9), 1),
        ingest_lag_s_median=round(float(np.median(lag)), 3),
        ingest_lag_s_max=round(float(lag.max()), 3),
        api_rps=float(answers.get("Requests/s", "nan")),
        api_p50_ms=float(answers.get("50%", "nan")),
        api_p99_ms=float(answers.get("99%", "nan")),
        api_failures=int(answers.get("Failure Count", "0")),
    )
    return row


def run(args: argparse.Namespace) -> Path:
    from service.store import open_store
    from simulators.simulation import simulate

    sizes = _ints(args.robots)
    workers = _ints(args.workers)
    alone = _ints(args.alone)
    alone_workers = _ints(args.alone_workers) or workers
    _log(f"simulating {args.recordings} recording(s) of {args.robot}")
    recs = [
        simulate(args.robot, seconds=args.window + 5.0, seed=args.seed + i, sensing="robot")
        for i in range(args.recordings)
    ]
    fits, cold = _cold(args.robot, recs, args.window, args.seed + 1)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        rounds = [(n, w, LOADED) for n in sizes for w in workers]
        rounds += [(n, w, ALONE) for n in alone for w in alone_workers]
        for n, w, beside in rounds:
            names = [f"{args.robot}-{i:04d}" for i in range(n)]
            store = open_store(f"sqlite:///{tmp}/fleet-{n}-{w}-{len(rows)}.db")
            try:
                _fill(store, names, recs, fits)
                _log(f"{n} robots on {w} worker(s), beside the training: {beside}")
                if beside == ALONE:
                    rows.append(_alone(store, names, args, w))
                else:
                    rows.append(_measured(store, names, recs, args, w))
                _log(json.dumps(rows[-1]))
            finally:
                store.close()
    return _write(args, recs[0], cold, rows)


def _ints(text: object) -> list[int]:
    return [int(x) for x in str(text).split(",") if x.strip()]


def speedups(rows: list[dict], beside: str) -> dict[int, float]:
    """Per fleet size: retrains per hour on 2 workers over 1, for the rounds with ``beside``."""
    by = {(r["robots"], r["workers"]): r for r in rows if r["beside"] == beside}
    return {
        n: round(by[(n, 2)]["retrains_per_hour"] / by[(n, 1)]["retrains_per_hour"], 2)
        for n in sorted({n for n, _ in by})
        if (n, 1) in by and (n, 2) in by
    }


def _write(args: argparse.Namespace, rec: Any, cold: list[dict], rows: list[dict]) -> Path:
    args.out.mkdir(parents=True, exist_ok=True)
    loaded = [r for r in rows if r["beside"] == LOADED]
    speedup, speedup_alone = speedups(rows, LOADED), speedups(rows, ALONE)
    warm = float(np.median([r["cpu_s_median"] for r in rows]))
    cold_cpu = float(np.median([c["cpu_s"] for c in cold]))
    training = _training(args.seed + 1)
    idle = ", Linux's idle scheduling class" if training.idle else ""
    data = {
        "machine": machine_note(),
        "command": f"bodyhealth bench fleet --robots {args.robots} --workers {args.workers} --robot "
        f"{args.robot} --recordings {args.recordings} --window {args.window:g} --api-rps {args.api_rps:g} "
        f"--alone '{args.alone}'"
        + (f" --alone-workers {args.alone_workers}" if args.alone_workers else "")
        + f" --seed {args.seed}",
        "robot": args.robot,
        "imus": rec.n_imus,
        "joints": rec.n_joints,
        "window_s": args.window,
        "cold": cold,
        "warm_cpu_s": round(warm, 2),
        "cold_cpu_s": round(cold_cpu, 2),
        "speedup_2_over_1": speedup,
        "speedup_2_over_1_alone": speedup_alone,
        "target_speedup": TARGET_SPEEDUP,
        "target_api_p99_ms": TARGET_P99_MS,
        "rows": rows,
        "load_average": round(os.getloadavg()[0], 1),
        "training_priority": {"nice": training.nice, "idle": training.idle},
    }
    (args.out / "fleet.json").write_text(json.dumps(data, indent=1) + "\n")
    lines = [
        "# bench fleet",
        "",
        f"Machine: {data['machine']}  ",
        f"Command: `{data['command']}`  ",
        f"Fleet: {args.robot} robots ({rec.n_joints} joints, {rec.n_imus} IMUs, `robot` sensing), each "
        f"with a {args.window:g} s window, a baseline and the weights of an earlier training; every robot "
        "retrained once per round on a local Dask cluster (one thread per worker process, the training at "
        f"the service's priority: nice {training.nice}{idle}) while ingest writes one second of frames "
        f"per robot every second and the API answers {args.api_rps:g} reads/s, asked from threads of "
        "another process (beside: ingest+api); rounds with beside "
        "none ran the same retrains with nothing else on the machine, as Dask workers on machines of their "
        "own do.",
        "",
        "| robots | workers | beside | wall s | retrains/hour | warm retrains "
        "| CPU s per retrain (median, max) | epochs | ingest samples/s | ingest lag median s "
        "| ingest lag max s | API p50 ms | API p99 ms | API failures |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *[_md_row(r) for r in rows],
        "",
        "2 workers against 1 (retrains per hour), with ingest and the API beside: "
        + _speedup_text(speedup)
        + "; with the training alone: "
        + _speedup_text(speedup_alone)
        + f" (must hold: at least {TARGET_SPEEDUP:g}x). API p99 while training: "
        + (f"{max(r['api_p99_ms'] for r in loaded):g} ms at most" if loaded else "not measured")
        + f" (must hold: under {TARGET_P99_MS:g} ms).",
        "",
        f"Warm against cold: a warm retrain (the steady state: a robot's networks start from its stored "
        f"weights) took {warm:g} CPU s (median of the rounds' medians); the first, cold training of each "
        f"recording took {', '.join(str(c['cpu_s']) for c in cold)} CPU s "
        f"({', '.join(str(c['epochs']) for c in cold)} epochs), one thread.",
        "Wall time and ingest lag depend on what else the machine runs: the load generator, the ingest "
        f"and the API share its cores with the workers (load average {data['load_average']} at the end).",
        "",
        "![fleet](fleet.png)",
        "",
    ]
    md = args.out / "fleet.md"
    md.write_text("\n".join(lines))
    _plot(rows, args.out / "fleet.png")
    print("\n".join(lines))
    return md


def _speedup_text(speedup: dict[int, float]) -> str:
    return ", ".join(f"{n} robots {s:g}x" for n, s in speedup.items()) or "not measured"


def _md_row(r: dict) -> str:
    head = (
        f"| {r['robots']} | {r['workers']} | {r['beside']} | {r['wall_s']} | {r['retrains_per_hour']:,} "
        f"| {r['warm']}/{r['robots']} | {r['cpu_s_median']}, {r['cpu_s_max']} | {r['epochs_median']:g} "
    )
    if r["beside"] == ALONE:
        return head + "| — | — | — | — | — | — |"
    return head + (
        f"| {r['ingest_samples_per_s']:,} | {r['ingest_lag_s_median']} | {r['ingest_lag_s_max']} "
        f"| {r['api_p50_ms']} | {r['api_p99_ms']} | {r['api_failures']} |"
    )


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9.0, 3.4))

    def of(w: int, beside: str) -> list[dict]:
        chosen = (r for r in rows if r["workers"] == w and r["beside"] == beside)
        return sorted(chosen, key=lambda r: r["robots"])

    for w in sorted({r["workers"] for r in rows}):
        rs, alone = of(w, LOADED), of(w, ALONE)
        line = ax.plot(
            [r["robots"] for r in rs], [r["retrains_per_hour"] for r in rs], "o-", label=f"{w} worker(s)"
        )[0]
        if alone:
            ax.plot(
                [r["robots"] for r in alone],
                [r["retrains_per_hour"] for r in alone],
                "s",
                mfc="none",
                color=line.get_color(),
                label=f"{w} worker(s), training alone",
            )
        bx.plot(
            [r["robots"] for r in rs], [r["api_p99_ms"] for r in rs], "o-", label=f"API p99, {w} worker(s)"
        )
    bx.axhline(TARGET_P99_MS, color="#c0392b", lw=0.8, ls=":", label=f"{TARGET_P99_MS:g} ms")
    for a in (ax, bx):
        a.set_xscale("log", base=2)
        a.set_xlabel("robots")
        a.legend(fontsize=8)
    ax.set_ylabel("retrains per hour")
    bx.set_ylabel("ms")
    save_figure(fig, path, dpi=110)


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    add_arguments(p)
    run(p.parse_args())
