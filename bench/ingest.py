"""Ingest throughput: frames/s each transport's ingestor sustains, against a humanoid's real-time rate.

Paths measured, side by side in one run, on the same recording of the largest demo robot: the
simulated ``humanoid`` (26 joints, 54 IMUs, 100 Hz; ``--robot synthetic`` plays random-walk signals of
``--joints``/``--imus`` instead):

- ``serial decode``: :class:`~service.ingest.serial.SerialSource` decoding frames from memory;
- ``serial pty``: the serial emulator in its own process writing into a pty, the source reading it;
- ``CAN decode+regroup``: :class:`~service.ingest.can_regroup.SampleAssembler` on frames from memory;
- ``CAN slcan pty``: the slcan emulator in its own process, python-can's notifier thread and the CAN
  source reading the pty (slcan parsing, decode, regroup);
- the same two CAN paths with the CAN FD variant of the layout (one frame per IMU, 15 joints a frame).

"× real time" is samples per second over the recording's rate: 10 means the ingestor keeps up with ten
such robots, or with one robot ten times over.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import RESULTS_DIR, machine_note
from bodyschema.recording import Recording
from sim2real.figures import save_figure

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="humanoid", help="catalog robot to simulate, or 'synthetic'")
    parser.add_argument("--joints", type=int, default=26, help="joints of the synthetic robot")
    parser.add_argument("--imus", type=int, default=54, help="IMUs of the synthetic robot")
    parser.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the recording played")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")


def _recording(n: int, k: int, rate: float, seconds: float, seed: int) -> Recording:
    rng = np.random.default_rng(seed)
    T = round(seconds * rate)
    q = np.cumsum(rng.normal(0, 0.01, (T, n)), axis=0)
    acc = rng.normal(0, 2, (T, k, 3)) + np.array([0, 0, 9.81])
    gyro = np.cumsum(rng.normal(0, 0.02, (T, k, 3)), axis=0).clip(-30, 30)
    return Recording(
        t=np.arange(T) / rate,
        joint_names=[f"joint{i}" for i in range(n)],
        q=q,
        imu_names=[f"imu{i}" for i in range(k)],
        acc=acc,
        gyro=gyro,
    )


def _log(msg: str) -> None:
    print(f"[bench ingest] {msg}", file=sys.stderr, flush=True)


def _serial_decode(rec: Recording) -> tuple[float, float, int]:
    from emulators.devices import SerialEmulator
    from service.ingest.device import DeviceConfig
    from service.ingest.serial import SerialSource

    chunks = SerialEmulator._encode(_Shim(rec))  # type: ignore[arg-type]
    wire = b"".join(chunks)
    cfg = DeviceConfig("bench", 1 / rec.sample_rate, rec.joint_names, rec.imu_names)
    src = SerialSource("loop://", cfg)
    t0, c0 = time.perf_counter(), time.process_time()
    n = 0
    for off in range(0, len(wire), 4096):
        n += sum(b.n_samples for b in src.decode(wire[off : off + 4096]))
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    src.close()
    return dt, cpu, n


class _Shim:
    """Enough of an emulator for its encoder to run without a pty."""

    def __init__(self, rec: Recording) -> None:
        from emulators.devices import sample_counters

        self.rec = rec
        self.counters, self.period = sample_counters(rec)
        self.streams = False  # one frame per sample: the bench plays single-clock recordings


def _can_decode(rec: Recording, layout: str) -> tuple[float, float, int]:
    from service.ingest.can_layout import encode_samples, encode_samples_fd
    from service.ingest.can_mapping import SignalMap
    from service.ingest.can_regroup import SampleAssembler
    from service.ingest.device import DeviceConfig

    cfg = DeviceConfig(
        "bench", 1 / rec.sample_rate, rec.joint_names, rec.imu_names, {"can": {"layout": layout}}
    )
    counter = np.arange(rec.n_samples)
    if layout == "fd":
        ids, lengths, data = encode_samples_fd(counter, rec.q, rec.acc, rec.gyro)
    else:
        ids, data = encode_samples(counter, rec.q, rec.acc, rec.gyro)
        lengths = np.full(len(ids), 8)
    F = len(ids)
    all_ids = np.tile(ids, rec.n_samples).tolist()
    datas = [data[t, f, : lengths[f]].tobytes() for t in range(rec.n_samples) for f in range(F)]
    asm = SampleAssembler(SignalMap.for_config(cfg))
    t0, c0 = time.perf_counter(), time.process_time()
    n = 0
    step = 2048
    for off in range(0, len(all_ids), step):
        asm.add_many(all_ids[off : off + step], datas[off : off + step])
        n += sum(b.n_samples for b in asm.take())
    n += sum(b.n_samples for b in asm.take(flush=True))
    return time.perf_counter() - t0, time.process_time() - c0, n


def _pty(kind: str, rec_path: Path, rec: Recording, tmp: Path, *extra: str) -> tuple[float, float, int, dict]:
    """Run the emulator in its own process; time from the first sample read to the last."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "emulators",
            kind,
            "--recording",
            str(rec_path),
            "--speed",
            "0",
            "--robot",
            "bench",
            "--config-out",
            str(tmp / f"{kind}.json"),
            "--linger",
            "30",
            *extra,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        fields = dict(kv.split("=", 1) for kv in proc.stdout.readline().split())
        spec = fields["source"]
        if kind == "can":
            from service.ingest.can import open_from_spec
        else:
            from service.ingest.serial import open_from_spec
        src = open_from_spec(spec.partition(":")[2])
        n, t_first, t_last, c_first, c_last = 0, None, None, 0.0, 0.0
        deadline = time.monotonic() + 300
        while n < rec.n_samples and time.monotonic() < deadline:
            got = src.read(0.5)
            k = sum(b.n_samples for b in got)
            if k:
                now, cpu = time.perf_counter(), time.process_time()
                if t_first is None:
                    t_first, c_first = now, cpu
                t_last, c_last = now, cpu
                n += k
        counters = src.counters.as_dict()
        src.close()
    finally:
        proc.terminate()
        proc.wait(10)
    if t_first is None or t_last is None or n < 2:
        raise RuntimeError(f"{kind} pty: no samples came through")
    # samples after the first read, over the time they took
    return t_last - t_first, c_last - c_first, n - 1, counters


