"""Figures from ``bench rotations`` (docs/bench/rotations.json)."""

from __future__ import annotations

from bench import fmt
from bench.figures.files import BenchFiles

__all__ = ["figure"]


def _share_within(rows: list[dict]) -> str:
    """The share of same-link rotations within twice their std, over every robot's (pair-weighted)."""
    n = sum(r["same_link_fixed"] for r in rows)
    k = sum(r["same_link_fixed_within_2std"] * r["same_link_fixed"] for r in rows)
    return f"{k / n:.1%}"


def figure(b: BenchFiles) -> str:
    d = b.json("rotations.json")
    assert isinstance(d, dict)
    rows = d["summary"]
    s = d["settings"]
    det = [r for r in rows if r["determined"]]
    und = [r for r in rows if r["undetermined"]]
    fixed = [r for r in rows if r["same_link_fixed"]]

    def ext(rs: list[dict], key: str, f=max) -> float:
        return f(r[key] for r in rs if r[key] is not None)

    lines = [
        f"Measured with {b.provenance('rotations')}: {len(rows)} catalog robots, {s['seeds']} recordings "
        f"of {s['seconds']:g} s each, `{s['imu_model']}` IMU errors, `{s['sensing']}` sensing preset, the "
        f"true tree. {sum(r['determined'] for r in rows)} rotations from the parent were reported "
        f"determined, the largest {ext(det, 'determined_max_deg'):.2f}° off; "
        f"{sum(r['undetermined'] for r in rows)} undetermined, on "
        f"{', '.join(r['robot'] for r in und) or 'none'}, "
        + (
            f"{ext(und, 'undetermined_min_deg', min):.1f} to {ext(und, 'undetermined_max_deg'):.1f}° off, "
            f"with turn stds of {ext(und, 'undetermined_turn_std_min_deg', min):.2f}° and more"
            if und
            else "none"
        )
        + f". Same-link rotations at rank 2 or more: {sum(r['same_link_fixed'] for r in rows)}, the largest "
        f"{ext(fixed, 'same_link_fixed_max_deg'):.2f}° off, {_share_within(fixed)} of them within twice "
        f"their std; {sum(r['same_link_rank1'] for r in rows)} at rank 1.",
        "",
        "| robot | determined | max error ° | undetermined | their errors ° | same link rank ≥ 2 "
        "| max error ° | rank 1 |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        span = (
            "—"
            if not r["undetermined"]
            else f"{r['undetermined_min_deg']:.1f}–{r['undetermined_max_deg']:.1f}"
        )
        lines.append(
            f"| {r['robot']} | {r['determined']} | {fmt(r['determined_max_deg'])} | {r['undetermined']} "
            f"| {span} | {r['same_link_fixed']} | {fmt(r['same_link_fixed_max_deg'])} "
            f"| {r['same_link_rank1']} |"
        )
    lines += ["", "![rotations](bench/rotations.png)"]
    return "\n".join(lines)
