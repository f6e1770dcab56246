"""ROS bag import: messages/s and MB/s of ``bodyhealth import rosbag`` for ROS 1, ROS 2 sqlite3 and MCAP.

The floor is a plain ``rosbags`` read loop over the same bag (open, read and deserialize every message,
keep nothing): the import does all of that and more, so the ratio of their times says what the import
adds (copying the numbers into blocks, assembling the recording); below 1 it is the machine's noise.
Peak memory is measured per bag size in a fresh process each (resident memory sampled while it reads,
and the Python heap's peak under tracemalloc): it should follow the numbers the recording holds, never
the size of the bag.

The bags are written by :func:`emulators.rosbag.write_rosbag` from a synthetic multi-rate robot (random
walks, a UR5e's 6 joints and 12 IMUs by default: IMUs at 100 Hz, encoders at 250 Hz on their own
stamps), one message per IMU sample and one joint state per encoder sample, as ROS drivers log them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench import REPO_ROOT, RESULTS_DIR, machine_note
from bodyschema.recording import Recording
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run"]

FORMATS = ("ros1", "sqlite3", "mcap")
LABELS = {"ros1": "ROS 1 (.bag)", "sqlite3": "ROS 2 sqlite3", "mcap": "ROS 2 MCAP"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--joints", type=int, default=6, help="joints of the synthetic robot")
    parser.add_argument("--imus", type=int, default=12, help="IMUs of the synthetic robot")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the bag timed")
    parser.add_argument(
        "--sizes",
        default="20,60,180",
        help="bag lengths (s, comma-separated) whose peak memory is measured",
    )
    parser.add_argument("--repeat", type=int, default=3, help="timed reads per bag (the best is kept)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _recording(n: int, k: int, seconds: float, seed: int) -> Recording:
    """Random walks of ``n`` joints at 250 Hz and ``k`` IMUs at 100 Hz, on two clocks."""
    rng = np.random.default_rng(seed)
    T, Tq = round(seconds * 100.0), round(seconds * 250.0)
    return Recording(
        t=0.0037 + np.arange(T) / 100.0,
        t_q=np.arange(Tq) / 250.0,
        joint_names=[f"joint{i}" for i in range(n)],
        q=np.cumsum(rng.normal(0, 0.01, (Tq, n)), axis=0),
        imu_names=[f"imu{i}" for i in range(k)],
        acc=rng.normal(0, 2, (T, k, 3)) + np.array([0, 0, 9.81]),
        gyro=np.cumsum(rng.normal(0, 0.02, (T, k, 3)), axis=0).clip(-30, 30),
    )


def _bag(root: Path, fmt: str, seconds: float) -> Path:
    return root / (f"s{seconds:g}.bag" if fmt == "ros1" else f"s{seconds:g}_{fmt}")


def _size(path: Path) -> int:
    return (
        sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
        if path.is_dir()
        else path.stat().st_size
    )


def _floor(path: Path) -> int:
    """A plain rosbags read loop: every message read and deserialized, nothing kept."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    n = 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def _import(path: Path) -> int:
    from service.ingest.rosbag import read_rosbag

    return read_rosbag(path)[1].messages


def _best(fn: Callable[[Path], int], path: Path, repeat: int) -> tuple[float, float, int]:
    """Best wall and CPU time of ``repeat`` runs, and the messages read."""
    walls, cpus, n = [], [], 0
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        n = fn(path)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus), n


_MEMORY_CHILD = """
import os, sys, threading, time, tracemalloc
from pathlib import Path
from service.ingest.rosbag import read_rosbag

PAGE = os.sysconf("SC_PAGE_SIZE")
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE
path = Path(sys.argv[1])
base = rss()
peak = [base]
done = threading.Event()
def watch():
    while not done.is_set():
        peak[0] = max(peak[0], rss())
        time.sleep(0.002)
watcher = threading.Thread(target=watch, daemon=True)
watcher.start()
rec = read_rosbag(path)[0]
done.set()
watcher.join()
held = sum(a.nbytes for a in (rec.t, rec.encoder_t, rec.q, rec.acc, rec.gyro))
del rec
tracemalloc.start()
read_rosbag(path)
heap = tracemalloc.get_traced_memory()[1]
print(base, peak[0] - base, heap, held)
"""