def run(args: argparse.Namespace) -> Path:
    from service.ingest.can_layout import frame_ids

    rec, what = _source(args)
    n_j, n_i = rec.n_joints, rec.n_imus
    F = len(frame_ids(n_j, n_i))
    F_fd = len(frame_ids(n_j, n_i, "fd"))
    rate = args.rate
    _log(
        f"robot: {n_j} joints, {n_i} IMUs at {rate:g} Hz; {rec.n_samples} samples; "
        f"CAN {F} frames/sample (FD: {F_fd}), serial 1 frame/sample"
    )
    rows = _measure(rec, rate, F, F_fd)
    args.out.mkdir(parents=True, exist_ok=True)
    md = args.out / "ingest.md"
    lines = _markdown_lines(args, rec, what, rows, F, F_fd)
    md.write_text("\n".join(lines), encoding="utf-8")
    (args.out / "ingest.json").write_text(
        json.dumps(
            {
                "machine": machine_note(),
                "rows": rows,
                "joints": n_j,
                "imus": n_i,
                "rate": rate,
                "can_frames_per_sample": F,
            },
            indent=1,
        )
    )
    _plot(rows, args.out / "ingest.png")
    print("\n".join(lines))
    return md


def _source(args: argparse.Namespace) -> tuple[Recording, str]:
    """The recording to ingest (synthetic or simulated) and how the bench file describes it."""
    if args.robot == "synthetic":
        rec = _recording(args.joints, args.imus, args.rate, args.seconds, args.seed)
        return rec, "synthetic random-walk signals"
    from simulators import simulate

    _log(f"simulating {args.robot} for {args.seconds:g} s")
    rec = simulate(args.robot, args.seconds, args.seed, rate=args.rate)
    return rec, f"simulated `{args.robot}`, seed {args.seed}"


def _result(
    path: str, rate: float, frames_per_sample: int, dt: float, cpu: float, n: int, note: str = ""
) -> dict:
    """One path's row: frames and samples per wall second and per CPU second, logged as it is made."""
    sps, cps = n / dt, n / max(cpu, 1e-9)
    _log(
        f"{path}: {sps * frames_per_sample:,.0f} frames/s ({sps / rate:.1f}x real time); per CPU-second "
        f"{cps * frames_per_sample:,.0f} frames ({cps / rate:.1f}x)"
    )
    return {
        "path": path,
        "samples": n,
        "seconds": round(dt, 3),
        "cpu_seconds": round(cpu, 3),
        "frames_per_s": round(sps * frames_per_sample),
        "samples_per_s": round(sps),
        "x_real_time": round(sps / rate, 1),
        "frames_per_cpu_s": round(cps * frames_per_sample),
        "x_real_time_per_core": round(cps / rate, 1),
        "note": note,
    }


