"""Figures from ``bench topology`` (docs/bench/topology.json): the fast and network estimators."""

from __future__ import annotations

import re

from bench.figures.files import BenchFiles, span, table_row

__all__ = [
    "TOPOLOGY_FAST_TARGET_S",
    "TOPOLOGY_NETWORK_TARGET_S",
    "doc",
    "fast_shortest",
    "network_cost",
    "network_paper",
    "readme",
]


#: Targets the docs measure against. They are requirements, not results, so no bench file holds them.
TOPOLOGY_FAST_TARGET_S = ("humanoid", 2.0)


TOPOLOGY_NETWORK_TARGET_S = ("ur5e", 60.0)


def _rows(b: BenchFiles) -> list[dict]:
    return b.json("topology.json")  # type: ignore[return-value]


def _settings(b: BenchFiles) -> dict[str, str]:
    return dict(re.findall(r"--([\w-]+) (\S+)", b.command("topology")))


def _setup(b: BenchFiles) -> str:
    rows = {r["robot"]: r for r in _rows(b)}
    s = _settings(b)
    hz = re.search(r"(\d+) s at\s+(\d+) Hz", b.text("topology.md"))
    rate = hz.group(2) if hz else "100"
    preset = re.search(r"`([\w-]+)` IMU preset", b.text("topology.md"))
    if preset is None:
        raise ValueError("topology.md: IMU preset not found")
    frobot, ftarget = TOPOLOGY_FAST_TARGET_S
    nrobot, ntarget = TOPOLOGY_NETWORK_TARGET_S
    fast_s, net_s = rows[frobot]["fast"]["seconds"], rows[nrobot]["network"]["seconds"]
    return (
        f"Measured with {b.provenance('topology')}: every catalog robot, `{preset.group(1)}` IMU model "
        f"(bias, scale, cross-axis, noise), {s['seconds']} s at {rate} Hz, {s['seeds']} seeds, {s['epochs']} "
        f"training epochs, one uninterrupted run. *Exact* = every joint's parent and every IMU's joint "
        "equal the truth. CPU seconds are medians per run; the network and MLP costs are ratios to "
        f"`fast` on the same recordings in the same run. Targets: `fast` ≤ {ftarget:g} s for the "
        f"{frobot} ({'met' if fast_s <= ftarget else 'missed'}: {fast_s:.2f} s), `network` ≤ "
        f"{ntarget:g} s for `{nrobot}` ({'met' if net_s <= ntarget else 'missed'}: {net_s:.0f} s)."
    )


def _exact(m: dict) -> str:
    return f"{m['exact']}/{m['runs']}"


def _ratio(r: dict, method: str) -> float:
    return r[method]["seconds"] / r["fast"]["seconds"]


def _readme_table(b: BenchFiles) -> str:
    lines = [
        "| robot | joints | IMUs | `fast` exact | `network` exact | `network-paper` | `mlp` "
        "| shortest exact `fast` | `fast` CPU s | network CPU ×fast | mlp CPU ×fast |",
        "|---|---:|---:|---|---|---|---|---:|---:|---:|---:|",
    ]
    for r in _rows(b):
        lines.append(
            table_row(
                [
                    r["robot"],
                    r["joints"],
                    r["imus"],
                    _exact(r["fast"]),
                    _exact(r["network"]),
                    _exact(r["network-paper"]),
                    _exact(r["mlp"]),
                    f"{r['shortest']:g} s",
                    f"{r['fast']['seconds']:.2f}",
                    f"{_ratio(r, 'network'):.0f}× ({r['network']['seconds']:.0f} s)",
                    f"{_ratio(r, 'mlp'):.0f}×",
                ]
            )
        )
    return "\n".join(lines)


def _totals(rows: list[dict], method: str) -> str:
    return f"{sum(r[method]['exact'] for r in rows)}/{sum(r[method]['runs'] for r in rows)}"


def _weakest(rows: list[dict]) -> dict:
    return min(rows, key=lambda r: r["network"]["true_min"] - r["network"]["false_max"])


