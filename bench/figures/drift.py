"""Figures from ``bench drift`` (docs/bench/drift.json and its accelerometer-frame run)."""

from __future__ import annotations

from bench.figures.files import BenchFiles

__all__ = ["figure"]


def _kinds(cat: list[dict]) -> str:
    """The kinds of the catalog part's false findings, counted ("4 imu_shifted"; "none")."""
    from collections import Counter

    n = Counter(f["kind"] for r in cat for w in r["nominal_findings"] for f in w)
    return ", ".join(f"{v} {k}" for k, v in sorted(n.items())) or "none"


def figure(b: BenchFiles, name: str = "drift") -> str:
    """``bench drift``'s run in ``docs/bench/<name>.json``, in the frame it ran in."""
    from bench.drift import elsewhere, finding_change, service_text

    d = b.json(f"{name}.json")
    assert isinstance(d, dict)
    cat = d["catalog"]
    windows = sum(r["nominal_windows"] for r in cat)
    false = sum(len(n) for r in cat for n in r["nominal_findings"])
    parts = []
    for kind, label in (("imu_rotated", "turn of one IMU"), ("axis_changed", "bend of its joint's axis")):
        runs = [g for r in cat for g in r["damages"] if g["kind"] == kind]
        seen = [
            c
            for g in runs
            if g["first_right"] and (c := finding_change(g["findings"][0]["detail"])) is not None
        ]
        mag = runs[0]["magnitude"] if runs else 0
        right = sum(g["first_right"] for g in runs)
        text = f"a {mag:g}° {label}: first found on its part on {right} of {len(runs)}"
        if seen:
            text += (
                f" (change seen {min(c[0] for c in seen):.2f} to {max(c[0] for c in seen):.2f}°, "
                f"limits {min(c[1] for c in seen):.2f} to {max(c[1] for c in seen):.2f}°)"
            )
        parts.append(text)
    slack = [g for r in cat for g in r["damages"] if g["kind"] == "backlash"]
    if slack:
        parts.append(
            f"a {slack[0]['magnitude']:g}° dead band in that joint: first found on its part on "
            f"{sum(g['first_right'] for g in slack)} of {len(slack)}"
        )
    for mm in sorted({g["magnitude"] for r in cat for g in r["damages"] if g["kind"] == "imu_shifted"}):
        runs = [g for r in cat for g in r["damages"] if g["kind"] == "imu_shifted" and g["magnitude"] == mm]
        parts.append(
            f"a {mm:g} mm slide of that IMU: found on {sum(g['found'] for g in runs)} of {len(runs)}"
        )
    lines = [
        f"Measured with {b.provenance(name)}, "
        + ("in the accelerometers' frame" if d.get("accelerometer_frame") else "about the gyros' axes")
        + f": {len(cat)} catalog robots "
        f"({', '.join(r['robot'] for r in cat)}), `robot` sensing preset, MPU-6050 IMUs kept across the "
        f"run, {d['window_s']:g} s windows: {false} false findings in {windows} healthy windows compared "
        f"with each robot's first ({_kinds(cat)}); " + "; ".join(parts) + ". Two estimates are compared "
        "here by their stated stds, slides too; the service judges slides against the baseline's pool "
        "(below) and raises none from two estimates."
    ]
    p = d.get("pooled")
    if p is not None:
        found = "; ".join(
            f"{g['mm']:g} mm of {g['imu']} ({g['lever_arm_mm']:.0f} mm from its axis) "
            + (
                f"after {g['windows_to_finding']} window{'s' if g['windows_to_finding'] > 1 else ''}"
                if g["windows_to_finding"]
                else f"not within {p['windows_after']} windows"
            )
            for g in p["slides"]
        )
        lines += [
            "",
            f"Slides judged on pooled lever arms ({p['robot']}, {p['n_base']} estimates against the mean of "
            f"the newest k, every k up to {p['n_recent']}, each without its farthest): "
            f"{sum(len(n) for n in p['nominal_findings'])} "
            "findings in "
            f"{p['nominal_windows']} healthy windows judged{elsewhere(d, 'pooled')}; found: {found}.",
        ]
    if d["service"] is not None:
        lines += ["", service_text(d)]
    return "\n".join(lines)
