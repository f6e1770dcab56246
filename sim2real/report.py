"""Sim-to-real output: the fitted IMU model in the simulator's format, transfer checks, plots, reports.

* :func:`to_imu_model` turns fitted effect parameters into a :class:`simulators.imu_model.ImuModel`
  (``bodyhealth simulate --imu-model fitted.json`` then simulates with it);
* :func:`simulate_readings` runs the simulator's IMU forward model on the ideal readings of a
  recording's reference motion — "simulate the measured motion";
* :func:`transfer` is the end-to-end figure of merit: how much closer to a *different* measured
  recording the fitted model's simulation is than the default model's;
* :func:`write_report` writes the discrepancy JSON, the fitted model, a Markdown summary and PNG plots;
* :func:`write_gravity_case` does the same for the robot gravity case (sensor networks without and with
  gravity, :mod:`bodyschema.discrepancy.network_gravity`).

The measured data this was built on is BROAD (Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark for
Robust Inertial Orientation Estimation", Data 6(7), 2021, CC BY 4.0); reports on it carry the
attribution.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bodyschema.discrepancy import DiscrepancyReport, Params, Problem, prepare
from bodyschema.imu_effects import rotation_matrix, specific_force
from bodyschema.recording import Recording
from bodyschema.rigid_motion import ReferenceMotion
from sim2real.broad import BROAD_ATTRIBUTION
from sim2real.figures import save_figure
from simulators.imu_model import ImuModel, distort, resolve_imu_model, save_imu_model

if TYPE_CHECKING:
    from bodyschema.discrepancy.network_gravity import GravityCase

__all__ = [
    "format_gravity_case",
    "format_joint",
    "format_not_named",
    "format_summary",
    "plot_gravity_case",
    "plot_residuals",
    "plot_structure",
    "robot_references",
    "simulate_readings",
    "to_imu_model",
    "transfer",
    "transfer_problem",
    "write_gravity_case",
    "write_report",
]


def to_imu_model(params: Params, name: str = "fitted") -> ImuModel:
    """Fitted effects as a fixed simulator IMU model (effects absent from ``params`` stay ideal).

    The simulator applies the lever arm *before* the mounting rotation, i.e. in the nominal frame;
    the analysis fits it in the rotated sensor frame, so it is rotated here: ``r_nominal = R r_sensor``.
    Noise is written as a density (``std / sqrt(rate)``), which holds at any simulation rate.

    >>> m = to_imu_model({"time_offset": {"seconds": 0.004}, "lever_arm": {"meters": [0.0, 0.0, 0.01]}})
    >>> [e for e, _ in m.effects]
    ['lever_arm', 'time_offset']
    """
    effects: list[tuple[str, dict[str, Any]]] = []
    if "gravity" in params:
        effects.append(("gravity", {"vector": list(params["gravity"]["vector"])}))
    if "lever_arm" in params:
        r = np.asarray(params["lever_arm"]["meters"], dtype=np.float64)
        if "mounting_rotation" in params:
            r = rotation_matrix(params["mounting_rotation"]["rotvec"]) @ r
        effects.append(("lever_arm", {"meters": r.tolist()}))
    for eff in ("mounting_rotation", "gyro_scale", "acc_scale", "gyro_bias", "acc_bias", "time_offset"):
        if eff in params:
            effects.append((eff, {k: v for k, v in params[eff].items()}))
    if "noise" in params:
        n = params["noise"]
        effects.append(
            ("noise", {"gyro_density": list(n["gyro_density"]), "acc_density": list(n["acc_density"])})
        )
    return ImuModel(name=name, effects=tuple(effects))


def _ideal(ref: ReferenceMotion) -> tuple[np.ndarray, np.ndarray]:
    return ref.omega, specific_force(ref.R, ref.acc_world, ref.gravity)


def simulate_readings(
    ref: ReferenceMotion, model: ImuModel | str, rng: np.random.Generator | None = None, noise: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro, acc)`` (T, 3): the simulator's IMU model applied to the ideal readings of ``ref``.

    Random effects of a preset are drawn with ``rng`` (default seed 0); ``noise=False`` leaves out the
    white noise and quantisation (the expected reading, what a comparison with low-passed data needs).
    """
    m = resolve_imu_model(model) if isinstance(model, str) else model
    p = m.instantiate(("imu0",), rng if rng is not None else np.random.default_rng(0))
    gyro, acc = _ideal(ref)
    a, g = distort(
        p,
        ref.t,
        acc[:, None, :],
        gyro[:, None, :],
        R=ref.R[:, None, :, :],
        world_gravity=ref.gravity,
    )
    if noise:
        from simulators.imu_model import finish

        rate = float(1.0 / np.median(np.diff(ref.t)))
        a, g = finish(p, a, g, rate, rng if rng is not None else np.random.default_rng(0))
    return g[:, 0], a[:, 0]


