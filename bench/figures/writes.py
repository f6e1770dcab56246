"""Figures from ``bench writes`` (docs/bench/writes.json): concurrent writers on the store."""

from __future__ import annotations

from bench.figures.files import BenchFiles

__all__ = ["doc"]


def doc(b: BenchFiles) -> str:
    d = b.json("writes.json")
    default = d["default_interval_s"]
    rows = {(r["backend"], r["commit_interval_s"]): r for r in d["rows"]}
    parts = []
    for backend, name in (("sqlite", "SQLite"), ("postgresql", "PostgreSQL")):
        at, none = rows.get((backend, default)), rows.get((backend, 0.0))
        if at and none:
            parts.append(
                f"{name} {at['journal_amplification']:.2f}x journal ({at['total_amplification']:.2f}x in "
                f"total) at {default:g} s, against {none['journal_amplification']:.2f}x "
                f"({none['total_amplification']:.2f}x) when every queued batch is committed at once"
            )
    return (
        f"`bodyhealth bench writes` streams {d['robots']} robots ({d['joints']} joints, {d['imus']} IMUs, "
        f"100 Hz) in real time through the ingest pipeline and counts the bytes written per byte of "
        f"frames, for each commit interval (target: journal at most {d['target']:g}x at the default "
        f"{default:g} s). In the run recorded there ({b.provenance('writes')}, load average "
        f"{d['load_average']:.1f}): " + "; ".join(parts) + "."
    )
