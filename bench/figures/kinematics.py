"""Figures from ``bench kinematics`` (docs/bench/kinematics.json)."""

from __future__ import annotations

from bench.figures.files import BenchFiles, table_row

__all__ = ["figure"]


def _rows(b: BenchFiles) -> dict:
    d = b.json("kinematics.json")
    assert isinstance(d, dict)
    return d


def _line(r: dict) -> str:
    return (
        f"axis error median {r['axis_median_deg']:.2f}° (max {r['axis_max_deg']:.2f}°), "
        f"{r['axis_within_2std']:.0%} of them within twice their std, where the axis the gyro reports is "
        f"off by {r['gyro_axis_median_deg']:.2f}° (max {r['gyro_axis_max_deg']:.2f}°; its sensitivity "
        f"matrix alone: {r['gyro_floor_median_deg']:.2f}°, max {r['gyro_floor_max_deg']:.2f}°); lever arm "
        f"median {r['lever_median_mm']:.1f} mm (max {r['lever_max_mm']:.1f} mm); "
        f"{r['converged']} of {r['imus_on_links']} IMUs converged"
    )


def figure(b: BenchFiles) -> str:
    d = _rows(b)
    s, t = d["settings"], d["targets"]
    longest = d["summary"][-1]
    verdict = []
    for key, name, unit, got in (
        ("axis_deg", "axis", "°", (longest["axis_median_deg"], longest["axis_max_deg"])),
        ("lever_mm", "lever arm", " mm", (longest["lever_median_mm"], longest["lever_max_mm"])),
    ):
        ok = got[0] is not None and got[0] <= t[key][0] and got[1] <= t[key][1]
        verdict.append(
            f"{name} median ≤ {t[key][0]:g}{unit} (max {t[key][1]:g}{unit}) — {'met' if ok else 'not met'}"
        )
    lines = [
        f"Measured with {b.provenance('kinematics')}: random trees of "
        f"{', '.join(map(str, s['joints']))} joints ({s['robots_per_size']} per size), `{s['imu_model']}` "
        f"IMU errors, `{s['sensing']}` sensing preset, the tree learned by `fast`. From "
        f"{longest['seconds']} s: {_line(longest)}. Targets from 60 s: " + "; ".join(verdict) + ".",
        "",
        "| seconds | converged | axis median / max ° | within 2 std | gyro axis median / max ° "
        "| lever median / max mm | CPU s |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["summary"]:
        lines.append(
            table_row(
                [
                    r["seconds"],
                    f"{r['converged']} / {r['imus_on_links']}",
                    f"{r['axis_median_deg']:.2f} / {r['axis_max_deg']:.2f}",
                    f"{r['axis_within_2std']:.0%}",
                    f"{r['gyro_axis_median_deg']:.2f} / {r['gyro_axis_max_deg']:.2f}",
                    f"{r['lever_median_mm']:.1f} / {r['lever_max_mm']:.1f}",
                    f"{r['cpu_s_median']:.2f}",
                ]
            )
        )
    pub = "; ".join(
        f"{p['source']}, {p['what']}: "
        + ", ".join(
            x
            for x in (
                f"{p['axis_deg']:g}°" if p["axis_deg"] is not None else "",
                f"{p['lever_mm']:g} mm" if p["lever_mm"] is not None else "",
            )
            if x
        )
        for p in d["published"]
    )
    lines += ["", f"Published figures, on other robots and sensors: {pub}."]
    return "\n".join(lines)
