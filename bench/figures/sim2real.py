"""Figures from ``bench sim2real`` and its detect and encoders runs (docs/bench/sim2real*)."""

from __future__ import annotations

import re
import statistics

import numpy as np

from bench.figures.files import BENCH, BenchFiles, num, span

__all__ = ["detect", "doc", "encoders", "example", "readme"]


def _trials(b: BenchFiles) -> dict[str, dict]:
    """Every per-trial discrepancy.json under docs/bench/sim2real/, by trial name."""
    base = b.root / BENCH / "sim2real"
    return {
        p.parent.name: b.json(f"sim2real/{p.parent.name}/discrepancy.json")
        for p in sorted(base.glob("*/discrepancy.json"))
    }  # type: ignore[misc]


def _cause(d: dict, effect: str) -> dict | None:
    return next((c for c in d["causes"] if c["effect"] == effect), None)


def _stats(b: BenchFiles) -> dict:
    trials = _trials(b)
    n = len(trials)
    causes = {
        e: {t: c for t, d in trials.items() if (c := _cause(d, e)) is not None}
        for e in ("time_offset", "lever_arm", "gyro_bias", "acc_bias", "gyro_scale")
    }
    lever = {t: np.asarray(c["params"]["meters"]) for t, c in causes["lever_arm"].items()}
    rows = b.table("sim2real.md", "trial")
    wall = [num(r["analysis s (cpu s)"]) for r in rows]
    cpu = [float(re.search(r"\(([0-9.]+)\)", r["analysis s (cpu s)"]).group(1)) for r in rows]  # type: ignore[union-attr]
    transfer = [r["transfer gain"] for r in rows]
    tr_med = [num(t) for t in transfer]
    tr_lo = [float(re.search(r"\(([-0-9.]+)–", t).group(1)) for t in transfer]  # type: ignore[union-attr]
    tr_hi = [float(re.search(r"–([-0-9.]+),", t).group(1)) for t in transfer]  # type: ignore[union-attr]
    held = {t: d["held_out"] for t, d in trials.items()}
    best = max(held, key=lambda t: held[t]["gain"])
    minutes = statistics.mean(d["meta"]["duration_s"] for d in trials.values()) / 60
    rate = statistics.median(
        d["params"]["noise"]["rate_hz"] for d in trials.values() if "noise" in d["params"]
    )
    limit = re.search(r"limit (\d+) s", b.text("sim2real.md"))
    return {
        "n": n,
        "causes": causes,
        "offset_ms": [c["params"]["seconds"] * 1e3 for c in causes["time_offset"].values()],
        "offset_gain": [c["gain"] for c in causes["time_offset"].values()],
        "lever_mm": [float(np.linalg.norm(v)) * 1e3 for v in lever.values()],
        "lever_z": sum(int(np.argmax(np.abs(v)) == 2) for v in lever.values()),
        "gyro_bias": [float(np.linalg.norm(c["params"]["vector"])) for c in causes["gyro_bias"].values()],
        "acc_bias": [float(np.linalg.norm(c["params"]["vector"])) for c in causes["acc_bias"].values()],
        "gyro_bias_sessions": sorted({t.rsplit("_", 1)[1] for t in causes["gyro_bias"]}),
        "held_gain": [h["gain"] for h in held.values()],
        "best": best,
        "best_held": held[best],
        "minutes": minutes,
        "rate": rate,
        "wall": wall,
        "cpu": cpu,
        "tr_med": tr_med,
        "tr_lo": tr_lo,
        "tr_hi": tr_hi,
        "limit": limit.group(1) if limit else "30",
    }


def _sessions(names: list[str]) -> str:
    return (
        f"session {names[0]}"
        if len(names) == 1
        else "sessions " + ", ".join(names[:-1]) + f" and {names[-1]}"
    )


def _provenance(b: BenchFiles) -> str:
    return (
        f"`{b.command('sim2real')}` on {b.machine('sim2real')}; the `{BENCH}/sim2real/*/discrepancy.json` "
        f"reports and `{BENCH}/sim2real.md`"
    )


