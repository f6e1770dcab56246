"""Figures from ``bench load`` (docs/bench/load.json): the API under concurrent readers."""

from __future__ import annotations

from bench import fmt
from bench.figures.files import BenchFiles

__all__ = ["readme"]


def readme(b: BenchFiles) -> str:
    d = b.json("load.json")
    at_target = [r for r in d["rows"] if r["offered_rps"] == d["target_rps"]]

    def who(r: dict) -> str:
        kind = "threads" if r.get("client") == "threads" else "locust users"
        return f"{r.get('users', '?')} {kind}"

    verdicts = [
        ("met" if r["p99_ms"] <= d["target_p99_ms"] and not r["failures"] else "missed")
        + f" from {who(r)} (p99 {r['p99_ms']:g} ms)"
        for r in at_target
    ]
    lines = [
        f"Measured with {b.provenance('load')}, load average {d['load_average']:.1f}: `bodyhealth serve "
        f"--demo` (SQLite, the farm ingesting in real time, the worker learning, the networks training) "
        f"under mixed reads from a load generator on the same machine, {d['seconds']:g} s per run. "
        f"Target: p99 ≤ {d['target_p99_ms']:g} ms at {d['target_rps']:g} rps — "
        + ("; ".join(verdicts) or "not measured at the target rate")
        + ".",
        "",
        "| offered rps | clients | achieved rps | p50 | p95 | p99 | service's own p99 | failures "
        "| service CPU s/s | frames stored/s | network retrains |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["rows"]:
        lines.append(
            f"| {r['offered_rps']:g} | {who(r)} | {r['achieved_rps']:.1f} | {r['p50_ms']:g} ms "
            f"| {r['p95_ms']:g} ms | {r['p99_ms']:g} ms | {fmt(r.get('app_p99_ms'), 'g', ' ms')} "
            f"| {r['failures']} "
            f"| {r['service_cpu_per_s']:.2f} "
            f"| {r['frames_stored_per_s']:.0f} | {r.get('network_retrains', 0)} |"
        )
    return "\n".join(lines)
