"""Figures from ``bench ingest`` (docs/bench/ingest.json): the transports' frame rates."""

from __future__ import annotations

import re

from bench.figures.files import BenchFiles, int_text, table_row

__all__ = ["INGEST_TARGET_X", "doc", "readme"]


#: Targets the docs measure against. They are requirements, not results, so no bench file holds them.
#: The ingest target the docs measure against: a requirement, not a result, so no bench file holds it.
INGEST_TARGET_X = 10.0


def _data(b: BenchFiles) -> dict:
    return b.json("ingest.json")  # type: ignore[return-value]


def _rows(d: dict) -> dict[str, dict]:
    return {r["path"]: r for r in d["rows"]}


def readme(b: BenchFiles) -> str:
    d = _data(b)
    rows = _rows(d)
    fps = d["can_frames_per_sample"] * d["rate"]
    shown = [
        ("serial pty (emulator process)", "serial frames, pty"),
        ("CAN slcan pty (emulator process)", "CAN classic, slcan over pty"),
        ("CAN FD slcan pty (emulator process)", "CAN FD, slcan over pty"),
        ("CAN decode+regroup (memory)", "CAN decode + regroup only"),
    ]
    worst = min(rows[k]["x_real_time"] for k, _ in shown)
    lines = [
        f"Measured with {b.provenance('ingest')}, load average {b.load('ingest')}: the simulated humanoid "
        f"({d['joints']} joints, {d['imus']} IMUs, {d['rate']:g} Hz: {int_text(fps)} classic CAN frames/s "
        "in real time). The emulator runs in its own process and writes a pty; the ingestor reads it. "
        f"Target ≥ {INGEST_TARGET_X:g}× real time — "
        f"{'met on every path' if worst >= INGEST_TARGET_X else 'missed'}.",
        "",
        "| path | frames/s | × real time |",
        "|---|---:|---:|",
    ]
    for key, label in shown:
        r = rows[key]
        x = r["x_real_time"]
        lines.append(table_row([label, int_text(r["frames_per_s"]), f"{x:.1f}×" if x < 100 else f"{x:.0f}×"]))
    return "\n".join(lines)


def doc(b: BenchFiles) -> str:
    d = _data(b)
    rows = _rows(d)
    fd = re.search(r"(\d+) CAN FD frames", b.text("ingest.md"))
    shown = [
        ("serial pty (emulator process)", "serial pty (emulator process)"),
        (
            "CAN slcan pty (emulator process)",
            f"CAN slcan pty, classic layout ({d['can_frames_per_sample']} frames/sample)",
        ),
        (
            "CAN FD slcan pty (emulator process)",
            f"CAN FD slcan pty ({fd.group(1) if fd else '?'} frames/sample)",
        ),
        ("CAN decode+regroup (memory)", "CAN decode+regroup alone (memory)"),
    ]
    lines = [
        f"Measured with {b.provenance('ingest')}, load average {b.load('ingest')}:",
        "",
        "| path | frames/s (wall) | × real time (wall) | frames per CPU-second | × real time per core |",
        "|---|---:|---:|---:|---:|",
    ]
    for key, label in shown:
        r = rows[key]
        lines.append(
            table_row(
                [
                    label,
                    int_text(r["frames_per_s"]),
                    f"{r['x_real_time']:.1f}",
                    int_text(r["frames_per_cpu_s"]),
                    f"{r['x_real_time_per_core']:.1f}",
                ]
            )
        )
    regroup = rows["CAN decode+regroup (memory)"]
    us = 1e6 / regroup["frames_per_cpu_s"]
    fps = d["can_frames_per_sample"] * d["rate"]
    lines += [
        "",
        f"Decoding and regrouping cost {us:.2f} µs of CPU per frame; the rest of the CAN path is "
        "python-can's per-frame work (slcan line parsing, `Message` objects, the notifier thread). A "
        "1 Mbit/s classic bus delivers at most about 8,000 frames/s — "
        f"{'less' if fps > 8000 else 'more'} than the humanoid's "
        f"{int_text(fps)} — so on classic CAN such a robot "
        f"{'needs two buses anyway; the CAN FD layout carries it on one' if fps > 8000 else 'fits one bus'}.",
    ]
    return "\n".join(lines)
