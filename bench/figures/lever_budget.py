"""Figures from ``bench lever-budget`` (docs/bench/lever-budget.json)."""

from __future__ import annotations

from bench.figures.files import BenchFiles, table_row

__all__ = ["figure"]


def figure(b: BenchFiles) -> str:
    from bench.lever_budget import summary

    d = b.json("lever-budget.json")
    assert isinstance(d, dict)
    conds = d["conditions"]
    first = next(iter(conds.values()))["frames"]["gyro"]
    windows = max(r["windows"] for r in first.values())
    lines = [
        f"Measured with {b.provenance('lever-budget')}: the lever arms of the {d['robot']}'s {len(first)} "
        f"IMUs in {windows} windows of {d['window_s']:g} s, the same motion under each condition. Scatter: "
        "RMS distance of one window's lever arm from the windows' mean, median over the IMUs (largest); "
        "understated: IMUs scattering more than twice the std they state.",
        "",
        "| condition | gyros' frame | understated | accelerometers' frame | understated |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, c in conds.items():
        cells = []
        for frame in ("gyro", "accelerometer"):
            s = summary(c, frame)
            cells += [
                f"{s['scatter_median_mm']:.1f} ({s['scatter_max_mm']:.1f}) mm",
                f"{s['understated']} of {s['imus']}",
            ]
        lines.append(table_row([label, *cells]))
    far = []
    for label, said in (("MPU-6050", "the MPU-6050 model"), ("noise only", "its noise alone")):
        g = conds.get(label, {}).get("frames", {}).get("gyro")
        if g:
            n = max(g, key=lambda k: g[k]["worst_mm"])
            far.append(f"{g[n]['worst_mm']:.1f} mm ({n}) with {said}")
    if far:
        head = "The farthest one window's lever arm came from its IMU's mean, about the gyros' axes: "
        lines += ["", head + "; ".join(far) + "."]
    return "\n".join(lines)
