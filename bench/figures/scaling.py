"""Figures from ``bench scaling`` (docs/bench/scaling.json): how the estimators' time grows."""

from __future__ import annotations

import numpy as np

from bench.figures.files import BenchFiles, table_row

__all__ = ["doc", "readme"]


def _series(b: BenchFiles) -> dict[str, list[dict]]:
    return b.json("scaling.json")["series"]  # type: ignore[index]


def _slope(rows: list[dict], key: str) -> float:
    x = np.log([r[key] for r in rows])
    y = np.log([r["cpu_s"] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def readme(b: BenchFiles) -> str:
    s = _series(b)
    j, i, t = s["joints"], s["imus"], s["samples"]
    secs = j[0]["samples"] / 100
    return (
        f"Measured with {b.provenance('scaling')}, `fast` on one CPU thread: joints {j[0]['joints']} → "
        f"{j[-1]['joints']}: {j[0]['cpu_s']:.3f} → {j[-1]['cpu_s']:.3f} s at {secs:g} s of data "
        f"(log-log slope {_slope(j, 'joints'):.2f}); IMUs {i[0]['imus']} → {i[-1]['imus']} on "
        f"{i[0]['joints']} joints: {i[0]['cpu_s']:.3f} → {i[-1]['cpu_s']:.3f} s (slope "
        f"{_slope(i, 'imus'):.2f}); samples {t[0]['samples']:,} → {t[-1]['samples']:,}: "
        f"{t[0]['cpu_s']:.3f} → {t[-1]['cpu_s']:.3f} s (slope {_slope(t, 'samples'):.2f})."
    )


def doc(b: BenchFiles) -> str:
    s = _series(b)
    exact = all(p["exact"] for rows in s.values() for p in rows)
    heads = {
        "joints": f"joints N (1 IMU/link, {s['joints'][0]['samples'] / 100:g} s)",
        "imus": f"IMUs K ({s['imus'][0]['joints']} joints, {s['imus'][0]['samples'] / 100:g} s)",
        "samples": f"samples T ({s['samples'][0]['joints']} joints)",
    }
    lines = [
        f"Measured with {b.provenance('scaling')}; exact on {'every' if exact else 'not every'} point:",
    ]
    for key, head in heads.items():
        rows = s[key]
        lines += [
            "",
            table_row([head, *(f"{r[key]:,}" for r in rows)]),
            "|---" * (len(rows) + 1) + "|",
            table_row(["CPU s", *(f"{r['cpu_s']:.3f}" for r in rows)]),
        ]
    lines += [
        "",
        f"Log-log slopes: {_slope(s['joints'], 'joints'):.2f} in joints, {_slope(s['imus'], 'imus'):.2f} "
        f"in IMUs, {_slope(s['samples'], 'samples'):.2f} in samples.",
    ]
    return "\n".join(lines)
