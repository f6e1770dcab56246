"""Figures from ``bench realism`` (docs/bench/realism.json)."""

from __future__ import annotations

import numpy as np

from bench.figures.files import BenchFiles

__all__ = ["figure"]


def figure(b: BenchFiles, name: str = "realism") -> str:
    """``bench realism``'s run in ``docs/bench/<name>.json``."""
    d = b.json(f"{name}.json")
    assert isinstance(d, dict)
    summary, rows, catalog = d["summary"], d["rows"], d.get("catalog", [])
    sizes = sorted({r["joints"] for r in rows})
    n_robots = len({(r["joints"], r["robot"]) for r in rows})
    parts = []
    for method, s in summary.items():
        if not s["robots"]:
            continue
        big = [r for r in rows if r["method"] == method and r["joints"] == sizes[-1] and r["cell"] != "ideal"]
        cost = (
            f"; {np.mean([r['cpu_s'] for r in big]):.1f} CPU s per robot on average and at most "
            f"{max(r['cpu_s'] for r in big):.1f} at {sizes[-1]} joints (sensed cells)"
            if big
            else ""
        )
        skew = s["max_abs_skew_err_ms_where_exact"]
        one = s.get("single_clock") or {}
        parts.append(
            f"`{method}`: {s['exact']} of {s['robots']} estimates exact, {s['undetermined']} "
            f"undetermined, {s['wrong']} confidently wrong"
            + (f", skew within {skew:.2f} ms wherever exact" if skew is not None else "")
            + cost
            + (
                f"; in single-clock form (one `t`, positions only) {one['exact']} of {one['robots']} "
                f"exact, {one['undetermined']} undetermined, {one['wrong']} confidently wrong"
                if one.get("robots")
                else ""
            )
        )
    text = (
        f"On random MuJoCo robots of {', '.join(map(str, sizes))} joints ({n_robots} "
        f"robots, {len({r['cell'] for r in rows})} sensing conditions; {b.provenance(name)}): "
        + "; ".join(parts)
        + "."
    )
    if catalog:
        exact = sum(c["verdict"] == "exact" for c in catalog)
        text += (
            f" The catalog on the robot preset: {exact} of {len(catalog)} exact with `fast`, skew error at "
            f"most {max(abs(c['skew_err_ms']) for c in catalog):.2f} ms."
        )
    return text
