"""Figures from ``bench excitation`` (docs/bench/excitation.json)."""

from __future__ import annotations

from bench import fmt
from bench.figures.files import BenchFiles

__all__ = ["figure"]


def figure(b: BenchFiles) -> str:
    d = b.json("excitation.json")
    assert isinstance(d, dict)
    s, runs = d["summary"], d["runs"]
    wrong = {
        m: sum(r["wrong"] for r in runs if r["motion"] == m) for m in dict.fromkeys(r["motion"] for r in runs)
    }
    later = s["planned_later_than_one_at_a_time"]
    return (
        f"On {s['robots']} robots ({b.provenance('excitation')}): the planned motion reached the unique, "
        f"right tree {fmt(s['median_topology_ratio'], '.2f')}x sooner than the default random motion "
        f"(median) and converged geometry {fmt(s['median_geometry_ratio'], '.2f')}x sooner; it was later "
        f"than one joint at a time on {len(later)} robot(s); unique but wrong trees at some prefix: "
        + ", ".join(f"{m} {n}" for m, n in wrong.items())
        + f"; {s['violations']} limit violations; planning took at most "
        f"{fmt(s['plan_cpu_s_max'], '.2f')} CPU s."
    )
