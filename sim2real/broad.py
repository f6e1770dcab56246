"""Import a BROAD trial (HDF5) as a recording (docs/design.md, 'Recording') with a motion-capture reference.

BROAD — the Berlin Robust Orientation Estimation Assessment Dataset — records one real IMU together
with optical motion capture of the same rigid body: Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark
for Robust Inertial Orientation Estimation", Data 6(7), 2021, licensed CC BY 4.0. The attribution
travels with every imported recording (``extra["attribution"]``).

What the file holds: ``imu_acc`` (m/s²), ``imu_gyr`` (rad/s), ``imu_mag`` (µT, not imported),
``opt_quat`` (wxyz, marker body -> ENU), ``opt_pos`` (m), ``movement`` (bool), attribute
``sampling_rate`` (≈ 285.7 Hz). The optical track has NaN where the cameras lost the markers. This
importer fills short gaps (slerp for the orientation, linear for the position) and fills long gaps
too, so the arrays stay finite, but marks them invalid in ``extra["ref_valid"]``; analyses must skip
invalid samples. ``extra["movement"]`` keeps the dataset's movement mask.

Example
-------
>>> paths = sorted(broad_data_dir().glob("*.hdf5"))
>>> rec = load_broad(paths[0]) if paths else None
>>> rec is None or (rec.imu_names == ("imu0",) and rec.ref_quat.shape[1] == 4)
True
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from bodyschema.recording import GRAVITY, Recording, RecordingError

__all__ = ["BROAD_ATTRIBUTION", "broad_data_dir", "fill_gaps", "gap_runs", "load_broad", "session_of"]

BROAD_ATTRIBUTION = (
    "BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, 'BROAD—A Benchmark for Robust Inertial "
    "Orientation Estimation', Data 6(7), 2021, https://doi.org/10.3390/data6070072, CC BY 4.0"
)


def broad_data_dir() -> Path:
    """Where the shared BROAD trials are: ``$BODYHEALTH_BROAD_DIR``, else ``shared/data/broad`` beside
    the repository (the layout of a checkout next to the team's shared folder)."""
    env = os.environ.get("BODYHEALTH_BROAD_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"


_REQUIRED = ("imu_acc", "imu_gyr", "opt_quat", "opt_pos", "movement")


def gap_runs(bad: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the runs of True in a boolean array (stop exclusive).

    >>> gap_runs(np.array([False, True, True, False, True]))
    [(1, 3), (4, 5)]
    """
    b = np.asarray(bad, dtype=bool)
    d = np.diff(np.concatenate([[0], b.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def fill_gaps(
    t: np.ndarray, quat: np.ndarray, pos: np.ndarray, max_gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill NaN rows of an optical track; returns ``(quat, pos, valid)``.

    Every gap is filled (slerp between the neighbouring orientations, linear for positions, the
    nearest sample held at the ends) so the arrays are finite; ``valid`` is False inside gaps longer
    than ``max_gap`` seconds and inside gaps at either end, where a fill is a guess.
    """
    bad = ~(np.all(np.isfinite(quat), axis=1) & np.all(np.isfinite(pos), axis=1))
    good = np.flatnonzero(~bad)
    if good.size < 2:
        raise RecordingError("the optical reference has fewer than two valid samples")
    q = quat.copy()
    p = pos.copy()
    rot = Rotation.from_quat(q[good], scalar_first=True)
    tg = t[good]
    inner = bad & (t > tg[0]) & (t < tg[-1])
    if inner.any():
        q[inner] = Slerp(tg, rot)(t[inner]).as_quat(scalar_first=True)
    for j in range(3):
        p[bad, j] = np.interp(t[bad], tg, pos[good, j])  # edge-held outside the valid span
    q[t < tg[0]] = q[good[0]]
    q[t > tg[-1]] = q[good[-1]]
    valid = np.ones(t.shape[0], dtype=bool)
    for start, stop in gap_runs(bad):
        at_edge = start == 0 or stop == t.shape[0]
        if at_edge or t[stop - 1] - t[start] + (t[1] - t[0]) > max_gap:
            valid[start:stop] = False
    return q, p, valid


def session_of(trial: str) -> str:
    """The IMU session letter of a BROAD trial name (``'07_undisturbed_fast_rotation_B'`` -> ``'B'``)."""
    stem = Path(trial).stem
    tail = stem.rsplit("_", 1)[-1]
    return tail if len(tail) == 1 and tail.isalpha() else ""


def load_broad(path: str | os.PathLike[str], max_gap: float = 0.1) -> Recording:
    """Read a BROAD trial into a :class:`~bodyschema.recording.Recording` (one IMU ``imu0``, no ``q``).

    ``max_gap`` (s): optical dropouts up to this long are interpolated and count as valid.
    """
    try:
        with h5py.File(path, "r") as f:
            missing = [k for k in _REQUIRED if k not in f]
            if missing:
                raise RecordingError(f"{path}: not a BROAD trial, missing datasets {missing}")
            rate = float(f.attrs.get("sampling_rate", 0.0))
            acc = np.asarray(f["imu_acc"], dtype=np.float64)
            gyr = np.asarray(f["imu_gyr"], dtype=np.float64)
            quat = np.asarray(f["opt_quat"], dtype=np.float64)
            pos = np.asarray(f["opt_pos"], dtype=np.float64)
            movement = np.asarray(f["movement"], dtype=bool).reshape(-1)
            info = str(f.attrs.get("info", ""))
    except OSError as err:
        raise RecordingError(f"{path}: not a readable HDF5 file ({err})") from err
    n = acc.shape[0]
    if rate <= 0:
        raise RecordingError(f"{path}: missing or bad sampling_rate attribute")
    shapes = {"imu_acc": (acc, 3), "imu_gyr": (gyr, 3), "opt_quat": (quat, 4), "opt_pos": (pos, 3)}
    for name, (arr, width) in shapes.items():
        if arr.shape != (n, width):
            raise RecordingError(f"{path}: {name} has shape {arr.shape}, expected {(n, width)}")
    if movement.shape != (n,):
        raise RecordingError(f"{path}: movement has shape {movement.shape}, expected {(n,)}")
    imu_ok = np.all(np.isfinite(acc), axis=1) & np.all(np.isfinite(gyr), axis=1)
    if not imu_ok.all():
        # The IMU itself should have no gaps; hold the last reading but mark the samples invalid.
        for arr in (acc, gyr):
            for j in range(3):
                arr[~imu_ok, j] = np.interp(np.flatnonzero(~imu_ok), np.flatnonzero(imu_ok), arr[imu_ok, j])
    t = np.arange(n) / rate
    q, p, valid = fill_gaps(t, quat, pos, max_gap)
    trial = Path(path).stem
    return Recording(
        t=t,
        joint_names=(),
        q=None,
        imu_names=("imu0",),
        acc=acc[:, None, :],
        gyro=gyr[:, None, :],
        gravity=GRAVITY.copy(),
        ref_quat=q,
        ref_pos=p,
        extra={
            "ref_valid": valid & imu_ok,
            "movement": movement,
            "attribution": np.array(BROAD_ATTRIBUTION),
            "source": np.array(f"BROAD trial {trial}"),
            "source_info": np.array(info),
        },
    )
