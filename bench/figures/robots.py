"""Figures from ``bench robots`` (docs/bench/robots.json): the measured robots' health and replay."""

from __future__ import annotations

from typing import Any

from bench.figures.files import BenchFiles

__all__ = ["figure", "foot_plane"]


def _faults(faults: list[dict[str, Any]]) -> str:
    found = sum(bool(f.get("found")) and f.get("rank") == 1 for f in faults)
    undetermined = sum(f.get("undetermined") is not None and not f.get("found") for f in faults)
    return (
        f"{found} of {len(faults)} injected faults found with the right kind first, "
        f"{undetermined} undetermined"
    )


def _replay(s: dict[str, Any]) -> str:
    return (
        f"the service's looped replay at 10x: {s['log_seconds'] / 60:.1f} min of log time, "
        f"floating-base baseline learned: {'yes' if s.get('floating_baseline') else 'no'}, "
        f"{s['alerts']} alerts, exit code {s['exit_code']}"
    )


def figure(b: BenchFiles) -> str:
    d = b.json("robots.json")
    assert isinstance(d, dict)
    parts = []
    for name, r in d.items():
        windows = r.get("untouched_windows") or []
        text = (
            f"{name}: {sum(w['findings'] for w in windows)} findings over {len(windows)} untouched 10 s "
            f"windows and {r.get('half_vs_half_findings')} first half against second; "
            f"{_faults(r.get('faults') or [])}"
        )
        if r.get("service_replay"):
            text += f"; {_replay(r['service_replay'])}"
        parts.append(text)
    return f"`bodyhealth bench robots` on {_machine(b)} (docs/bench/robots.md): " + "; ".join(parts) + "."


def _machine(b: BenchFiles) -> str:
    lines = b.text("robots.md").splitlines()
    return next(
        (ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("Machine:")), "machine not recorded"
    )


def foot_plane(b: BenchFiles) -> str:
    """Per point-footed robot: the feet's plane against the IMU's gravity, healthy and under each fault."""
    d = b.json("robots.json")
    assert isinstance(d, dict)
    parts = []
    for name, r in d.items():
        p = r.get("foot_plane") or {}
        if "fault_shift_deg" not in p:
            continue
        shifts = "; ".join(f"`{k}` {v}°" for k, v in p["fault_shift_deg"].items())
        parts.append(
            f"{name}: a plane on {p['plane_fraction']:.0%} of samples; healthy, its tilt against the "
            f"accelerometer's gravity spreads {p['block_std_deg'][0]}° and {p['block_std_deg'][1]}° "
            f"(x, y) over 1 s blocks, and the two halves' means differ by {p['halves_change_norm_deg']}°; "
            f"a fault shifts the mean by: {shifts}"
        )
    return f"`bodyhealth bench robots` on {_machine(b)} (docs/bench/robots.md): " + ". ".join(parts) + "."
