"""Read and write recordings as ``.npz`` files (docs/design.md §2, a contract with outside tools).

Example
-------
>>> import numpy as np, tempfile, os
>>> from bodyschema.recording import Recording
>>> rec = Recording(t=np.arange(3) * 0.01, joint_names=["j1"], q=np.zeros((3, 1)),
...                 imu_names=["imu0"], acc=np.zeros((3, 1, 3)), gyro=np.zeros((3, 1, 3)))
>>> path = os.path.join(tempfile.mkdtemp(), "rec.npz")
>>> save_recording(rec, path)
>>> load_recording(path).imu_names
('imu0',)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bodyschema.recording import Recording, RecordingError

__all__ = ["load_recording", "save_recording"]

_ARRAYS = ("t", "q", "qd", "qdd", "acc", "gyro", "gravity", "ref_quat", "ref_pos")
_NAMES = ("joint_names", "imu_names", "truth_joint_parent", "truth_imu_joint")


def save_recording(rec: Recording, path: str | os.PathLike[str]) -> None:
    """Write ``rec`` to ``path`` (compressed npz; names stored as unicode arrays, never pickled)."""
    data: dict[str, np.ndarray] = {}
    for k in _ARRAYS:
        v = getattr(rec, k)
        if v is not None:
            data[k] = np.asarray(v, dtype=np.float64)
    for k in _NAMES:
        v = getattr(rec, k)
        if v is not None:
            data[k] = np.asarray(list(v), dtype=np.str_)
    for k, v in rec.extra.items():
        if k in data:
            raise RecordingError(f"extra key {k!r} collides with a standard field")
        data[k] = np.asarray(v)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **data)


def load_recording(path: str | os.PathLike[str]) -> Recording:
    """Read a ``.npz`` recording (docs/design.md §2); raise :class:`RecordingError` saying why if not one."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise RecordingError(f"{path}: not a readable .npz recording ({err})") from err
    missing = [k for k in ("t", "imu_names", "acc", "gyro") if k not in data]
    if missing:
        raise RecordingError(f"{path}: missing keys {missing}")
    kw: dict[str, object] = {}
    for k in _ARRAYS:
        if k in data:
            kw[k] = np.asarray(data.pop(k), dtype=np.float64)
    for k in _NAMES:
        if k in data:
            kw[k] = tuple(str(x) for x in data.pop(k).reshape(-1))
    kw.setdefault("joint_names", ())
    kw.setdefault("q", None)
    return Recording(extra=data, **kw)  # type: ignore[arg-type]