def _margins(b: BenchFiles) -> str:
    rows = _rows(b)
    weak = _weakest(rows)
    others = [r for r in rows if r is not weak]
    wrong = weak["network"]["wrong"]
    seeds = [str(i) for i, w in enumerate(wrong) if w]
    repaired = (
        f" (seed {', '.join(seeds)}, where the correction repairs the {sum(wrong)} wrong entries)"
        if seeds
        else ""
    )
    paper = [r["network-paper"]["true_min"] for r in rows]
    fast, net = _totals(rows, "fast"), _totals(rows, "network")
    exact = (
        f"`fast` and `network` are exact in {fast} runs each."
        if fast == net
        else f"`fast` is exact in {fast} runs, `network` in {net}."
    )
    return (
        f"{exact} The weakest margin is the {weak['robot']}'s: its smallest true dependency feature is "
        f"{weak['network']['true_min']:.3f} against a largest false one of "
        f"{weak['network']['false_max']:.3f}{repaired}; on every other robot true features are ≥ "
        f"{min(r['network']['true_min'] for r in others):.2f} and false ones ≤ "
        f"{max(r['network']['false_max'] for r in others):.2f}. The paper's variance statistic "
        f"(`network-paper`) scores {_totals(rows, 'network-paper')}, with a smallest true feature of "
        f"0.000 on {sum(f'{x:.3f}' == '0.000' for x in paper)} of {len(rows)} robots and at most "
        f"{max(paper):.3f} on the others."
    )


def readme(b: BenchFiles) -> str:
    return "\n\n".join([_setup(b), _readme_table(b), _margins(b)])


def network_cost(b: BenchFiles) -> str:
    rows = _rows(b)
    s = _settings(b)
    big = [r for r in rows if r["robot"].startswith("paper-") or r["robot"] == "humanoid"]
    ur = next(r for r in rows if r["robot"] == "ur5e")
    return (
        f"About {span([r['network']['seconds'] / r['imus'] for r in big], '.1f')} CPU s per IMU per "
        f"{s['seconds']} s recording at {s['epochs']} epochs on the paper robots and the humanoid, from "
        f"the table above; small robots pay more per IMU for each step's fixed cost (ur5e: "
        f"{ur['network']['seconds']:.0f} s for {ur['imus']} IMUs; {b.provenance('topology')})."
    )


def doc(b: BenchFiles) -> str:
    lines = [
        f"Measured with {b.provenance('topology')}:",
        "",
        "| robot | fast exact | fast CPU s | shortest exact fast | network exact | network CPU s (×fast) "
        "| smallest true / largest false feature | network-paper | mlp |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in _rows(b):
        lines.append(
            table_row(
                [
                    r["robot"],
                    _exact(r["fast"]),
                    f"{r['fast']['seconds']:.2f}",
                    f"{r['shortest']:g} s",
                    _exact(r["network"]),
                    f"{r['network']['seconds']:.0f} ({_ratio(r, 'network'):.0f}×)",
                    f"{r['network']['true_min']:.3f} / {r['network']['false_max']:.3f}",
                    _exact(r["network-paper"]),
                    _exact(r["mlp"]),
                ]
            )
        )
    return "\n".join(lines)


def fast_shortest(b: BenchFiles) -> str:
    rows = _rows(b)
    seeds = _settings(b)["seeds"]
    all_exact = all(r["fast"]["exact"] == r["fast"]["runs"] for r in rows)
    return (
        f"On the catalog robots with observable excitation `fast` is exact on "
        f"{'all' if all_exact else 'not all'} {seeds} seeds from "
        f"{span([r['shortest'] for r in rows], 'g')} s of data ({b.provenance('topology')})."
    )


def network_paper(b: BenchFiles) -> str:
    rows = _rows(b)
    runs = sum(r["network-paper"]["runs"] for r in rows)
    exact = sum(r["network-paper"]["exact"] for r in rows)
    weak = _weakest(rows)
    return (
        f"In the benchmark ({b.provenance('topology')}) `network-paper` is exact in {exact} of the {runs} "
        "runs, with a smallest true feature of "
        f"{span([r['network-paper']['true_min'] for r in rows], '.3f')}; "
        f"`network`'s thinnest margin is the {weak['robot']}'s (smallest true "
        f"{weak['network']['true_min']:.3f} against largest false {weak['network']['false_max']:.3f} over "
        f"{weak['network']['runs']} seeds)."
    )