def transfer_problem(
    rec: Recording, cutoff: float | None = 10.0, analysis_rate: float | None = None, imu: int = 0
) -> Problem:
    """The prepared comparison data of a recording for :func:`transfer` (reuse it for many models).

    At the recorded rate by default: the simulator shifts time by linear interpolation, which a
    coarse grid would blur.
    """
    from bodyschema.discrepancy import reference_of

    ref = reference_of(rec, cutoff)
    return prepare(ref, rec.gyro[:, imu], rec.acc[:, imu], rec.extra.get("ref_valid"), cutoff, analysis_rate)


def transfer(
    rec: Recording | Problem,
    model: ImuModel | str,
    default: ImuModel | str = "ideal",
    cutoff: float | None = 10.0,
    imu: int = 0,
) -> dict[str, float]:
    """Figure of merit: the fitted model's simulation against a measured recording, vs the default's.

    Both simulations and the measurement are low-passed alike and compared on the samples with a
    valid reference. ``score`` is the mean over the two channels of MSE(model) / MSE(default): below
    1 the model simulates this recording better than the default; ``gain = 1 - score``. ``rec`` may
    be a :func:`transfer_problem` already prepared.
    """
    prob = rec if isinstance(rec, Problem) else transfer_problem(rec, cutoff, imu=imu)
    out: dict[str, float] = {}
    mse = {}
    for tag, m in (("default", default), ("model", model)):
        g, a = simulate_readings(prob.ref, m)
        mse[tag] = (
            float(np.mean((prob.gyro - g)[prob.index] ** 2)),
            float(np.mean((prob.acc - a)[prob.index] ** 2)),
        )
        out[f"gyro_rms_{tag}"] = float(np.sqrt(mse[tag][0]))
        out[f"acc_rms_{tag}"] = float(np.sqrt(mse[tag][1]))
    ratios = [mse["model"][c] / max(mse["default"][c], 1e-300) for c in (0, 1)]
    score = 0.5 * (ratios[0] + ratios[1])
    out["score"] = score
    out["gain"] = 1.0 - score
    return out