def _memory(path: Path) -> tuple[float, float, float, float]:
    """(RSS before, MB; peak RSS growth while reading, MB; peak Python heap while reading, MB, as
    tracemalloc sees it, numpy's arrays included; MB the recording's arrays hold) of a fresh process
    importing the bag at ``path``."""
    pythonpath = os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))
    out = subprocess.run(
        [sys.executable, "-c", _MEMORY_CHILD, str(path)],
        capture_output=True,
        text=True,
        check=True,
        env={**os.environ, "PYTHONPATH": pythonpath},
        timeout=600,
    ).stdout.split()
    base, grow, heap, held = (float(x) / 2**20 for x in out)
    return base, grow, heap, held


def _log(msg: str) -> None:
    print(f"[bench import] {msg}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> Path:
    from emulators.rosbag import RosbagWriteOptions, write_rosbag

    sizes = sorted({float(s) for s in str(args.sizes).split(",") if s.strip()} | {float(args.seconds)})
    rows: list[dict] = []
    memory: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-import-") as tmp:
        root = Path(tmp)
        for seconds in sizes:
            rec = _recording(args.joints, args.imus, seconds, args.seed)
            for fmt in FORMATS:
                path = _bag(root, fmt, seconds)
                _log(f"writing {path.name} ({seconds:g} s)")
                write_rosbag(rec, path, RosbagWriteOptions(format=fmt))
        timed = _recording(args.joints, args.imus, float(args.seconds), args.seed)
        for fmt in FORMATS:
            path = _bag(root, fmt, float(args.seconds))
            size = _size(path)
            _log(f"timing {fmt}")
            f_wall, f_cpu, f_n = _best(_floor, path, args.repeat)
            i_wall, i_cpu, i_n = _best(_import, path, args.repeat)
            if i_n != f_n:
                raise RuntimeError(f"{fmt}: the import read {i_n} messages, the floor {f_n}")
            rows.append(
                {
                    "format": fmt,
                    "bag_mb": round(size / 1e6, 2),
                    "messages": i_n,
                    "floor_msgs_per_s": round(f_n / f_wall),
                    "floor_mb_per_s": round(size / 1e6 / f_wall, 1),
                    "import_msgs_per_s": round(i_n / i_wall),
                    "import_mb_per_s": round(size / 1e6 / i_wall, 1),
                    "floor_msgs_per_cpu_s": round(f_n / f_cpu) if f_cpu > 0 else None,
                    "import_msgs_per_cpu_s": round(i_n / i_cpu) if i_cpu > 0 else None,
                    "import_over_floor": round(i_wall / f_wall, 2),
                    "x_real_time": round(float(args.seconds) / i_wall, 1),
                }
            )
        base_rss = 0.0
        for fmt in FORMATS:
            for seconds in sizes:
                path = _bag(root, fmt, seconds)
                _log(f"memory {path.name}")
                base_rss, grow, heap, held = _memory(path)
                memory.append(
                    {
                        "format": fmt,
                        "seconds": seconds,
                        "bag_mb": round(_size(path) / 1e6, 2),
                        "rss_growth_mb": round(grow, 1),
                        "heap_peak_mb": round(heap, 1),
                        "recording_arrays_mb": round(held, 2),
                    }
                )
    return _write(args, timed, rows, memory, base_rss)


def _write(
    args: argparse.Namespace, rec: Recording, rows: list[dict], memory: list[dict], base: float
) -> Path:
    args.out.mkdir(parents=True, exist_ok=True)
    per_s = rec.n_imus * rec.sample_rate + rec.encoder_rate
    lines = [
        "# bench import",
        "",
        f"Machine: {machine_note()}  ",
        f"Robot: synthetic, {rec.n_joints} joints at {rec.encoder_rate:g} Hz and {rec.n_imus} IMUs at "
        f"{rec.sample_rate:g} Hz on their own stamps ({per_s:,.0f} messages per second of robot time; "
        f"seed {args.seed}).  ",
        f"Command: `bodyhealth bench import --joints {args.joints} --imus {args.imus} "
        f"--seconds {args.seconds:g} --sizes {args.sizes} --repeat {args.repeat}`",
        "",
        f"Throughput on a {args.seconds:g} s bag, best of {args.repeat} reads (wall clock):",
        "",
        "| format | bag MB | messages | floor msgs/s | floor MB/s | import msgs/s | import MB/s "
        "| import / floor time | × real time |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        *[
            f"| {LABELS[r['format']]} | {r['bag_mb']} | {r['messages']:,} | {r['floor_msgs_per_s']:,} "
            f"| {r['floor_mb_per_s']} | {r['import_msgs_per_s']:,} | {r['import_mb_per_s']} "
            f"| {r['import_over_floor']} | {r['x_real_time']} |"
            for r in rows
        ],
        "",
        "Floor: the same bag through a plain `rosbags` loop (`AnyReader.messages()` and `deserialize` of",
        "every message, nothing kept). Import: `read_rosbag`, the whole `bodyhealth import rosbag` but",
        "the `.npz` write. × real time: seconds of robot time imported per second.",
        "",
        f"Memory per bag size, each bag in a fresh process (RSS with the libraries loaded: {base:.0f} MB):",
        "",
        "| format | robot s | bag MB | peak RSS growth MB | peak heap MB | recording arrays MB |",
        "|---|---:|---:|---:|---:|---:|",
        *[
            f"| {LABELS[m['format']]} | {m['seconds']:g} | {m['bag_mb']} | {m['rss_growth_mb']} "
            f"| {m['heap_peak_mb']} | {m['recording_arrays_mb']} |"
            for m in memory
        ],
        "",
        "Peak RSS growth: the process's resident memory sampled every 2 ms while it reads, over what it",
        "held before (the allocator keeps some freed memory, so this is an upper bound). Peak heap: the",
        "largest Python and numpy allocation total during a second read (tracemalloc). No message is",
        "kept: memory follows the numbers the recording holds (gathered in blocks and joined stream by",
        "stream, about twice the final arrays at the end), not the bytes of the bag, plus what the",
        "reader keeps: rosbags reads a ROS 1 bag's whole index (an entry per message) when it opens it.",
        "The wall-clock columns depend on what else the machine runs (load average below).",
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores when this ran)",
        "",
    ]
    md = args.out / "import.md"
    md.write_text("\n".join(lines), encoding="utf-8")
    (args.out / "import.json").write_text(
        json.dumps(
            {
                "machine": machine_note(),
                "seconds": float(args.seconds),
                "joints": rec.n_joints,
                "imus": rec.n_imus,
                "rss_before_mb": round(base, 1),
                "rows": rows,
                "memory": memory,
            },
            indent=1,
        )
    )
    _plot(rows, memory, args.out / "import.png")
    print("\n".join(lines))
    return md


def _plot(rows: list[dict], memory: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9.0, 3.4))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r["floor_msgs_per_s"] for r in rows], height=0.4, color="#9cc0e6", label="rosbags loop")
    ax.barh(y + 0.2, [r["import_msgs_per_s"] for r in rows], height=0.4, color="#4a7ab5", label="import")
    ax.set_yticks(y, [LABELS[r["format"]] for r in rows])
    ax.set_xlabel("messages / s")
    ax.invert_yaxis()
    ax.legend(loc="lower right", fontsize=8)
    for fmt in FORMATS:
        ms = [m for m in memory if m["format"] == fmt]
        bx.plot([m["bag_mb"] for m in ms], [m["heap_peak_mb"] for m in ms], "o-", label=LABELS[fmt])
    arrays = [m for m in memory if m["format"] == FORMATS[0]]
    bx.plot(
        [m["bag_mb"] for m in arrays],
        [m["recording_arrays_mb"] for m in arrays],
        "k--",
        label="recording arrays",
    )
    bx.set_xlabel("bag size, MB")
    bx.set_ylabel("peak heap while importing, MB")
    bx.legend(fontsize=8)
    save_figure(fig, path, dpi=110)


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    add_arguments(p)
    run(p.parse_args())
