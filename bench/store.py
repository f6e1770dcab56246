"""Store throughput: sustained ingest of a 72-IMU robot into SQLite and PostgreSQL, and 60 s window reads.

Writes ``docs/bench/store.md`` (table, machine noted), ``store.json`` and ``store.png``. Two ingest
paths are measured on each backend, side by side in one run:

* ``pipeline`` — the real path: a source thread hands 0.1 s batches to the bounded queue, the writer
  coalesces what is queued and commits it with ``Store.write_many``;
* ``write_many 1 s`` — direct calls with one second of frames per transaction (a lower bound for a
  writer that is never behind).

The real-time multiple is device seconds stored per wall second (100 Hz frames); the target is 100×
(720,000 IMU samples/s) on SQLite.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, machine_note
from bodyschema.progress import progress
from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import open_store
from sim2real.figures import save_figure

__all__ = ["Frames", "add_arguments", "database", "run"]

TARGET_MULTIPLE = 100.0
DEFAULT_PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/postgres"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=300.0, help="device seconds ingested per measurement")
    p.add_argument("--imus", type=int, default=72)
    p.add_argument("--joints", type=int, default=12)
    p.add_argument("--rate", type=float, default=100.0, help="frame rate, Hz")
    p.add_argument("--window", type=float, default=60.0, help="window read, device seconds")
    p.add_argument("--backends", default="sqlite,postgresql", help="comma list of sqlite, postgresql")
    p.add_argument(
        "--postgres-url",
        default=os.environ.get("BODYHEALTH_BENCH_POSTGRES_URL", DEFAULT_PG_ADMIN),
        help="admin URL of a PostgreSQL server; a throwaway database is created and dropped",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=RESULTS_DIR)


# ------------------------------------------------------------------------------------------- data
class Frames:
    """Batches of a synthetic robot: a 10 s block of random frames repeated with time running on."""

    def __init__(self, imus: int, joints: int, rate: float, seed: int, batch: int = 10) -> None:
        rng = np.random.default_rng(seed)
        self.rate, self.batch = rate, batch
        self.block = int(10 * rate) // batch * batch
        self.q = rng.normal(size=(self.block, joints))
        self.acc = rng.normal(size=(self.block, imus, 3))
        self.gyro = rng.normal(size=(self.block, imus, 3))
        self.joint_names = tuple(f"j{i}" for i in range(joints))
        self.imu_names = tuple(f"imu{i}" for i in range(imus))

    def batches(self, robot: str, seconds: float) -> Iterator[FrameBatch]:
        n = round(seconds * self.rate)
        for i in range(0, n, self.batch):
            j = i % self.block
            sl = slice(j, j + self.batch)
            t = (i + np.arange(self.batch)) / self.rate
            yield FrameBatch(
                robot, t, self.joint_names, self.q[sl], self.imu_names, self.acc[sl], self.gyro[sl]
            )


class _IterSource(Source):
    """Hands out batches from an iterator as fast as asked, then reports itself exhausted."""

    def __init__(self, name: str, batches: Iterable[FrameBatch], per_read: int = 20) -> None:
        super().__init__(name)
        self._it = iter(batches)
        self._per_read = per_read
        self.exhausted = False

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        out = []
        for b in self._it:
            out.append(b)
            if len(out) == self._per_read:
                return out
        self.exhausted = True
        return out


# ---------------------------------------------------------------------------------------- backends
@contextmanager
def database(backend: str, admin: str, tmp: Path) -> Iterator[str]:
    if backend == "sqlite":
        yield f"sqlite:///{tmp / f'bench-{uuid.uuid4().hex[:8]}.db'}"
        return
    import psycopg

    name = f"bodyhealth_bench_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(admin, autocommit=True, connect_timeout=5) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield admin.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://", 1) + "/" + name
    finally:
        with psycopg.connect(admin, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@dataclass
class Row:
    backend: str
    path: str
    device_seconds: float
    wall_seconds: float
    imu_samples_per_s: float
    realtime_multiple: float
    cpu_seconds: float
    transactions: int
    window_read_ms: float | None = None
    bytes_per_imu_sample: float | None = None
    note: str = ""


def _measure(backend: str, url: str, frames: Frames, args: argparse.Namespace) -> list[Row]:
    settings = Settings(
        database_url=url, retention_seconds=max(args.seconds * 2, 600.0), prune_interval_seconds=1e9
    )
    rows = []
    k = len(frames.imu_names)
    with open_store(url, settings=settings) as store:
        # Direct write_many, one second of frames per transaction.
        per_txn = int(frames.rate) // frames.batch
        batches = list(frames.batches("direct", args.seconds))
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(0, len(batches), per_txn):
            store.write_many(batches[i : i + per_txn])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        n = sum(b.n_samples for b in batches)
        rows.append(
            Row(
                backend,
                "write_many 1 s",
                args.seconds,
                wall,
                n * k / wall,
                args.seconds / wall,
                cpu,
                -(-len(batches) // per_txn),
            )
        )
        del batches

        # The pipeline: source thread -> bounded queue -> coalescing writer.
        src = _IterSource("bench", frames.batches("pipeline", args.seconds))
        pipe = Pipeline(store, [src], settings=settings, put_timeout=600.0)
        t0, c0 = time.perf_counter(), time.process_time()
        with pipe:
            pipe.wait_exhausted()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        c = src.counters.as_dict()
        if c["stored"] != n or c["dropped"] or c["malformed"]:
            raise RuntimeError(f"pipeline lost frames: {c}")
        row = Row(
            backend,
            "pipeline",
            args.seconds,
            wall,
            n * k / wall,
            args.seconds / wall,
            cpu,
            int(pipe.stats.extra.get("transactions", 0)),
        )

        # Window reads (after a warm-up read).
        store.read_window("pipeline", args.window)
        times = []
        for _ in range(5):
            t1 = time.perf_counter()
            rec = store.read_window("pipeline", args.window)
            times.append(time.perf_counter() - t1)
        expected = round(min(args.window, args.seconds) * frames.rate)
        if rec is None or rec.n_samples != expected or rec.n_imus != k:
            raise RuntimeError(f"window read returned {None if rec is None else rec.acc.shape}")
        row.window_read_ms = 1000 * statistics.median(times)
        if backend == "sqlite":
            with store.engine.connect() as conn:
                conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
            path = Path(store.engine.url.database or "")
            size = sum(p.stat().st_size for p in path.parent.glob(path.name + "*"))
            row.bytes_per_imu_sample = size / (2 * n * k)
        rows.append(row)
    return rows


# --------------------------------------------------------------------------------------------- run
def run(args: argparse.Namespace) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = Frames(args.imus, args.joints, args.rate, args.seed)
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    rows: list[Row] = []
    skipped: dict[str, str] = {}
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-store-") as tmp:
        for backend in progress(backends, desc="bench store", unit="backend"):
            try:
                with database(backend, args.postgres_url, Path(tmp)) as url:
                    rows.extend(_measure(backend, url, frames, args))
            except ImportError as err:
                skipped[backend] = str(err)
            except Exception as err:  # report a backend that is not there instead of failing the run
                if backend == "sqlite":
                    raise
                skipped[backend] = f"{type(err).__name__}: {err}".splitlines()[0]
    _write(out, rows, skipped, args, load)
    return out / "store.md"


def _write(
    out: Path, rows: list[Row], skipped: dict[str, str], args: argparse.Namespace, load: float
) -> None:
    note = machine_note()
    meta = {
        "machine": note,
        "imus": args.imus,
        "joints": args.joints,
        "rate_hz": args.rate,
        "device_seconds": args.seconds,
        "window_seconds": args.window,
        "target_multiple": TARGET_MULTIPLE,
        "load_average": load,
    }
    (out / "store.json").write_text(
        json.dumps({**meta, "rows": [asdict(r) for r in rows], "skipped": skipped}, indent=2) + "\n"
    )
    lines = [
        "# Store benchmark",
        "",
        f"`bodyhealth bench store`: one robot with {args.imus} IMUs and {args.joints} joints at "
        f"{args.rate:g} Hz, "
        f"{args.seconds:g} s of device time per measurement, batches of 0.1 s; window read = the latest "
        f"{args.window:g} s as arrays (median of 5). Target: {TARGET_MULTIPLE:g}× real time "
        f"({TARGET_MULTIPLE * args.imus * args.rate:,.0f} IMU samples/s) on SQLite.",
        "",
        f"Machine: {note}; load average {load:.1f} when the run started (the machine is shared: × real "
        "time is wall-clock; CPU s is this process's CPU time, all threads).",
        "",
        "| backend | path | IMU samples/s | × real time | CPU s | transactions | 60 s window read "
        "| disk / IMU sample |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.backend} | {r.path} | {r.imu_samples_per_s:,.0f} | {r.realtime_multiple:,.0f}× "
            f"| {r.cpu_seconds:.2f} | {r.transactions} | "
            + (f"{r.window_read_ms:.0f} ms" if r.window_read_ms is not None else "")
            + " | "
            + (f"{r.bytes_per_imu_sample:.0f} B" if r.bytes_per_imu_sample is not None else "")
            + " |"
        )
    for backend, why in skipped.items():
        lines.append(f"| {backend} | skipped: {why} | | | | | | |")
    lines += [
        "",
        "An IMU sample is one accelerometer and one gyroscope triple (float64) of one IMU; each frame also "
        "carries the time stamp and the joint positions.",
        "",
        "![store benchmark](store.png)",
        "",
    ]
    (out / "store.md").write_text("\n".join(lines))
    _plot(out / "store.png", rows, note)


def _plot(path: Path, rows: list[Row], note: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), gridspec_kw={"width_ratios": [2, 1]})
    labels = [f"{r.backend}\n{r.path}" for r in rows]
    ax1.bar(
        labels,
        [r.realtime_multiple for r in rows],
        color=["C0" if r.backend == "sqlite" else "C1" for r in rows],
    )
    ax1.axhline(TARGET_MULTIPLE, color="k", ls="--", lw=1, label=f"target {TARGET_MULTIPLE:g}×")
    ax1.set_ylabel("× real time (100 Hz frames)")
    ax1.set_title("sustained ingest")
    ax1.legend()
    reads = [r for r in rows if r.window_read_ms is not None]
    ax2.bar([r.backend for r in reads], [r.window_read_ms for r in reads], color="C2")
    ax2.set_ylabel("ms")
    ax2.set_title("read a 60 s window")
    fig.suptitle(note, fontsize=8)
    save_figure(fig, path, dpi=100)