def _measure(rec: Recording, rate: float, F: int, F_fd: int) -> list[dict]:
    """Every path's row: the in-memory decoders, then the pty paths with the emulator in its own process."""
    rows = [
        _result("serial decode (memory)", rate, 1, *_serial_decode(rec)),
        _result("CAN decode+regroup (memory)", rate, F, *_can_decode(rec, "classic")),
        _result("CAN FD decode+regroup (memory)", rate, F_fd, *_can_decode(rec, "fd")),
    ]
    with tempfile.TemporaryDirectory(prefix="bench-ingest-") as tmpdir:
        tmp = Path(tmpdir)
        from simulators.recording_io import save_recording

        save_recording(rec, tmp / "rec.npz")
        dt, cpu, n, c = _pty("serial", tmp / "rec.npz", rec, tmp)
        note = f"crc_errors={c.get('crc_errors', 0)}, gaps={c.get('sequence_gaps', 0)}"
        rows.append(_result("serial pty (emulator process)", rate, 1, dt, cpu, n, note))
        dt, cpu, n, c = _pty("can", tmp / "rec.npz", rec, tmp)
        note = f"frames_missing={c.get('frames_missing', 0)}, decode_errors={c.get('decode_errors', 0)}"
        rows.append(_result("CAN slcan pty (emulator process)", rate, F, dt, cpu, n, note))
        dt, cpu, n, c = _pty("can", tmp / "rec.npz", rec, tmp, "--can-fd")
        note = f"frames_missing={c.get('frames_missing', 0)}, decode_errors={c.get('decode_errors', 0)}"
        rows.append(_result("CAN FD slcan pty (emulator process)", rate, F_fd, dt, cpu, n, note))
    return rows


def _markdown_lines(
    args: argparse.Namespace, rec: Recording, what: str, rows: list[dict], F: int, F_fd: int
) -> list[str]:
    """The bench file's lines: the setup, one table row per path, and how to read the columns."""
    n_j, n_i, rate = rec.n_joints, rec.n_imus, args.rate
    return [
        "# bench ingest",
        "",
        f"Machine: {machine_note()}  ",
        f"Robot: {n_j} joints, {n_i} IMUs at {rate:g} Hz ({rec.n_samples} samples, {what}); "
        f"CAN: {F} classic frames per sample "
        f"({F * rate:,.0f} frames/s in real time) or {F_fd} CAN FD frames ({F_fd * rate:,.0f} frames/s), "
        "serial: 1 frame "
        f"({12 + 4 * n_j + 12 * n_i + 4} B) per sample.  ",
        f"Command: `bodyhealth bench ingest --robot {args.robot} --rate {rate:g} --seconds {args.seconds:g}`",
        "",
        "| path | frames/s (wall) | × real time (wall) | frames per CPU-second | × real time per core "
        "| note |",
        "|---|---:|---:|---:|---:|---|",
        *[
            f"| {r['path']} | {r['frames_per_s']:,} | {r['x_real_time']} | {r['frames_per_cpu_s']:,} "
            f"| {r['x_real_time_per_core']} | {r['note']} |"
            for r in rows
        ],
        "",
        "pty paths: the emulator runs in its own process with `--speed 0` (as fast as the reader takes it);",
        'time runs from the first sample read to the last. "Per CPU-second" divides by the CPU time of the',
        "ingesting process (all its threads, python-can's notifier included; the emulator's is not counted),",
        "which does not depend on what else the machine runs; the wall-clock columns do",
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores when this ran).",
        "",
        "A classic CAN bus at 1 Mbit/s carries at most about 8,000 8-byte frames a second, less than this",
        "robot sends in real time: on classic CAN it needs two buses (one ingestor each), or the CAN FD",
        "layout on one.",
        "",
    ]


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    names = [r["path"] for r in rows]
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r["x_real_time"] for r in rows], height=0.4, color="#4a7ab5", label="wall clock")
    ax.barh(
        y + 0.2,
        [r["x_real_time_per_core"] for r in rows],
        height=0.4,
        color="#9cc0e6",
        label="per CPU-second",
    )
    ax.set_yticks(y, names)
    ax.axvline(10, color="#b54a4a", ls="--", label="10× real time")
    ax.set_xscale("log")
    ax.set_xlabel("× real time (humanoid, 26 joints, 54 IMUs, 100 Hz)")
    ax.invert_yaxis()
    ax.legend(loc="lower right", fontsize=8)
    save_figure(fig, path, dpi=110)


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    add_arguments(p)
    run(p.parse_args())
    os._exit(0)
