"""The robot analysis of :mod:`sim2real.robots` as text (``bodyhealth sim2real --model ROBOT.urdf``)."""

from __future__ import annotations

__all__ = ["format_robot"]


def _fmt(x: object) -> str:
    if isinstance(x, dict):
        return ", ".join(f"{k} {_fmt(v)}" for k, v in x.items())
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def format_robot(out: dict[str, object]) -> list[str]:
    """The robot analysis as lines of text: per prediction the residual before and after, the
    held-out gain per channel, every named effect with its 95 % interval; then the agreement of the
    predictions and what could not be done."""
    lines = [f"robot {out['robot']}, IMU mount from {out['imu_mount']['source']}, band {out['cutoff_hz']} Hz"]
    if out.get("encoder_quantization"):
        q = out["encoder_quantization"]
        lines.append(
            f"encoder quantization {q['quantum_rad']:.3g} rad: floor gyro {q['gyro_std']:.3g} rad/s, "
            f"acc {q['acc_std']:.3g} m/s²"
        )
    for name, rep in out["predictions"].items():
        rb, ra, g = rep["residual_before"], rep["residual_after"], rep["held_out"]["channel_gain"]
        lines.append(
            f"-- prediction {name}: gyro {rb['gyro_rms']:.4f} -> {ra['gyro_rms']:.4f} rad/s, "
            f"acc {rb['acc_rms']:.3f} -> {ra['acc_rms']:.3f} m/s²; held-out gain gyro {g['gyro']:.3f}, "
            f"acc {g['acc']:.3f}"
        )
        for c in rep["causes"]:
            if c["effect"] == "noise":
                continue
            reading = c.get("reading", "sensor or mount")
            note = "" if reading == "sensor or mount" else f"  ({reading})"
            iv = _fmt(c["interval"])
            lines.append(f"   {c['effect']}: {_fmt(c['params'])}  95 % {iv}  gain {c['gain']:.3f}{note}")
        for e in rep.get("robot_effects", []):
            if e.get("named"):
                val = e.get("value", e.get("params", e.get("ratio")))
                iv, gain = _fmt(e.get("interval", "-")), _fmt(e.get("gain", "-"))
                lines.append(f"   {e['effect']}: {_fmt(val)}  95 % {iv}  gain {gain}")
    for effect, a in out.get("agreement", {}).items():
        enc, moc = _fmt(a["encoders"]["interval"]), _fmt(a["mocap"]["interval"])
        lines.append(f"agreement {effect}: {a['agree']} (95 %: encoders {enc}, mocap {moc})")
        if "closure" in a:
            c = a["closure"]
            between = _fmt(c["between_predictions"]["interval"])
            lines.append(
                f"  closes over the predictions' own {effect}: {c['closes']} "
                f"(encoders against mocap, 95 %: {between}; expected {_fmt(c['expected'])})"
            )
    lines += [f"could not: {c}" for c in out["could_not"]]
    return lines