def robot_references(rec: Recording, robot: str, cutoff: float | None = 10.0) -> dict[str, ReferenceMotion]:
    """The reference motion of every IMU site of ``robot`` (catalog name or MJCF file) driven by ``rec.q``.

    With joint velocities ``qd`` in the recording, each site's angular velocity and acceleration come
    from the site Jacobians (``mj_jacSite``, ``mj_jacDot``) and the joint accelerations: the recorded
    ``qdd`` when there is one (the simulator records the acceleration its physics realises over each
    sample's first step, with which its accelerometers agree, so an ideal simulated IMU then matches
    to rounding), else the forward difference of ``qd`` — the mean acceleration over the interval
    that starts at each sample (the same at one physics step per sample). Without ``qd``, orientations
    and positions from forward kinematics are differentiated by splines (poor under torques that switch
    between samples).
    Needs a fixed base (a floating base's pose is not in ``q``) and the recording's joints in the model.
    """
    import mujoco
    from scipy.spatial.transform import Rotation

    from bodyschema.rigid_motion import lowpass, reference_motion
    from simulators.robot import Robot

    if rec.q is None:
        raise ValueError("the recording has no joint positions q")
    bot = Robot.from_file(robot) if os.path.exists(robot) else Robot.from_catalog(robot)
    m = bot.model
    if np.any(m.jnt_type == mujoco.mjtJoint.mjJNT_FREE):
        raise ValueError(f"{robot}: a floating base's pose is not in q; fixed-base robots only")
    missing = [j for j in rec.joint_names if j not in bot.joint_names]
    if missing:
        raise ValueError(f"joints {missing} of the recording are not in {robot} ({list(bot.joint_names)})")
    d = mujoco.MjData(m)
    d.qpos[:] = bot.data.qpos
    j = [bot.joint_names.index(n) for n in rec.joint_names]
    adr, dof = bot.qpos_adr[j], bot.dof_adr[j]
    T, K = rec.n_samples, len(bot.imu_names)
    R = np.empty((T, K, 3, 3))
    P = np.empty((T, K, 3))
    W = np.zeros((T, K, 3))
    A = np.zeros((T, K, 3))
    qd = rec.qd
    qdd = rec.qdd
    if qd is not None and qdd is None:
        qdd = np.zeros_like(qd)
        qdd[:-1] = np.diff(qd, axis=0) / np.diff(rec.t)[:, None]
        qdd[-1] = qdd[-2]
    jacp, jacr, jdot = np.zeros((3, m.nv)), np.zeros((3, m.nv)), np.zeros((3, m.nv))
    v, a = np.zeros(m.nv), np.zeros(m.nv)
    for i in range(T):  # one kinematics pass per sample; MuJoCo has no batched call for it
        d.qpos[adr] = rec.q[i]
        if qd is None:
            mujoco.mj_kinematics(m, d)
        else:
            v[dof], a[dof] = qd[i], qdd[i]  # type: ignore[index]
            d.qvel[:] = v
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
        R[i] = d.site_xmat[bot.site_ids].reshape(K, 3, 3)
        P[i] = d.site_xpos[bot.site_ids]
        if qd is not None:
            for k, s in enumerate(bot.site_ids):
                mujoco.mj_jacSite(m, d, jacp, jacr, int(s))
                mujoco.mj_jacDot(m, d, jdot, None, d.site_xpos[s], int(m.site_bodyid[s]))
                W[i, k] = jacr @ v
                A[i, k] = jacp @ a + jdot @ v
    gravity = np.asarray(m.opt.gravity, dtype=np.float64)
    rate = float(1.0 / np.median(np.diff(rec.t)))
    out = {}
    for k, name in enumerate(bot.imu_names):
        if qd is None:
            quat = Rotation.from_matrix(R[:, k]).as_quat(scalar_first=True)
            out[name] = reference_motion(rec.t, quat, P[:, k], gravity, cutoff)
        else:
            omega = np.einsum("tji,tj->ti", R[:, k], W[:, k])
            out[name] = ReferenceMotion(
                rec.t, R[:, k], lowpass(omega, rate, cutoff), lowpass(A[:, k], rate, cutoff), gravity
            )
    return out


# ----------------------------------------------------------------------------------------- text
def _fmt_params(effect: str, params: dict[str, Any]) -> str:
    parts = []
    for k, v in params.items():
        if k == "rate_hz":
            continue
        arr = np.atleast_1d(np.asarray(v, dtype=np.float64))
        if effect == "time_offset":
            parts.append(f"{arr[0] * 1e3:.2f} ms")
        elif effect == "mounting_rotation":
            axis = np.round(arr / max(np.linalg.norm(arr), 1e-12), 2).tolist()
            parts.append(f"{np.degrees(np.linalg.norm(arr)):.2f}° about {axis}")
        elif effect == "lever_arm":
            parts.append(f"[{', '.join(f'{x * 1e3:.1f}' for x in arr)}] mm")
        elif effect == "noise" and k == "std":
            g = ", ".join(f"{x:.3g}" for x in arr[:3])
            a = ", ".join(f"{x:.3g}" for x in arr[3:])
            parts.append(f"std gyro [{g}] rad/s, acc [{a}] m/s²")
        elif effect == "noise":
            continue
        else:
            parts.append(f"{k} [{', '.join(f'{x:.4g}' for x in arr)}]")
    return "; ".join(parts)


