"""Figures from ``bench calibration`` (docs/bench/calibration.json)."""

from __future__ import annotations

from bench.figures.files import BenchFiles

__all__ = ["figure"]


def figure(b: BenchFiles) -> str:
    d = b.json("calibration.json")
    assert isinstance(d, dict)
    parts = []
    for answer, a in d["summary"].items():
        if not isinstance(a, dict) or "forms" not in a:
            continue
        forms = a["forms"].values()
        n = sum(f["exact"] + f["undetermined"] + f["wrong"] for f in forms)
        top = [r for r in a["reliability"] if r["from"] >= 0.99]
        sure = f"{sum(r['right'] for r in top)} of {sum(r['parts'] for r in top)}"
        parts.append(
            f"{answer}: exact {sum(f['exact'] for f in forms)} of {n}, undetermined "
            f"{sum(f['undetermined'] for f in forms)}, confidently wrong {sum(f['wrong'] for f in forms)}; "
            f"parts at confidence ≥ 0.99 right: {sure}"
        )
    return f"On {len(d['rows'])} robot-forms ({b.provenance('calibration')}): " + "; ".join(parts) + "."
