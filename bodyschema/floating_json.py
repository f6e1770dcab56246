"""A floating-base baseline as JSON and back, bit for bit, so a service can keep it across restarts.

:func:`bodyschema.floating_health.floating_baseline` learns tolerances that are extremes of one long
healthy window (longest holds, whole travels, the IMU's longest repeated reading) and, with foot
forces, the stance chains' and the tilt model's fits. Learning them again after a restart needs that
much device time of frames again, and a baseline learned on a later window may already hold a fault;
keeping the learned one is what lets judging go on. Arrays are kept as their raw little-endian bytes
(base64) with dtype and shape: exact, and free of the NaN that JSON (and PostgreSQL's JSON) refuses.

>>> import numpy as np
>>> from bodyschema.floating_health import floating_baseline
>>> from bodyschema.recording import Recording
>>> t = np.arange(400) * 0.01
>>> q = np.stack([np.sin(t), np.cos(2 * t)], axis=1)
>>> rec = Recording(t, ("a", "b"), q, ("imu",), np.ones((400, 1, 3)), np.zeros((400, 1, 3)))
>>> base = floating_baseline(rec)
>>> back = baseline_from_json(baseline_to_json(base))
>>> back.joint_names, bool(np.array_equal(back.max_jerk, base.max_jerk)), back.tilt is None
(('a', 'b'), True, True)
"""

from __future__ import annotations

import base64
from dataclasses import fields, is_dataclass
from typing import Any

import numpy as np

from bodyschema.floating_health import FloatingBaseline, _Chain
from bodyschema.stance_tilt import TiltLeg, TiltModel

__all__ = ["FORMAT", "baseline_from_json", "baseline_to_json"]

#: Version of the layout below; a stored baseline of another version is learned again, not guessed at.
FORMAT = 1


def _array(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    le = a.astype(a.dtype.newbyteorder("<"), copy=False)
    return {"dtype": le.dtype.str, "shape": list(a.shape), "b64": base64.b64encode(le.tobytes()).decode()}


def _unarray(d: dict[str, Any]) -> np.ndarray:
    raw = base64.b64decode(d["b64"])
    return np.frombuffer(raw, dtype=np.dtype(d["dtype"])).reshape(d["shape"]).copy()


def _encode(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return _array(v)
    if is_dataclass(v) and not isinstance(v, type):
        return {f.name: _encode(getattr(v, f.name)) for f in fields(v)}
    if isinstance(v, tuple | list):
        return [_encode(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def _chain(d: dict[str, Any]) -> _Chain:
    return _Chain(
        str(d["phase"]),
        tuple(bool(k) for k in d["key"]),
        tuple(int(c) for c in d["columns"]),
        _unarray(d["axes"]),
        _unarray(d["bias"]),
        float(d["rms"]),
        float(d["dof"]),
    )


def _tilt(d: dict[str, Any] | None) -> TiltModel | None:
    if d is None:
        return None
    legs = tuple(
        TiltLeg(int(g["foot"]), tuple(int(c) for c in g["columns"]), _unarray(g["axes"]), _unarray(g["c"]))
        for g in d["legs"]
    )
    return TiltModel(legs, _unarray(d["basis"]), _unarray(d["block_means"]), _unarray(d["block_counts"]))


def baseline_to_json(base: FloatingBaseline) -> dict[str, Any]:
    """``base`` as a JSON-able dict (``format``: :data:`FORMAT`)."""
    return {"format": FORMAT, **_encode(base)}


def baseline_from_json(d: dict[str, Any]) -> FloatingBaseline:
    """The baseline :func:`baseline_to_json` wrote. Raises ``ValueError`` for another format or a
    dict that is not one (a key missing, an array that does not fit its shape)."""
    if d.get("format") != FORMAT:
        raise ValueError(f"floating baseline format {d.get('format')!r}, this version reads {FORMAT}")
    try:
        thr = d["force_threshold"]
        return FloatingBaseline(
            joint_names=tuple(str(n) for n in d["joint_names"]),
            imu_names=tuple(str(n) for n in d["imu_names"]),
            quantum=_unarray(d["quantum"]),
            moving=_unarray(d["moving"]),
            max_jerk=_unarray(d["max_jerk"]),
            still_run_s=_unarray(d["still_run_s"]),
            imu_repeat=_unarray(d["imu_repeat"]),
            imu_run=_unarray(d["imu_run"]),
            force_threshold=None if thr is None else _unarray(thr),
            chains=tuple(_chain(c) for c in d["chains"]),
            tilt=_tilt(d.get("tilt")),
        )
    except (KeyError, TypeError) as err:
        raise ValueError(f"not a floating baseline: {err!r}") from None
