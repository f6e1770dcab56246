"""Figures from ``bench shapes`` (docs/bench/shapes.json)."""

from __future__ import annotations

from bench import fmt
from bench.figures.files import BenchFiles

__all__ = ["axis_floor", "figure"]


def figure(b: BenchFiles) -> str:
    d = b.json("shapes.json")
    assert isinstance(d, dict)
    rows, summary = d["rows"], d["summary"]
    joints = [r["joints"] for r in rows]
    parts = []
    for shape, s in summary.items():
        text = (
            f"{shape}: {s['exact']} exact, {s['undetermined']} undetermined ({s['named_joints']} joints "
            f"named to move), {s['wrong']} confidently wrong"
        )
        if s.get("robots_all_moved") is not None:
            moved = f"{s['exact_all_moved']} of the {s['robots_all_moved']}"
            text += f" (exact on {moved} robots whose joints all moved)"
        if s.get("axis_deg_median") is not None:
            text += (
                f"; on the true tree axis error median {s['axis_deg_median']:.2f}° (the gyro's reading "
                f"{fmt(s['gyro_axis_deg_median'])}°), lever arm median {fmt(s['lever_mm_median'], '.1f')} "
                f"mm over {s['imus']} IMUs, {s['converged']} converged"
            )
        parts.append(text)
    still = sum(len(r["still_joints"]) for r in rows if r["shape"] == rows[0]["shape"])
    return (
        f"On {len({r['robot'] for r in rows})} random robots of {min(joints)}-{max(joints)} joints from the "
        "independent generator (`bench/generator.py`, no code shared with `simulators/`; "
        f"{still} joints jammed: true rate RMS under 0.05 rad/s in the estimator's band over the span it "
        f"fits; {b.provenance('shapes')}): " + "; ".join(parts) + "."
    )


def axis_floor(b: BenchFiles) -> str:
    """The accelerometer cross-axis floor under the axis error, per recording shape (docs/kinematics.md)."""
    d = b.json("shapes.json")
    assert isinstance(d, dict)
    parts = [
        f"{shape}: floor median {fmt(s['axis_floor_deg_median'])}° against an axis error median of "
        f"{fmt(s['axis_deg_median'])}° over the {s['imus']} IMUs answered"
        for shape, s in d["summary"].items()
        if s.get("axis_floor_deg_median") is not None
    ]
    return f"Per IMU, from its drawn matrix ({b.provenance('shapes')}): " + "; ".join(parts) + "."