def format_summary(report: DiscrepancyReport) -> str:
    """A human-readable summary: residuals before/after and the causes in order."""
    b, a, h = report.residual_before, report.residual_after, report.held_out
    lines = [
        f"residual before: gyro {b['gyro_rms']:.4f} rad/s, acc {b['acc_rms']:.4f} m/s²",
        f"residual after:  gyro {a['gyro_rms']:.4f} rad/s, acc {a['acc_rms']:.4f} m/s²",
        f"held-out ({h['blocks']} blocks): gyro {h['gyro_rms_before']:.4f} -> "
        f"{h['gyro_rms_after']:.4f} rad/s, "
        f"acc {h['acc_rms_before']:.4f} -> {h['acc_rms_after']:.4f} m/s², gain {h['gain']:.3f}",
        "causes:" if report.causes or report.joint else "causes: none (the model explains the data)",
    ]
    for i, c in enumerate(report.causes, 1):
        gain = f"gain {c.gain:.3f} (p={c.p_value:.2g})" if c.effect != "noise" else "no gain (white)"
        lines.append(f"  {i}. {c.effect}: {_fmt_params(c.effect, c.params)} — {gain}")
        if c.interval:
            lines.append("     95 % interval: " + ", ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in c.interval))
        lines.append(f"     signature: {c.signature}")
    lines += format_joint(report)
    lines += format_not_named(report)
    return "\n".join(lines)


def format_joint(report: DiscrepancyReport) -> list[str]:
    """The effects named jointly: this recording fixes their joint value, not the split.

    >>> from bodyschema.discrepancy.report import JointCause
    >>> j = JointCause(("acc_bias", "gravity"), ("acc_bias",), {"vector": [0.1, 0.0, 0.0]}, {},
    ...                [[0.09, 0.11], [-0.01, 0.01], [-0.01, 0.01]], 0.99, 0.42, {}, "rotate the sensor")
    >>> format_joint(DiscrepancyReport({}, [], {}, {}, joint=[j]))[1]
    '  acc_bias or gravity: as acc_bias vector [0.1, 0, 0]'
    """
    if not report.joint:
        return []
    lines = ["named jointly (not separable on this recording):"]
    for j in report.joint:
        first = j.effects[0]
        lines.append(f"  {j.label}: as {first} {_fmt_params(first, j.params)}")
        if j.interval:
            lines.append("     95 % interval: " + ", ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in j.interval))
        lines.append(f"     signatures overlap: canonical correlation {j.correlation:.3f} > {j.cut:.3f}")
        lines.append(f"     would separate them: {j.separate_by}")
    return lines


def format_not_named(report: DiscrepancyReport) -> list[str]:
    """One line per library effect the analysis did not name: the smallest change this recording
    would reveal, and whether the data nonetheless ask for one (evidence above that limit that the
    held-out selection did not accept).

    >>> rep = DiscrepancyReport({}, [], {}, {}, evidence=[
    ...     {"effect": "gyro_bias", "channel": "gyro", "estimate": [0.001, 0.0, 0.0], "p_value": 0.4,
    ...      "detection_limit": 0.004}])
    >>> format_not_named(rep)
    ['not named:', '  gyro_bias: below 0.004 here (gyro; estimate 0.001, p=0.4)']
    """
    named = report.stated
    best: dict[str, dict[str, object]] = {}
    for ev in report.evidence:
        if ev["effect"] in named or ev["channel"] == "both":
            continue
        if ev["effect"] not in best or ev["detection_limit"] < best[ev["effect"]]["detection_limit"]:
            best[ev["effect"]] = ev
    if not best:
        return []
    lines = ["not named:"]
    for effect, ev in best.items():
        ask = float(np.linalg.norm(ev["estimate"]))
        # the change from the effect's null (a gain of 1, the standard gravity), in its own units
        limit, p = float(ev["detection_limit"]), float(ev["p_value"])
        if p >= float(ev.get("alpha", 0.01)):
            line = f"below {limit:.3g} here ({ev['channel']}; estimate {ask:.3g}, p={p:.2g})"
            lines.append(f"  {effect}: {line}")
        else:
            lines.append(
                f"  {effect}: the {ev['channel']} asks for {ask:.3g} (p={p:.2g}; limit {limit:.3g} here), "
                "too little held-out gain to name"
            )
    return lines


# ---------------------------------------------------------------------------------------- plots
def _residuals(report: DiscrepancyReport) -> tuple[Any, np.ndarray, np.ndarray]:
    from bodyschema.discrepancy.fit import residual

    prob = report.problem
    if prob is None:
        raise ValueError("the report carries no data to plot (problem is None)")
    before, _ = residual(prob, {})
    after, _ = residual(prob, {k: v for k, v in report.params.items() if k != "noise"})
    return prob, before, after


def _save_time_axes(fig: Any, axes: Any, path: str | os.PathLike[str], title: str) -> Path:
    """Finish a column of traces against time (legend on top, time label below) and save it."""
    for ax in axes:
        ax.tick_params(labelsize=7)
    axes[0].legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def plot_residuals(report: DiscrepancyReport, path: str | os.PathLike[str], title: str = "") -> Path:
    """Residuals per axis against time, before and after the fitted effects (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    prob, before, after = _residuals(report)
    t = prob.ref.t - prob.ref.t[0]
    mask = np.zeros(t.shape[0], dtype=bool)
    mask[prob.index] = True
    fig, axes = plt.subplots(6, 1, figsize=(11, 10), sharex=True)
    labels = ["gyro x", "gyro y", "gyro z", "acc x", "acc y", "acc z"]
    for i, ax in enumerate(axes):
        ax.plot(t, np.where(mask, before[:, i], np.nan), lw=0.5, color="tab:red", label="before (ideal)")
        ax.plot(t, np.where(mask, after[:, i], np.nan), lw=0.5, color="tab:blue", label="after (fitted)")
        ax.set_ylabel(f"{labels[i]}\n{'rad/s' if i < 3 else 'm/s²'}", fontsize=8)
    return _save_time_axes(fig, axes, path, title or "measured minus simulated IMU readings")


def plot_structure(report: DiscrepancyReport, path: str | os.PathLike[str], title: str = "") -> Path:
    """Residual structure before/after: R² per feature family and axis, and the residual spectra (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.signal import welch

    prob, before, after = _residuals(report)
    fig, axes = plt.subplots(2, 2, figsize=(12, 7))
    for row, (name, cols) in enumerate((("gyro", slice(0, 3)), ("acc", slice(3, 6)))):
        ax = axes[row, 0]
        fam = list(report.structure_before[name]["r2"])
        x = np.arange(len(fam))
        stages = (("before", report.structure_before), ("after", report.structure_after))
        for j, (tag, st) in enumerate(stages):
            r2 = np.array([st[name]["r2"][f] for f in fam])  # (families, 3)
            for ax_i in range(3):
                ax.bar(
                    x + (j * 3 + ax_i - 2.5) * 0.13,
                    r2[:, ax_i],
                    width=0.13,
                    color=("tab:red" if tag == "before" else "tab:blue"),
                    alpha=0.4 + 0.2 * ax_i,
                )
        ax.set_xticks(x, fam, rotation=20, fontsize=7)
        ax.set_ylim(0, 1)
        ax.set_ylabel(f"{name}: R² of residual (x,y,z)", fontsize=8)
        ax.set_title("red: before, blue: after", fontsize=8)
        ax = axes[row, 1]
        for tag, r, color in (("before", before, "tab:red"), ("after", after, "tab:blue")):
            nper = min(1024, prob.index.size)
            f, pxx = welch(r[prob.index][:, cols], fs=prob.rate, nperseg=nper, axis=0)
            ax.semilogy(f, pxx.sum(axis=1), color=color, label=tag)
        ax.set_xlabel("Hz", fontsize=8)
        ax.set_ylabel(f"{name} residual PSD", fontsize=8)
        ax.legend(fontsize=7)
    fig.suptitle(title or "residual structure", fontsize=10)
    return save_figure(fig, path)


# --------------------------------------------------------------------------------------- report
def _attribution(report: DiscrepancyReport) -> str | None:
    a = report.meta.get("attribution")
    if a:
        return str(a)
    if "BROAD" in str(report.meta.get("source", "")):
        return BROAD_ATTRIBUTION
    return None


def write_report(
    report: DiscrepancyReport,
    out_dir: str | os.PathLike[str],
    title: str = "",
    plots: bool = True,
    transfers: dict[str, dict[str, float]] | None = None,
) -> list[Path]:
    """Write ``discrepancy.json``, ``imu_model.json``, ``report.md`` and (``plots``) PNGs to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "discrepancy.json", out / "imu_model.json", out / "report.md"]
    data = report.to_json()
    if transfers:
        data["transfer"] = transfers
    files[0].write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    save_imu_model(to_imu_model(report.params, name=title or "fitted"), files[1])
    md = [f"# Sim-to-real report{': ' + title if title else ''}", ""]
    if report.meta.get("source"):
        md += [f"Data: {report.meta['source']}", ""]
    attribution = _attribution(report)
    if attribution:
        md += [f"Measured data: {attribution}", ""]
    md += ["```", format_summary(report), "```", ""]
    md += [
        "Gains are fractions of the ideal model's residual energy (gyro and accelerometer normalised "
        "alike), measured on held-out time blocks; each effect was accepted only when its held-out "
        "gain was significant over the blocks (one-sided t-test of log score ratios).",
        "",
    ]
    if transfers:
        md += [
            "## Transfer to other recordings",
            "",
            "| recording | gyro rms default -> fitted (rad/s) | acc rms default -> fitted (m/s²) | gain |",
            "|---|---|---|---|",
        ]
        for name, tr in transfers.items():
            md.append(
                f"| {name} | {tr['gyro_rms_default']:.4f} -> {tr['gyro_rms_model']:.4f} | "
                f"{tr['acc_rms_default']:.4f} -> {tr['acc_rms_model']:.4f} | {tr['gain']:.3f} |"
            )
        md.append("")
    if plots and report.problem is not None:
        files.append(plot_residuals(report, out / "residuals.png", title))
        files.append(plot_structure(report, out / "structure.png", title))
        md += ["![residuals before and after](residuals.png)", "", "![residual structure](structure.png)"]
    files[2].write_text("\n".join(md), encoding="utf-8")
    return files


# ----------------------------------------------------------------------------------- gravity case
def format_gravity_case(case: GravityCase) -> str:
    """The gravity case in a few lines: residuals and topology per form, then the named causes."""
    d = case.to_json()
    g = np.linalg.norm(case.gravity)
    lines = [f"sensor networks without gravity (Eq. 11) and with it (Eq. 24), recording |g| = {g:.2f} m/s²"]
    for form in ("eq11", "eq24"):
        f = d["forms"][form]
        acc = f["accuracy"]
        topo = "no ground truth"
        if acc:
            topo = (
                f"exact {acc['exact']}, joint parents {acc['joint_parent']:.2f}, "
                f"IMU joints {acc['imu_joint']:.2f}"
            )
        lines.append(
            f"  {form}: residual acc {f['acc_rms']:.4f} m/s², gyro {f['gyro_rms']:.4f} rad/s; topology {topo}"
        )
    gain = d["residual_gain"]
    lines.append(
        f"  Eq. 24 removes {gain['acc']:.1%} of the accelerometer and {gain['gyro']:.1%} of the "
        "gyro residual energy"
    )
    for name, an in case.analyses.items():
        lines.append(f"causes of the Eq. 11 residual on the {name} reference ({len(case.imus)} IMUs):")
        if not an.causes:
            lines.append("  none named on half of the IMUs")
        for c in an.causes:
            text = f"  {c['effect']}: {c['imus']}/{c['of']} IMUs, median held-out gain {c['median_gain']:.3f}"
            p = c.get("params")
            if p:
                lo, hi = p["norm_range"]
                text += f"; |g| {p['norm']:.2f} m/s² (range {lo:.2f}-{hi:.2f})"
                for k, other in (("angle_to_recording_deg", "recording"), ("angle_to_eq24_deg", "Eq. 24")):
                    if k in p:
                        text += f", {p[k]:.1f}° from the {other} gravity"
            lines.append(text)
    return "\n".join(lines)


def plot_gravity_case(case: GravityCase, path: str | os.PathLike[str], title: str = "") -> Path:
    """Accelerometer residual of one IMU under Eq. 11, Eq. 11 plus the named effects, and Eq. 24 (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = case.traces
    fig, axes = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
    series = [
        ("eq11", "Eq. 11 (no gravity)", "tab:red"),
        ("eq11_fitted", "Eq. 11 + named effects", "tab:orange"),
        ("eq24", "Eq. 24 (gravity)", "tab:blue"),
    ]
    for ax_i, ax in enumerate(axes):
        for key, label, color in series:
            if key in tr:
                ax.plot(tr["t"], tr[key][:, ax_i], lw=0.5, color=color, label=label)
        ax.set_ylabel(f"acc {'xyz'[ax_i]}\nm/s²", fontsize=8)
    imu = case.settings.get("trace_imu", "")
    return _save_time_axes(fig, axes, path, title or f"measured minus sensor-network accelerometer, {imu}")


def write_gravity_case(
    case: GravityCase, out_dir: str | os.PathLike[str], title: str = "", plots: bool = True
) -> list[Path]:
    """Write ``gravity_case.json``, ``gravity_case.md`` and (``plots``) ``gravity_case.png`` in ``out_dir``.

    ``.json`` is :meth:`GravityCase.to_json`; the PNG is :func:`plot_gravity_case`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "gravity_case.json", out / "gravity_case.md"]
    files[0].write_text(json.dumps(case.to_json(), indent=2) + "\n", encoding="utf-8")
    md = [
        f"# Gravity case{': ' + title if title else ''}",
        "",
        "```",
        format_gravity_case(case),
        "```",
        "",
        "Residuals are in-sample (both forms trained on the same data with the same seed). The causes "
        "come from the held-out effect selection on the Eq. 11 residual; an effect is listed when it "
        "was named on at least half of the analysed IMUs.",
        "",
    ]
    if plots:
        files.append(plot_gravity_case(case, out / "gravity_case.png", title))
        md += ["![accelerometer residual before and after](gravity_case.png)", ""]
    files[1].write_text("\n".join(md), encoding="utf-8")
    return files
