"""Figures from ``bench store`` (docs/bench/store.json): the windowed store's write and read rates."""

from __future__ import annotations

from bench.figures.files import BenchFiles, int_text, table_row

__all__ = ["doc", "readme"]


def _data(b: BenchFiles) -> dict:
    return b.json("store.json")  # type: ignore[return-value]


def readme(b: BenchFiles) -> str:
    d = _data(b)
    names = {"sqlite": "SQLite", "postgresql": "PostgreSQL"}
    rows = sorted(d["rows"], key=lambda r: (r["backend"] != "sqlite", not r["path"].startswith("pipeline")))
    target = d["target_multiple"] * d["imus"] * d["rate_hz"]
    best = max((r for r in rows if r["backend"] == "sqlite"), key=lambda r: r["realtime_multiple"])
    met = best["realtime_multiple"] >= d["target_multiple"]
    how = "through the ingest pipeline" if best["path"].startswith("pipeline") else f"with {best['path']}"
    lines = [
        f"Measured with {b.provenance('store')}, load average {d['load_average']:.1f}: a {d['imus']}-IMU, "
        f"{d['joints']}-joint robot at {d['rate_hz']:g} Hz, {d['device_seconds']:g} s of device time; window "
        f"read = the latest {d['window_seconds']:g} s as arrays. Target ≥ {d['target_multiple']:g}× real "
        f"time ({int_text(target)} IMU samples/s) on SQLite — {'met ' + how if met else 'missed'}.",
        "",
        f"| backend | path | IMU samples/s | × real time | {d['window_seconds']:g} s window read |",
        "|---|---|---:|---:|---:|",
    ]
    for r in rows:
        path = (
            "pipeline (queue → coalescing writer)"
            if r["path"].startswith("pipeline") and r["backend"] == "sqlite"
            else "pipeline"
            if r["path"].startswith("pipeline")
            else f"`write_many`, {r['path'].removeprefix('write_many ')} per transaction"
        )
        read = f"{r['window_read_ms']:.0f} ms" if r["window_read_ms"] is not None else ""
        lines.append(
            table_row(
                [
                    names.get(r["backend"], r["backend"]),
                    path,
                    int_text(r["imu_samples_per_s"]),
                    f"{r['realtime_multiple']:.0f}×",
                    read,
                ]
            )
        )
    return "\n".join(lines).replace("|  |", "| |")


def doc(b: BenchFiles) -> str:
    d = _data(b)
    rows = {(r["backend"], r["path"].split()[0]): r for r in d["rows"]}
    parts = []
    for backend, name in (("sqlite", "SQLite"), ("postgresql", "PostgreSQL")):
        pipe, direct = rows.get((backend, "pipeline")), rows.get((backend, "write_many"))
        if pipe and direct:
            parts.append(
                f"{name} {pipe['realtime_multiple']:.0f}× real time through the pipeline and "
                f"{direct['realtime_multiple']:.0f}× with `write_many`, a {d['window_seconds']:g} s window "
                f"read in {pipe['window_read_ms']:.0f} ms"
            )
    return (
        f"`bodyhealth bench store` ingests a {d['imus']}-IMU, {d['joints']}-joint robot at "
        f"{d['rate_hz']:g} Hz into SQLite and PostgreSQL, through the pipeline and through direct "
        f"`write_many` calls with one second per transaction, and times reading a "
        f"{d['window_seconds']:g} s window. In the run recorded "
        f"there ({b.provenance('store')}, load average {d['load_average']:.1f}): " + "; ".join(parts) + "."
    )
