"""Write amplification: bytes the database writes per byte of frames, against the writer's commit interval.

Robots stream in real time: each of ``--robots`` synthetic robots (``--joints`` encoders, ``--imus``
IMUs, 100 Hz) hands the ingest pipeline a 0.1 s batch every 0.1 s of wall time, as the farm and the
device transports do. The pipeline's writer commits what it gathered (``ingest_commit_interval_seconds``,
see :meth:`service.ingest.pipeline.Pipeline._gather`); every commit rewrites whole database pages and
index entries, so small transactions write far more than they store.

Amplification = bytes written / bytes of the frames (float64 time stamp, joint positions, accelerometer
and gyroscope triples), two ways:

* **journal**: what the commits wrote to the write-ahead log. This is what transaction and chunk size
  decide, and what the target (at most 2x at the default interval) is about. On SQLite it is what this
  process passed to ``write()`` while ingesting (``wchar`` in /proc/self/io; nothing else in the process
  writes files); on PostgreSQL the WAL the server generated (``pg_current_wal_lsn()`` before and after:
  cluster-wide, so run it on a server nothing else writes to).
* **total**: the journal plus the copy into the tables (SQLite: a final ``wal_checkpoint(TRUNCATE)``;
  PostgreSQL: the growth of the database's files). Every journaled database writes each byte twice, so
  this is the journal plus about 1x, whatever the chunk size.

Each setting runs ``--seconds`` of wall time, side by side in one run.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from bench import RESULTS_DIR, machine_note
from bench.store import DEFAULT_PG_ADMIN, Frames, database
from bodyschema.progress import progress
from service.frames import FrameBatch
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import Store, open_store
from sim2real.figures import save_figure

__all__ = ["TARGET", "add_arguments", "run"]

#: The most bytes written per byte of frames the default commit interval may cost.
TARGET = 2.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robots", type=int, default=3, help="robots streaming at once")
    p.add_argument("--imus", type=int, default=7, help="IMUs per robot")
    p.add_argument("--joints", type=int, default=6, help="joints per robot")
    p.add_argument("--seconds", type=float, default=20.0, help="wall (= device) seconds per setting")
    p.add_argument(
        "--intervals", default="0,0.1,0.25,0.5,1", help="commit intervals measured, s (comma list)"
    )
    p.add_argument("--backends", default="sqlite,postgresql", help="comma list of sqlite, postgresql")
    p.add_argument(
        "--postgres-url",
        default=os.environ.get("BODYHEALTH_BENCH_POSTGRES_URL", DEFAULT_PG_ADMIN),
        help="admin URL of a PostgreSQL server; a throwaway database is created and dropped",
    )
    p.add_argument("--out", type=Path, default=RESULTS_DIR)


class _Paced(Source):
    """One robot's 0.1 s batches stamped from ``t0`` on, each handed out when its wall time has come
    (real time from ``start``, monotonic)."""

    def __init__(self, name: str, frames: Frames, seconds: float, start: float, t0: float) -> None:
        super().__init__(name)
        self._batches = [
            FrameBatch(b.robot, b.t + t0, b.joint_names, b.q, b.imu_names, b.acc, b.gyro)
            for b in frames.batches(name, seconds)
        ]
        self._i, self._start = 0, start - t0
        self.exhausted = False

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        if self._i >= len(self._batches):
            self.exhausted = True
            return []
        b = self._batches[self._i]
        wait = self._start + float(b.t[-1]) - time.monotonic()
        if wait > timeout:
            time.sleep(timeout)
            return []
        time.sleep(max(0.0, wait))
        self._i += 1
        return [b]


def _wchar() -> int:
    with open("/proc/self/io", encoding="ascii") as fh:
        return next(int(ln.split()[1]) for ln in fh if ln.startswith("wchar:"))


@dataclass
class Row:
    backend: str
    commit_interval_s: float
    frame_bytes: int
    journal_bytes: int
    total_bytes: int
    journal_amplification: float
    total_amplification: float
    transactions: int
    samples_per_chunk: float


class _Meter:
    """Bytes the journal and the tables of one backend took, from a start mark."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self.sqlite = store.dialect == "sqlite"
        self.start = self._journal()
        self.start_size = 0 if self.sqlite else self._size()

    def _journal(self) -> int:
        if self.sqlite:
            return _wchar()
        with self.store.engine.connect() as conn:
            return int(conn.exec_driver_sql("SELECT pg_current_wal_lsn() - '0/0'::pg_lsn").scalar())

    def _size(self) -> int:
        with self.store.engine.connect() as conn:
            conn.exec_driver_sql("CHECKPOINT")
            return int(conn.exec_driver_sql("SELECT pg_database_size(current_database())").scalar())

    def written(self) -> tuple[int, int]:
        """(journal, total) bytes since the start mark."""
        journal = self._journal() - self.start
        if self.sqlite:
            with self.store.engine.connect() as conn:
                conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
            return journal, _wchar() - self.start
        return journal, journal + self._size() - self.start_size


