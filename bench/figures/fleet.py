"""Figures from ``bench fleet`` (docs/bench/fleet.json): the service at fleet scale."""

from __future__ import annotations

import statistics

from bench.figures.files import BenchFiles, int_text, table_row

__all__ = ["doc"]


def doc(b: BenchFiles) -> str:
    from bench.fleet import ALONE, LOADED

    d: dict = b.json("fleet.json")  # type: ignore[assignment]
    rows = [r for r in d["rows"] if r["beside"] == LOADED]
    alone = [r for r in d["rows"] if r["beside"] == ALONE]
    # Workers on machines of their own (the distributed setup) train at the rate measured alone, when
    # the bench measured it; else at the best rate measured beside ingest and the API.
    basis = alone or rows
    best = max(basis, key=lambda r: r["retrains_per_hour"] / r["workers"])
    per_worker = best["retrains_per_hour"] / best["workers"]
    warm = d["warm_cpu_s"]
    per_robot_sps = statistics.median(r["ingest_samples_per_s"] / r["robots"] for r in rows)
    speed = ", ".join(f"{n} robots {s:g}x" for n, s in d["speedup_2_over_1"].items())
    speed_alone = ", ".join(f"{n} robots {s:g}x" for n, s in d["speedup_2_over_1_alone"].items())
    alone_lines = (
        [
            "",
            "With the training alone on the machine (no ingest, no API), as on workers of their own:",
            "",
            "| robots | workers | retrains/hour | CPU s per retrain (median) |",
            "|---:|---:|---:|---:|",
            *[
                table_row([r["robots"], r["workers"], int_text(r["retrains_per_hour"]), r["cpu_s_median"]])
                for r in alone
            ],
        ]
        if alone
        else []
    )
    lines = [
        f"From {b.provenance('fleet')} (load average {d['load_average']} at its end): {d['robot']} "
        f"robots ({d['joints']} joints, {d['imus']} IMUs), {d['window_s']:g} s windows. A warm retrain "
        f"took {warm:g} CPU s (median), a robot's first, cold one {d['cold_cpu_s']:g} CPU s. Per fleet "
        "size and workers, on this machine, with ingest and the API running beside the training:",
        "",
        "| robots | workers | retrains/hour | ingest lag median s | ingest lag max s | API p99 ms |",
        "|---:|---:|---:|---:|---:|---:|",
        *[
            table_row(
                [
                    r["robots"],
                    r["workers"],
                    int_text(r["retrains_per_hour"]),
                    r["ingest_lag_s_median"],
                    r["ingest_lag_s_max"],
                    f"{r['api_p99_ms']:g}",
                ]
            )
            for r in rows
        ],
        *alone_lines,
        "",
        f"2 workers against 1: {speed} with ingest and the API beside"
        + (f"; {speed_alone} with the training alone" if speed_alone else "")
        + ". Extrapolated from the per-robot costs: workers at the best rate measured per worker "
        f"{'with the training alone ' if alone else ''}({per_worker:,.0f} retrains/hour, {best['robots']} "
        f"robots on {best['workers']}), CPU cores from the warm retrain's CPU seconds, and "
        f"{per_robot_sps:,.0f} IMU samples/s per robot:",
        "",
        "| robots | retrain every | retrains/hour needed | workers (measured rate) | CPU cores (warm CPU s) "
        "| IMU samples/s into the store |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    for n in (1_000, 10_000):
        for every, label in ((60.0, "1 min (default)"), (600.0, "10 min"), (3600.0, "1 h")):
            need = n * 3600.0 / every
            lines.append(
                table_row(
                    [
                        int_text(n),
                        label,
                        int_text(need),
                        int_text(-(-need // per_worker)),
                        int_text(-(-need * warm // 3600.0)),
                        int_text(n * per_robot_sps),
                    ]
                )
            )
    return "\n".join(lines)
