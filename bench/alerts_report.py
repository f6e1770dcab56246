"""The pure half of ``bodyhealth bench alerts``: alert timelines, false alerts, summaries and the report.

Nothing here talks to the service: the harness (:mod:`bench.alerts`) polls the alerts route and hands
each answer to :func:`update_first_seen`; what the alerts mean against the damages injected is decided
here, so it can be tested on constructed timelines.

Times are seconds since the service was started (the bench's monotonic clock), so one run's baseline,
injections, restart and alerts share one axis.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bench import fmt

__all__ = [
    "TARGETS",
    "AlertKey",
    "Injection",
    "classify",
    "command_text",
    "damage_latency",
    "first_seen",
    "key_str",
    "markdown",
    "parse_damage",
    "percentiles_ms",
    "plot",
    "service_percentiles",
    "summarize",
    "update_first_seen",
]

#: (robot, kind, part): what an alert is tracked under by the service (``part`` is ``imu:<name>`` or
#: ``joint:<name>``).
AlertKey = tuple[str, str, str]

#: The targets the bench reports against, in seconds: from the service's start to a baseline of every
#: robot; from an injection to its alert being seen pending, and active.
TARGETS: dict[str, float] = {"baseline_s": 180.0, "pending_s": 90.0, "active_s": 300.0}

#: The state an alert ends in; an alert first seen in any other state was raised (pending at the least).
RESOLVED = "resolved"


def key_str(key: AlertKey) -> str:
    """An alert key as one JSON-friendly string.

    >>> key_str(("ur5e-1", "joint_locked", "joint:wrist_2"))
    'ur5e-1 joint_locked joint:wrist_2'
    """
    return " ".join(key)


def update_first_seen(
    seen: dict[AlertKey, dict[str, float]],
    t: float,
    alerts: Iterable[Mapping],
    details: dict[AlertKey, dict[str, Any]] | None = None,
) -> None:
    """Record in ``seen`` the first time ``t`` each (robot, kind, part) is seen in each state.

    States are taken as the route names them (``pending``, ``active``, ``resolved`` or any the service
    adds), so a new state shows up in the results without a change here. Where an alert says whether
    the sensor networks confirmed it (``confirmed`` true or false), that is kept too, as ``STATE
    confirmed`` or ``STATE unconfirmed`` beside the plain state. ``details`` keeps each key's finding
    and note as first seen (what a false alert is read back from once the service's data is gone).
    """
    for a in alerts:
        key = (str(a["robot"]), str(a["kind"]), str(a["part"]))
        if details is not None and key not in details:
            details[key] = {"finding": a.get("finding"), "note": a.get("note", "")}
        states = seen.setdefault(key, {})
        state = str(a["state"])
        states.setdefault(state, float(t))
        if a.get("confirmed") is not None:
            states.setdefault(f"{state} {'confirmed' if a['confirmed'] else 'unconfirmed'}", float(t))


def first_seen(polls: Iterable[tuple[float, Sequence[Mapping]]]) -> dict[AlertKey, dict[str, float]]:
    """First-seen time per key and state over a timeline of polls ``(t, alerts answered at t)``.

    >>> a = {"robot": "r", "kind": "imu_moved", "part": "imu:imu0"}
    >>> first_seen([(1.0, []), (2.0, [{**a, "state": "pending"}]), (4.0, [{**a, "state": "active"}]),
    ...             (6.0, [{**a, "state": "active"}])])
    {('r', 'imu_moved', 'imu:imu0'): {'pending': 2.0, 'active': 4.0}}
    """
    seen: dict[AlertKey, dict[str, float]] = {}
    for t, alerts in sorted(polls, key=lambda p: p[0]):
        update_first_seen(seen, t, alerts)
    return seen


def parse_damage(text: str) -> tuple[str, str, dict[str, Any]]:
    """``ROBOT:KIND[:key=value,...]`` as (robot, kind, params); numbers become floats.

    >>> parse_damage("quadruped-1:imu_rotated:imu=imu25,angle_deg=2")
    ('quadruped-1', 'imu_rotated', {'imu': 'imu25', 'angle_deg': 2.0})
    >>> parse_damage("ur5e-1")
    Traceback (most recent call last):
    ...
    ValueError: damage 'ur5e-1': expected ROBOT:KIND[:key=value,...]
    """
    parts = text.strip().split(":", 2)
    if len(parts) < 2 or not parts[0] or not parts[1]:
        raise ValueError(f"damage {text!r}: expected ROBOT:KIND[:key=value,...]")
    params: dict[str, Any] = {}
    for item in filter(None, (parts[2] if len(parts) == 3 else "").split(",")):
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ValueError(f"damage {text!r}: parameter {item!r} is not key=value")
        try:
            params[name] = float(value)
        except ValueError:
            params[name] = value
    return parts[0], parts[1], params


@dataclass(frozen=True)
class Injection:
    """One damage asked of the service: ``part`` and ``t`` are set when it was applied (201), else
    ``detail`` says why it was not (an unknown kind or parameter: not injectable)."""

    robot: str
    kind: str
    params: dict[str, Any]
    t: float | None = None
    part: str | None = None
    detail: str = ""

    @property
    def applied(self) -> bool:
        return self.t is not None and self.part is not None

    @property
    def key(self) -> AlertKey:
        return (self.robot, self.kind, self.part or "")


def _raised(states: Mapping[str, float]) -> float | None:
    """When an alert was first seen raised: in any state but resolved (an active one was pending
    before; the poll may have missed that)."""
    times = [t for s, t in states.items() if s != RESOLVED]
    return min(times) if times else None


def damage_latency(seen: Mapping[AlertKey, Mapping[str, float]], inj: Injection) -> dict[str, Any]:
    """Seconds from ``inj`` to its alert seen raised (``pending_s``) and active (``active_s``), None
    when not seen; ``states``: every state seen, seconds after the injection.

    >>> inj = Injection("r", "imu_moved", {}, t=10.0, part="imu:imu0")
    >>> damage_latency({("r", "imu_moved", "imu:imu0"): {"active": 50.0}}, inj)
    {'pending_s': 40.0, 'active_s': 40.0, 'states': {'active': 40.0}}
    """
    if not inj.applied:
        return {"pending_s": None, "active_s": None, "states": {}}
    assert inj.t is not None
    states = {s: t - inj.t for s, t in seen.get(inj.key, {}).items() if t >= inj.t}
    raised = _raised(states)
    return {"pending_s": raised, "active_s": states.get("active"), "states": states}


def classify(
    seen: Mapping[AlertKey, Mapping[str, float]],
    injections: Sequence[Injection],
    restart_t: float | None = None,
    details: Mapping[AlertKey, Mapping[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """Every false alert: one whose (robot, kind, part) is no damage applied, or that was raised
    before its damage was. ``phase``: ``healthy`` before the first injection, else ``damaged``;
    ``after_restart`` when first raised after the restart at ``restart_t``; its finding and note as
    first seen, from ``details`` (:func:`update_first_seen`), where given.

    >>> inj = [Injection("r", "imu_moved", {}, t=100.0, part="imu:imu0")]
    >>> seen = {("r", "imu_moved", "imu:imu0"): {"pending": 120.0},
    ...         ("r", "imu_dead", "imu:imu3"): {"pending": 40.0, "resolved": 50.0}}
    >>> [(f["kind"], f["phase"], f["became_active"]) for f in classify(seen, inj)]
    [('imu_dead', 'healthy', False)]
    >>> said = {("r", "imu_dead", "imu:imu3"): {"finding": {"detail": "zero"}, "note": ""}}
    >>> classify(seen, inj, details=said)[0]["finding"]
    {'detail': 'zero'}
    """
    applied = [i for i in injections if i.applied]
    first_injection = min((i.t for i in applied if i.t is not None), default=None)
    out = []
    for key, states in sorted(seen.items()):
        t = _raised(states)
        if t is None:  # seen resolved only: raised and cleared between two polls, or before the bench
            t = min(states.values())
        if any(i.key == key and i.t is not None and i.t <= t for i in applied):
            continue
        out.append(
            {
                "robot": key[0],
                "kind": key[1],
                "part": key[2],
                "first_s": t,
                "states": dict(states),
                "became_active": "active" in states,
                "phase": "healthy" if first_injection is None or t < first_injection else "damaged",
                "after_restart": restart_t is not None and t >= restart_t,
            }
            | dict((details or {}).get(key, {}))
        )
    return out


def percentiles_ms(seconds: Sequence[float]) -> dict[str, float | int | None]:
    """n, p50, p99 and max of request latencies given in seconds, in ms (linear interpolation; with
    few requests p99 is close to the largest).

    >>> percentiles_ms([0.01, 0.02, 0.03])
    {'n': 3, 'p50_ms': 20.0, 'p99_ms': 29.8, 'max_ms': 30.0}
    """
    if not seconds:
        return {"n": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}
    ms = sorted(1000.0 * s for s in seconds)

    def q(p: float) -> float:
        x = p * (len(ms) - 1)
        lo = int(x)
        hi = min(lo + 1, len(ms) - 1)
        return round(ms[lo] + (ms[hi] - ms[lo]) * (x - lo), 3)

    return {"n": len(ms), "p50_ms": q(0.5), "p99_ms": q(0.99), "max_ms": round(ms[-1], 3)}


def _metric(values: Sequence[float | None], target: float | None) -> dict[str, Any]:
    got = [v for v in values if v is not None]
    worst = max(got) if got else None
    missed = len(values) - len(got)
    return {
        "values": list(values),
        "max": worst,
        "median": statistics.median(got) if got else None,
        "missed": missed,
        "target": target,
        "met": None if target is None else (missed == 0 and worst is not None and worst <= target),
    }


def service_percentiles(phase: Mapping[str, Any]) -> dict[str, float | int | None]:
    """:func:`percentiles_ms` of the service's own time (its ``Server-Timing``) for a phase's
    approvals, from each approval's row where the bench kept it (n 0 where it did not).

    >>> service_percentiles({"each": [[10.0, "ur5e-1", 40.0, 12.0], [12.0, "ur5e-1", 30.0, None]]})
    {'n': 1, 'p50_ms': 12.0, 'p99_ms': 12.0, 'max_ms': 12.0}
    """
    ms = [row[3] for row in phase.get("each", []) if len(row) > 3 and row[3] is not None]
    return percentiles_ms([m / 1e3 for m in ms])


def summarize(runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per metric over the runs: every run's value, max, median, how many runs missed it (no value
    within the bench's limit) and whether every run met its target. False alerts have target 0.

    >>> runs = [{"baseline_s": 100.0, "damages": [{"kind": "imu_moved", "pending_s": 30.0,
    ...          "active_s": 60.0}], "false_alerts": [], "approvals": {}},
    ...         {"baseline_s": None, "damages": [], "false_alerts": [{}], "approvals": {}}]
    >>> s = summarize(runs)
    >>> s["baseline_s"]["max"], s["baseline_s"]["missed"], s["baseline_s"]["met"]
    (100.0, 1, False)
    >>> s["false_alerts"]["values"], s["false_alerts"]["met"]
    ([0, 1], False)
    >>> s["imu_moved active_s"]["values"], s["imu_moved active_s"]["met"]
    ([60.0, None], False)
    """
    out = {"baseline_s": _metric([r.get("baseline_s") for r in runs], TARGETS["baseline_s"])}
    kinds = list(dict.fromkeys(d["kind"] for r in runs for d in r.get("damages", []) if "kind" in d))
    for kind in kinds:
        for what in ("pending_s", "active_s"):
            values = []
            for r in runs:
                hit = [d for d in r.get("damages", []) if d.get("kind") == kind]
                values.append(hit[0].get(what) if hit else None)
            out[f"{kind} {what}"] = _metric(values, TARGETS[what])
    false = _metric([len(r.get("false_alerts", [])) for r in runs], 0.0)
    out["false_alerts"] = false
    for phase in ("quiet", "flood"):
        for q in ("p50_ms", "p99_ms"):
            values = [r.get("approvals", {}).get(phase, {}).get(q) for r in runs]
            if any(v is not None for v in values):
                out[f"approval {phase} {q}"] = _metric(values, None)
            values = [service_percentiles(r.get("approvals", {}).get(phase, {}))[q] for r in runs]
            if any(v is not None for v in values):
                out[f"service's own {phase} {q}"] = _metric(values, None)
    return out


def _cell(m: Mapping[str, Any], spec: str) -> str:
    return fmt(m.get("max"), spec) + (f" ({m['missed']} missed)" if m.get("missed") else "")


def command_text(data: Mapping[str, Any]) -> str:
    """The run's command in backticks, followed by the service settings its environment set (a run at
    another setting than the defaults says so wherever its command is quoted)."""
    env = " ".join(f"{k}={v}" for k, v in sorted(data.get("settings_from_environment", {}).items()))
    return f"`{data['command']}`" + (f" with `{env}`" if env else "")


def markdown(data: Mapping[str, Any]) -> str:
    """The report ``docs/bench/alerts.md``: targets and summary first, then each run."""
    o = data["options"]
    approver = data.get("approvals_from")
    lines = [
        "# Benchmark: alerts in time on a busy machine",
        "",
        command_text(data),
        "",
        f"Machine: {data['machine']}; {o['busy']} busy-loop processes pinned one per core beside the "
        f"service for the whole run; load average {fmt(data['load_before'], '.2f')} before the first "
        f"run. The demo (`bodyhealth serve --demo`, speed {o['speed']:g}x, its own SQLite file) runs as "
        "a process of its own; this process polls the alerts route every "
        f"{o['poll_seconds']:g} s (times are when a poll first saw a state: up to one poll interval "
        "plus the API's read cache late)."
        + (f" Approvals are sent and timed by {approver}." if approver else ""),
        "",
    ]
    if data.get("note"):
        lines += [f"**{data['note']}**", ""]
    lines += [
        "| metric | target | max | median | runs | met |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for name, m in data["summary"].items():
        spec = ".0f" if name == "false_alerts" else ".1f"
        met = "—" if m["met"] is None else ("yes" if m["met"] else "**no**")
        lines.append(
            f"| {name} | {fmt(m['target'], '.0f')} | {_cell(m, spec)} | {fmt(m['median'], spec)} "
            f"| {len(m['values'])} | {met} |"
        )
    lines += [
        "",
        "Pending: the alert first seen raised (pending, or already active when a poll missed the "
        "pending state). Active: first seen `active`. A missed value is none within the bench's limit "
        "and fails its target.",
        "",
    ]
    for r in data["runs"]:
        lines += _run_lines(r)
    lines += [
        f"![Baseline and alert times per run against the targets]({data.get('name', 'alerts')}.png)",
        "",
    ]
    return "\n".join(lines)


def _lock_log_line(
    r: Mapping[str, Any], key: str, what: str, ms: str, describe: Callable[[Mapping[str, Any]], str]
) -> str:
    """One line on the service's logged ``key`` (``write_waits`` or ``slow_holds``: writes that
    ``what``): how many, the approvals among them, and the longest by ``ms``, which
    ``describe`` says more of ("" for a run recorded before they were kept)."""
    logged = r.get(key)
    if logged is None:
        return ""
    if not logged:
        return f"No write {what}."
    approvals = sum("approve_baseline" in (x.get("writer") or "") for x in logged)
    top = max(logged, key=lambda x: x.get(ms) or 0)
    return (
        f"Writes that {what}: {len(logged)} ({approvals} approvals); the longest "
        f"{fmt(top.get(ms), '.0f')} ms, {describe(top)}."
    )


def _write_waits_line(r: Mapping[str, Any]) -> str:
    """The service's waits for the store's write lock over 100 ms, the longest with the writer it
    waited behind."""
    return _lock_log_line(
        r,
        "write_waits",
        "waited over 100 ms for the store's lock",
        "waited_ms",
        lambda w: f"{w.get('writer')} behind {w.get('behind')}",
    )


def _slow_holds_line(r: Mapping[str, Any]) -> str:
    """The service's holds of the store's write lock over 100 ms, the longest with its commit's share,
    its thread's and its process's CPU and the WAL it committed onto."""

    def describe(h: Mapping[str, Any]) -> str:
        commit, cpu, pcpu = (fmt(h.get(k), ".0f") for k in ("commit_ms", "cpu_ms", "process_cpu_ms"))
        wal = fmt((h.get("wal_bytes") or 0) / 2**20, ".1f")
        return (
            f"{h.get('writer')}: commit {commit} ms, CPU {cpu} ms (the process's {pcpu} ms), WAL {wal} MiB "
            "when it committed"
        )

    return _lock_log_line(r, "slow_holds", "held the store's lock over 100 ms", "held_ms", describe)


def _run_lines(r: Mapping[str, Any]) -> list[str]:
    lines = [
        f"## Run {r['run']}",
        "",
        f"Load average {fmt(r['load_before'], '.2f')} at the start, {fmt(r['load_after'], '.2f')} at the "
        f"end; {r['polls']} alert polls ({r['poll_errors']} failed); `WindowGone` in the service's log: "
        f"{r.get('window_gone', '—')}. {_write_waits_line(r)} {_slow_holds_line(r)}".rstrip(),
        "",
        "Baseline: "
        + ", ".join(_baseline_item(r, k, v) for k, v in r["baselines"].items())
        + f"; all robots: {fmt(r['baseline_s'], '.0f')} s (limit {r['baseline_limit_s']:.0f} s).",
        "",
        "| damage | part | injected at | pending after, s | active after, s | states seen (s after) |",
        "|---|---|---:|---:|---:|---|",
    ]
    for d in r["damages"]:
        states = ", ".join(f"{s} {t:.0f} s" for s, t in d.get("states", {}).items()) or d.get("detail", "")
        lines.append(
            f"| {d['robot']} {d['kind']} | {d.get('part') or '—'} | {fmt(d.get('t_s'), '.0f')} s "
            f"| {fmt(d.get('pending_s'), '.0f')} | {fmt(d.get('active_s'), '.0f')} | {states} |"
        )
    false = r["false_alerts"]
    if r["damages"]:
        lines += ["", f"Alerts were waited for up to {r['alert_limit_s']:.0f} s after the injections."]
    lines += [
        "",
        f"False alerts: {len(false)} ({sum(f['became_active'] for f in false)} became active; "
        f"{sum(f['after_restart'] for f in false)} after the restart)"
        + "".join(_false_item(f) for f in false)
        + ".",
        "",
    ]
    if r.get("restart"):
        rs = r["restart"]
        lines += [
            f"Restart at {rs['t_s']:.0f} s: SIGTERM answered with exit code {rs['exit_code']} after "
            f"{fmt(rs['stop_s'], '.1f')} s; answering again {fmt(rs['down_s'], '.1f')} s after the SIGTERM.",
            "",
        ]
    ap, fl = r["approvals"], r["flood"]
    lines += [
        "| baseline approvals | n | p50 | p99 | max | statuses | the service's own p50 / p99 |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    for phase in ("quiet", "flood"):
        a = ap.get(phase, {})
        own = service_percentiles(a)
        lines.append(
            f"| {phase} | {a.get('n', 0)} | {fmt(a.get('p50_ms'), '.0f')} ms "
            f"| {fmt(a.get('p99_ms'), '.0f')} ms | {fmt(a.get('max_ms'), '.0f')} ms "
            f"| {_statuses(a.get('statuses', {}))} "
            f"| {fmt(own['p50_ms'], '.0f')} / {fmt(own['p99_ms'], '.0f')} ms |"
        )
    lines += [
        "",
        f"Retrain flood: {fl.get('requests', 0)} POST retrain requests at {fl.get('rps', 0):g}/s; "
        f"statuses {_statuses(fl.get('statuses', {}))}; Retry-After {fl.get('retry_after', '—')}.",
        "",
    ]
    lines += [f"- {' '.join(n.split())[:500]}" for n in r.get("notes", [])] + ([""] if r.get("notes") else [])
    return lines


def _baseline_item(r: Mapping[str, Any], robot: str, t: float | None) -> str:
    source = r.get("baseline_sources", {}).get(robot)
    return f"{robot} {fmt(t, '.0f')} s" + (f" ({source})" if source else "")


def _false_item(f: Mapping[str, Any]) -> str:
    detail = (f.get("finding") or {}).get("detail")
    said = f', "{detail}"' if detail else ""
    return f"; {f['robot']} {f['kind']} {f['part']} at {f['first_s']:.0f} s ({f['phase']}{said})"


def _statuses(counts: Mapping[str, int]) -> str:
    return ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())) or "—"


def plot(path: Any, data: Mapping[str, Any]) -> None:
    """Per run, a timeline: each robot's baseline after the service's start (left) and each damage's
    pending and active alert after its injection (right), against the targets; a miss is drawn as a
    cross at the limit the bench waited."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.figures import save_figure

    runs = data["runs"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 1.8 + 0.7 * max(1, len(runs))), sharey=True)
    for y, r in enumerate(runs):
        for k, (name, t) in enumerate(r["baselines"].items()):
            x = r["baseline_limit_s"] if t is None else t
            left.plot([x], [y], "x" if t is None else "o", color="k" if t is None else "tab:blue", ms=4)
            left.annotate(name, (x, y), fontsize=6, xytext=(2, 4 + 7 * k), textcoords="offset points")
        for d, dy in zip(r["damages"], (-0.2, 0.0, 0.2, 0.3, -0.3, 0.1), strict=False):
            limit = r.get("alert_limit_s", TARGETS["active_s"])
            for what, marker, color in (("pending_s", "o", "tab:orange"), ("active_s", "s", "tab:red")):
                t = d.get(what)
                if d.get("part") is None:
                    continue
                right.plot([limit if t is None else t], [y + dy], "x" if t is None else marker, color=color)
            right.annotate(f"{d['kind']}", (0, y + dy), fontsize=6, xytext=(2, 2), textcoords="offset points")
    left.axvline(TARGETS["baseline_s"], color="tab:blue", ls="--", lw=1, label="baseline target")
    right.axvline(TARGETS["pending_s"], color="tab:orange", ls="--", lw=1, label="pending target")
    right.axvline(TARGETS["active_s"], color="tab:red", ls="--", lw=1, label="active target")
    right.plot([], [], "o", color="tab:orange", label="pending seen")
    right.plot([], [], "s", color="tab:red", label="active seen")
    right.plot([], [], "kx", label="missed (at the limit)")
    left.set_yticks(range(len(runs)), [f"run {r['run']}" for r in runs])
    left.set_ylim(-0.6, len(runs) - 0.4)
    left.set_xlabel("s from the service's start to each robot's baseline")
    right.set_xlabel("s from injection to the alert")
    left.legend(fontsize=7, loc="lower right")
    right.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"bench alerts: {data['options']['busy']} busy loops; {data['machine']}", fontsize=8)
    save_figure(fig, path)