def _measure(backend: str, url: str, interval: float, frames: Frames, args: argparse.Namespace) -> Row:
    settings = Settings(database_url=url, prune_interval_seconds=1e9, ingest_commit_interval_seconds=interval)
    with open_store(url, settings=settings) as store:
        # Register the robots first: their first rows are written once per robot, not per commit.
        warm = Frames(args.imus, args.joints, 100.0, seed=1)
        store.write_many([next(warm.batches(f"r{i}", 0.1)) for i in range(args.robots)])
        meter = _Meter(store)
        start = time.monotonic() + 0.2
        # the robots go on after the registration batch's stamps
        sources = [_Paced(f"r{i}", frames, args.seconds, start, t0=1.0) for i in range(args.robots)]
        pipe = Pipeline(store, sources, settings=settings, put_timeout=60.0)
        with pipe:
            pipe.wait_exhausted(timeout=args.seconds + 120.0)
        journal, total = meter.written()
        stored = sum(s.counters.as_dict()["stored"] for s in sources)
        with store.engine.connect() as conn:
            chunks = conn.exec_driver_sql("SELECT count(*), coalesce(sum(n), 0) FROM chunks").one()
    per_sample = 8 * (1 + args.joints + 6 * args.imus)
    frame_bytes = stored * per_sample
    return Row(
        backend,
        interval,
        frame_bytes,
        journal,
        total,
        journal / frame_bytes,
        total / frame_bytes,
        int(pipe.stats.extra.get("transactions", 0)),
        (int(chunks[1]) - args.robots) / max(1, int(chunks[0]) - args.robots),
    )


def run(args: argparse.Namespace) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = Frames(args.imus, args.joints, 100.0, seed=0)
    intervals = [float(x) for x in args.intervals.split(",") if x.strip()]
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    rows: list[Row] = []
    skipped: dict[str, str] = {}
    load = os.getloadavg()[0]
    cells = [(b, i) for b in backends for i in intervals]
    with tempfile.TemporaryDirectory(prefix="bench-writes-") as tmp:
        for backend, interval in progress(cells, desc="bench writes", unit="setting"):
            if backend in skipped:
                continue
            try:
                with database(backend, args.postgres_url, Path(tmp)) as url:
                    rows.append(_measure(backend, url, interval, frames, args))
            except Exception as err:  # a backend that is not there is reported, not fatal
                if backend == "sqlite":
                    raise
                skipped[backend] = f"{type(err).__name__}: {err}".splitlines()[0]
    default = Settings.model_fields["ingest_commit_interval_seconds"].default
    _write(out, rows, skipped, args, load, default)
    return out / "writes.md"


def _write(
    out: Path, rows: list[Row], skipped: dict[str, str], args: argparse.Namespace, load: float, default: float
) -> None:
    note = machine_note()
    (out / "writes.json").write_text(
        json.dumps(
            {
                "machine": note,
                "load_average": load,
                "robots": args.robots,
                "imus": args.imus,
                "joints": args.joints,
                "seconds": args.seconds,
                "default_interval_s": default,
                "target": TARGET,
                "rows": [asdict(r) for r in rows],
                "skipped": skipped,
            },
            indent=2,
        )
        + "\n"
    )
    lines = [
        "# Write amplification",
        "",
        f"`bodyhealth bench writes`: {args.robots} robots ({args.joints} joints, {args.imus} IMUs, 100 Hz) "
        f"streaming 0.1 s batches in real time into the ingest pipeline for {args.seconds:g} s per "
        f"setting. Amplification = bytes written / bytes of the frames (float64): to the journal (the "
        f"write-ahead log; what chunk size decides) and in total (plus the copy into the tables). Target: "
        f"journal at most {TARGET:g}x at the default commit interval ({default:g} s).",
        "",
        f"Machine: {note}; load average {load:.1f} when the run started.",
        "",
        "| backend | commit interval | frames | journal | total | journal / frames | total / frames "
        "| transactions | samples per chunk |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        mark = " (default)" if r.commit_interval_s == default else ""
        lines.append(
            f"| {r.backend} | {r.commit_interval_s:g} s{mark} | {r.frame_bytes / 1e6:.2f} MB "
            f"| {r.journal_bytes / 1e6:.2f} MB | {r.total_bytes / 1e6:.2f} MB "
            f"| {r.journal_amplification:.2f}x | {r.total_amplification:.2f}x | {r.transactions} "
            f"| {r.samples_per_chunk:.1f} |"
        )
    for backend, why in skipped.items():
        lines.append(f"| {backend} | skipped: {why} | | | | | | | |")
    lines += [
        "",
        "Journal: SQLite, what the process wrote while ingesting (its WAL); PostgreSQL, the WAL the "
        "server generated (cluster-wide: nothing else should write to the server during the run). "
        "Total: plus the checkpoint into the database file (SQLite) or the growth of the database's "
        "files (PostgreSQL); every journaled database writes each byte twice.",
        "",
        "![write amplification](writes.png)",
        "",
    ]
    (out / "writes.md").write_text("\n".join(lines))
    _plot(out / "writes.png", rows, note, default)


def _plot(path: Path, rows: list[Row], note: str, default: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for backend in sorted({r.backend for r in rows}):
        rs = sorted((r for r in rows if r.backend == backend), key=lambda r: r.commit_interval_s)
        x = [r.commit_interval_s for r in rs]
        line = ax.plot(x, [r.journal_amplification for r in rs], "o-", label=f"{backend} journal")[0]
        ax.plot(
            x, [r.total_amplification for r in rs], "s--", color=line.get_color(), label=f"{backend} total"
        )
    ax.axhline(TARGET, color="red", ls="--", lw=1, label=f"journal target {TARGET:g}x")
    ax.axvline(default, color="grey", ls=":", lw=1, label=f"default {default:g} s")
    ax.set_xlabel("ingest commit interval, s")
    ax.set_ylabel("bytes written / bytes of frames")
    ax.set_yscale("log")
    ax.legend()
    ax.set_title(f"Write amplification\n{note}", fontsize=8)
    save_figure(fig, path)
