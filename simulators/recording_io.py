"""Read and write recordings as ``.npz`` files (docs/design.md, 'Recording': a contract with outside tools).

Multi-rate recordings (encoders on their own stamps ``t_q``) are described in docs/recording-format.md;
files with one ``t`` load as before. Timing problems are refused with a message saying where
(:func:`bodyschema.recording.check_stamps`), except two documented repairs: ``repair=True`` drops
samples whose stamp repeats the previous one, and gaps are kept as they are; both are logged.

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

import logging
import os
import secrets
import zipfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodyschema.recording import MIN_SAMPLES, Recording, RecordingError, check_complete, find_gaps

__all__ = ["Blocks", "drop_duplicate_stamps", "load_recording", "save_recording"]

log = logging.getLogger(__name__)

_ARRAYS = ("t", "t_q", "q", "qd", "qdd", "acc", "gyro", "gravity", "ref_quat", "ref_pos")
_IMU_SERIES = ("acc", "gyro", "ref_quat", "ref_pos")
_ENC_SERIES = ("q", "qd", "qdd")
_NAMES = ("joint_names", "imu_names", "truth_joint_parent", "truth_imu_joint")


@dataclass(frozen=True)
class Blocks:
    """The content of one array, written block by block (float64 rows in C order, first axis split):
    what :func:`save_recording` writes instead of the array of the same name when it is given, so a
    recording larger than memory can be written. ``blocks()`` starts a new pass over the rows."""

    blocks: Callable[[], Iterable[np.ndarray]]


def save_recording(
    rec: Recording, path: str | os.PathLike[str], *, blocks: Mapping[str, Blocks] | None = None
) -> None:
    """Write ``rec`` to ``path`` (compressed npz; names stored as unicode arrays, never pickled).

    ``blocks`` replaces the content of named arrays (``acc``, ``q``, ...) by rows produced block by
    block; the recording then only needs arrays of the right shape there (``np.broadcast_to`` views
    cost nothing), and the blocks must fill that shape exactly.
    """
    blocks = dict(blocks or {})
    unknown = set(blocks) - set(_ARRAYS)
    if unknown:
        raise RecordingError(f"blocks for unknown arrays: {sorted(unknown)}")
    data: dict[str, np.ndarray | tuple[tuple[int, ...], Blocks]] = {}
    for k in _ARRAYS:
        v = getattr(rec, k)
        if v is not None:
            data[k] = (np.shape(v), blocks.pop(k)) if k in blocks else np.asarray(v, dtype=np.float64)
    if blocks:
        raise RecordingError(f"blocks for arrays the recording lacks: {sorted(blocks)}")
    for k in _NAMES:
        v = getattr(rec, k)
        if v is not None:
            data[k] = np.asarray(list(v), dtype=np.str_)
    for k, v in rec.extra.items():
        if k in data:
            raise RecordingError(f"extra key {k!r} collides with a standard field")
        data[k] = np.asarray(v)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written beside the target and renamed only once complete: a failure (or a crash) leaves no
    # half-written file, and an existing recording at ``path`` stays as it was.
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.part")
    try:
        _write_npz(tmp, data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _write_npz(path: Path, data: Mapping[str, np.ndarray | tuple[tuple[int, ...], Blocks]]) -> None:
    """``np.savez_compressed``, written here because it needs every array in memory: the same zip of
    ``.npy`` members, where a member given as (shape, :class:`Blocks`) gets the ``.npy`` header of a
    float64 array of that shape and then its rows as they come. A failure removes the partial file."""
    try:
        with zipfile.ZipFile(path, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
            for key, val in data.items():
                with zf.open(key + ".npy", "w", force_zip64=True) as f:
                    if isinstance(val, np.ndarray):
                        np.lib.format.write_array(f, val, allow_pickle=False)
                        continue
                    shape, src = val
                    descr = np.lib.format.dtype_to_descr(np.dtype(np.float64))
                    header = {"descr": descr, "fortran_order": False, "shape": shape}
                    np.lib.format.write_array_header_1_0(f, header)
                    rows = 0
                    for b in src.blocks():
                        b = np.ascontiguousarray(b, dtype=np.float64)
                        if b.shape[1:] != shape[1:]:
                            raise RecordingError(f"{key}: a block of shape {b.shape} in an array {shape}")
                        rows += b.shape[0]
                        f.write(b.tobytes())
                    if rows != shape[0]:
                        raise RecordingError(f"{key}: blocks gave {rows} rows for an array {shape}")
    except BaseException:
        path.unlink(missing_ok=True)
        raise


def drop_duplicate_stamps(
    data: dict[str, np.ndarray], stamps: str, series: tuple[str, ...], source: str = "recording"
) -> int:
    """Drop, in place, every sample of ``series`` whose ``stamps`` entry equals the previous stamp.

    The first of the repeated samples is kept (a logger that re-sends a frame repeats it). Stamps that
    go backwards are not touched: :class:`Recording` refuses them. Returns how many were dropped and
    logs a warning naming the stream when any were.
    """
    if stamps not in data:
        return 0
    t = np.asarray(data[stamps], dtype=np.float64)
    if t.ndim != 1 or t.shape[0] < 2:
        return 0
    keep = np.concatenate([[True], np.diff(t) != 0])
    n = int((~keep).sum())
    if n:
        first = float(t[np.flatnonzero(~keep)[0]])
        log.warning(
            "%s: dropped %d sample(s) with a repeated %s stamp (first at %.6g s)", source, n, stamps, first
        )
        data[stamps] = t[keep]
        for k in series:
            if k in data and data[k].shape[:1] == keep.shape:
                data[k] = data[k][keep]
    return n


def _read_npz(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path``; a file that is not a zip of ``.npy`` arrays is refused
    by what it is, before numpy reads it (numpy would call a text file "pickled data")."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as err:
        raise RecordingError(f"{path}: not a readable .npz recording ({err})") from err
    if head.startswith(b"\x93NUMPY"):
        raise RecordingError(f"{path}: not an .npz recording: a single .npy array (save with np.savez)")
    if not head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        what = "an empty file" if not head else f"it starts with {head!r}"
        raise RecordingError(f"{path}: not an .npz recording: not a readable zip archive ({what})")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        reason = "an array holds Python objects (pickles are not read)" if "pickle" in str(err) else err
        raise RecordingError(f"{path}: not an .npz recording: {reason}") from err


def load_recording(path: str | os.PathLike[str], *, repair: bool = False) -> Recording:
    """Read a ``.npz`` recording (docs/design.md, 'Recording', and docs/recording-format.md); raise
    :class:`RecordingError` saying why if not one.

    ``repair`` drops samples with a repeated stamp (logged) instead of refusing the file. Gaps in
    either stream (intervals over 3 median periods) are logged as warnings, never filled. A file with
    NaN or Inf in a stream, or fewer than :data:`~bodyschema.recording.MIN_SAMPLES` samples in one, is
    refused naming the stream and the first bad index (:func:`~bodyschema.recording.check_complete`).
    """
    data = _read_npz(path)
    missing = [k for k in ("t", "imu_names", "acc", "gyro") if k not in data]
    if missing:
        raise RecordingError(f"{path}: missing keys {missing}")
    if repair:
        multirate = "t_q" in data
        drop_duplicate_stamps(data, "t", _IMU_SERIES if multirate else _IMU_SERIES + _ENC_SERIES, str(path))
        if multirate:
            drop_duplicate_stamps(data, "t_q", _ENC_SERIES, str(path))
    kw: dict[str, object] = {}
    for k in _ARRAYS:
        if k in data:
            kw[k] = np.asarray(data.pop(k), dtype=np.float64)
    for k in _NAMES:
        if k in data:
            kw[k] = tuple(str(x) for x in data.pop(k).reshape(-1))
    kw.setdefault("joint_names", ())
    kw.setdefault("q", None)
    try:
        rec = Recording(extra=data, **kw)  # type: ignore[arg-type]
        check_complete(rec, MIN_SAMPLES)
    except RecordingError as err:
        raise RecordingError(f"{path}: {err}") from err
    for name, stamps in (("t", rec.t), ("t_q", rec.t_q)):
        gaps = [] if stamps is None else find_gaps(stamps)
        if gaps:
            longest = max(b - a for a, b in gaps)
            log.warning(
                "%s: %d gap(s) in %s (longest %.3g s, first at %.6g s); kept as they are",
                path,
                len(gaps),
                name,
                longest,
                gaps[0][0],
            )
    return rec
