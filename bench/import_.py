"""ROS bag import: messages/s and MB/s of ``bodyhealth import rosbag`` for ROS 1, ROS 2 sqlite3 and MCAP.

The floor is a plain ``rosbags`` read loop over the same bag (open, read and deserialize every message,
keep nothing): the import does all of that and more (copying the numbers into blocks, assembling and
writing the recording), so the ratio of their times says what it adds. Peak memory is measured per bag
size, up to a bag over 1 GB, in a fresh process each (resident memory sampled while it imports): it
must not follow the size of the bag.

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
#: the peak resident memory allowed while importing a 1 GB bag
RSS_LIMIT_MB = 300
LABELS = {"ros1": "ROS 1 (.bag)", "sqlite3": "ROS 2 sqlite3", "mcap": "ROS 2 MCAP"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--joints", type=int, default=6, help="joints of the synthetic robot")
    parser.add_argument("--imus", type=int, default=12, help="IMUs of the synthetic robot")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the bag timed")
    parser.add_argument(
        "--sizes",
        default="20,60,180,2200",
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
    """The whole ``bodyhealth import rosbag``: the bag read and the recording written (.npz)."""
    from service.ingest.rosbag import import_rosbag

    with tempfile.TemporaryDirectory(prefix="bench-import-out-") as tmp:
        return import_rosbag(path, Path(tmp) / "rec.npz")[1].messages


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
import os, sys, tempfile, threading, time
from pathlib import Path
from service.ingest.rosbag import import_rosbag

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
with tempfile.TemporaryDirectory(dir=sys.argv[2]) as tmp:
    t0 = time.perf_counter()
    rec, summary = import_rosbag(path, Path(tmp) / "rec.npz")
    wall = time.perf_counter() - t0
    done.set()
    watcher.join()
held = 8 * sum(a.size for a in (rec.t, rec.encoder_t, rec.q, rec.acc, rec.gyro))
print(base, peak[0], held, wall, summary.messages)
"""


def _memory(path: Path, scratch: Path) -> dict[str, float]:
    """A fresh process running ``bodyhealth import rosbag``'s import of the bag at ``path`` into a
    file under ``scratch``: its RSS before and at its peak (MB), the MB of numbers the recording holds,
    the import's wall time (s) and the messages read."""
    pythonpath = os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))
    out = subprocess.run(
        [sys.executable, "-c", _MEMORY_CHILD, str(path), str(scratch)],
        capture_output=True,
        text=True,
        check=True,
        env={**os.environ, "PYTHONPATH": pythonpath},
        timeout=3600,
    ).stdout.split()
    base, peak, held, wall, n = (float(x) for x in out)
    return {"base": base / 2**20, "peak": peak / 2**20, "held": held / 2**20, "wall": wall, "messages": n}


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
                _log(f"memory {path.name} ({_size(path) / 1e6:.0f} MB)")
                m = _memory(path, root)
                base_rss = m["base"]
                memory.append(
                    {
                        "format": fmt,
                        "seconds": seconds,
                        "bag_mb": round(_size(path) / 1e6, 2),
                        "messages": int(m["messages"]),
                        "rss_before_mb": round(m["base"], 1),
                        "rss_peak_mb": round(m["peak"], 1),
                        "rss_growth_mb": round(m["peak"] - m["base"], 1),
                        "recording_arrays_mb": round(m["held"], 2),
                        "import_s": round(m["wall"], 1),
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
        "every message, nothing kept). Import: `import_rosbag`, the whole `bodyhealth import rosbag`,",
        "the compressed `.npz` written. × real time: seconds of robot time imported per second.",
        "",
        f"Memory per bag size, each bag imported to a file in a fresh process (RSS with the libraries "
        f"loaded: {base:.0f} MB; must hold: peak under {RSS_LIMIT_MB} MB for a 1 GB bag):",
        "",
        "| format | robot s | bag MB | messages | peak RSS MB | RSS growth MB | recording arrays MB "
        "| import s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        *[
            f"| {LABELS[m['format']]} | {m['seconds']:g} | {m['bag_mb']:,} | {m['messages']:,} "
            f"| {m['rss_peak_mb']} | {m['rss_growth_mb']} | {m['recording_arrays_mb']} | {m['import_s']} |"
            for m in memory
        ],
        "",
        "Peak RSS: the process's resident memory sampled every 2 ms during `import_rosbag` (what",
        "`bodyhealth import rosbag` runs): the bag read, the recording written to a compressed `.npz`.",
        "Recording arrays: what the numbers would take in memory. No message and no array of numbers is",
        "held: each stream's values go to an unnamed temporary file beside the output as they are",
        "decoded, and are written from there block by block (4,096 samples); what stays in memory are",
        "the stamps, 8 bytes a sample (the growth left with the bag's size). ROS 1 bags are read chunk",
        "by chunk in file order, not through rosbags' per-message index (about 160 bytes a message).",
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
        bx.plot([m["bag_mb"] for m in ms], [m["rss_peak_mb"] for m in ms], "o-", label=LABELS[fmt])
    arrays = [m for m in memory if m["format"] == FORMATS[0]]
    bx.plot(
        [m["bag_mb"] for m in arrays],
        [m["recording_arrays_mb"] for m in arrays],
        "k--",
        label="recording arrays (not held)",
    )
    bx.axhline(RSS_LIMIT_MB, color="#c0392b", lw=0.8, ls=":", label=f"{RSS_LIMIT_MB} MB")
    bx.set_xscale("log")
    bx.set_xlabel("bag size, MB")
    bx.set_ylabel("peak RSS while importing, MB")
    bx.legend(fontsize=8)
    save_figure(fig, path, dpi=110)


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    add_arguments(p)
    run(p.parse_args())
