"""Figures from ``bench alerts`` (docs/bench/alerts.json, and a run kept under another name): alerts in
time on a loaded machine."""

from __future__ import annotations

from typing import Any

from bench.alerts_report import command_text
from bench.figures.files import BenchFiles

__all__ = ["figure"]


def _metric(name: str, m: dict[str, Any]) -> str:
    return f"{name} max {m['max']:.0f} (median {m['median']:.0f}, target {m['target']:g})"


def figure(b: BenchFiles, name: str = "alerts") -> str:
    """One line per run file ``name``.json: the command, the loads and each timed target's max."""
    d = b.json(f"{name}.json")
    assert isinstance(d, dict)
    s, runs = d["summary"], d["runs"]
    loads = [x for r in runs for x in (r["load_before"], r["load_after"])]
    timed = "; ".join(_metric(k, m) for k, m in s.items() if k.endswith("_s") and "target" in m)
    approvals = ", ".join(
        f"{k.split()[1]} p99 max {s[k]['max']:.0f} ms" for k in s if k.startswith("approval") and "p99" in k
    )
    own_p99 = [k for k in s if k.startswith("service's own") and k.endswith("p99_ms")]
    own = ", ".join(f"{k.split()[2]} p99 max {s[k]['max']:.0f} ms" for k in own_p99)
    approvals += f" (the service's own time {own})" if own else ""
    false = s.get("false_alerts", {}).get("max")
    restarts = [f"{r['restart']['t_s']:.0f} s" for r in runs if r.get("restart")]
    when = f", restarted at {', '.join(restarts)}" if restarts else ""
    return (
        f"{command_text(d)} on {d['machine']}, {len(runs)} run{'s' if len(runs) != 1 else ''}{when}, "
        f"load average {min(loads):.1f} to {max(loads):.1f}: seconds {timed}; false alerts {false}; "
        f"baseline approvals {approvals}."
    )