def readme(b: BenchFiles) -> str:
    s = _stats(b)
    n, c = s["n"], s["causes"]
    trial = s["best"].split("_")[0]
    h = s["best_held"]
    return "\n".join(
        [
            f"Measured with {_provenance(b)}: all {n} shared BROAD trials (one real IMU + optical motion "
            f"capture, ≈{s['minutes']:.1f} min each). Gains are measured on held-out time blocks, never on "
            "the fit data; *transfer* simulates the other trials of the same IMU session with the fitted "
            "model vs the default model (1 − MSE ratio).",
            "",
            "| | result |",
            "|---|---|",
            f"| named in {len(c['time_offset'])}/{n} trials | `time_offset` "
            f"{span(s['offset_ms'], '.1f')} ms (the IMU lags the motion capture by about one "
            f"{s['rate']:.1f} Hz sample) |",
            f"| named in {len(c['lever_arm'])}/{n} trials | `lever_arm` {span(s['lever_mm'], '.1f')} mm, "
            f"largest along the sensor z axis in {s['lever_z']}/{len(c['lever_arm'])} |",
            f"| named in some | `gyro_bias` {span(s['gyro_bias'], '.3f')} rad/s "
            f"({len(c['gyro_bias'])}/{n}), "
            f"`acc_bias` {span(s['acc_bias'], '.2f')} m/s² ({len(c['acc_bias'])}/{n}), `gyro_scale` "
            f"({len(c['gyro_scale'])}/{n}) |",
            f"| held-out gain per trial | {span(s['held_gain'])} (trial {trial}: gyro RMS "
            f"{h['gyro_rms_before']:.3f} → {h['gyro_rms_after']:.3f} rad/s) |",
            f"| transfer gain to other trials of the session | median per fitted trial "
            f"{span(s['tr_med'])} (range {min(s['tr_lo']):.2f}–{max(s['tr_hi']):.2f})"
            f"{', never worse' if min(s['tr_lo']) >= 0 else ''} |",
            f"| analysis time per trial | median {statistics.median(s['wall']):.1f} s, max "
            f"{max(s['wall']):.1f} s wall clock (limit {s['limit']} s); CPU median "
            f"{statistics.median(s['cpu']):.1f} s |",
        ]
    )


def doc(b: BenchFiles) -> str:
    s = _stats(b)
    n, c = s["n"], s["causes"]
    trial = s["best"].split("_")[0]
    h = s["best_held"]
    lo, hi = min(s["tr_lo"]), max(s["tr_hi"])
    return "\n".join(
        [
            f"In short (measured with {_provenance(b)}):",
            "",
            f"* **{'Every' if len(c['time_offset']) == n else 'Not every'} trial** names a **time offset** "
            "of "
            f"{span(s['offset_ms'], '.1f')} ms (the IMU samples lag the motion capture by about one sample "
            f"at {s['rate']:.1f} Hz; held-out gain {span(s['offset_gain'])} of the ideal model's residual "
            f"energy on its own), and {len(c['lever_arm'])} of {n} a **lever arm** of "
            f"{span(s['lever_mm'], '.1f')} mm, largest along the sensor's z axis in {s['lever_z']} of "
            f"{len(c['lever_arm'])}. Beside them: a small gyro bias "
            f"({span(s['gyro_bias'], '.3f')} rad/s, "
            f"{len(c['gyro_bias'])} trials, {_sessions(s['gyro_bias_sessions'])}), an accelerometer bias "
            f"({span(s['acc_bias'], '.2f')} m/s², {len(c['acc_bias'])} trials) and, in "
            f"{len(c.get('gyro_scale', []))} trials, a gyro scale error.",
            f"* Total held-out gain {span(s['held_gain'])} per trial (best: trial {trial}, gyro RMS "
            f"{h['gyro_rms_before']:.3f} → {h['gyro_rms_after']:.3f} rad/s). What remains is mostly "
            "accelerometer residual above a few Hz, where differentiating the motion capture twice is itself "
            "the error.",
            "* **Transfer:** the model fitted on one trial and simulated on the other trials of the same "
            f"IMU session removes {lo * 100:.0f}–{hi * 100:.0f} % of the default model's error (median per "
            f"fitting trial {span(s['tr_med'])}){'; never negative' if lo >= 0 else ''}.",
            f"* Analysis {span(s['wall'], '.1f')} s wall clock per trial "
            f"(≈ {s['minutes']:.1f} min of data), "
            f"{span(s['cpu'], '.1f')} s CPU; limit {s['limit']} s.",
        ]
    )


def example(b: BenchFiles) -> str:
    name = "02_undisturbed_slow_rotation_B"
    text = b.text(f"sim2real/{name}/report.md")
    m = re.search(r"```\n(.*?)```", text, re.S)
    if m is None:
        raise ValueError(f"sim2real/{name}/report.md has no output block")
    return "\n".join(
        [
            f"Example output (trial {name.split('_')[0]}, slow rotations, session {name[-1]}; from "
            f"{BENCH}/sim2real/{name}/report.md, written by `{b.command('sim2real')}` on "
            f"{b.machine('sim2real')}):",
            "",
            "```",
            m.group(1).rstrip("\n"),
            "```",
        ]
    )


def detect(b: BenchFiles) -> str:
    from bench.sim2real_detect import summary

    d = b.json("sim2real-detect.json")
    return "\n".join([f"Measured with `{d['command']}` on {d['machine']}:", "", *summary(d)])


def encoders(b: BenchFiles) -> str:
    from bench.sim2real_encoders import summary

    d = b.json("sim2real-encoders.json")
    return "\n".join([f"Measured with `{d['command']}` on {d['machine']}:", "", *summary(d)])
