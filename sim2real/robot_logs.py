"""Import what robots log — a CSV table or a MATLAB v7.3 file — as a recording (docs/design.md,
'Recording').

An import map (TOML, :mod:`sim2real.robot_logs_map`, docs/recording-format.md "Importing CSV and MAT
logs") says which columns or datasets hold the clock(s), joint positions (and velocities), each IMU's
accelerometer and gyro, and the extra arrays to carry along (foot forces, a motion-capture base pose).
The import converts units, then measures the log's quirks (:mod:`sim2real.robot_logs_quirks`: held
values, irregular stamps, the encoder quantum) and keeps that report in the recording
(``extra["import_report"]``, a JSON string) so it travels with the data.

Bad input is refused with one line naming the stream and the first bad index: NaN or Inf, a text cell
that is not a number, too few samples, a stream whose length differs from its clock's, a column or
dataset the log does not have (with the close matches).

Example
-------
>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> _ = (d / "log.csv").write_text("t,q1,ax,ay,az,wx,wy,wz\\n" + "".join(
...     f"{i * 0.01},{i // 2 * 0.0015},0,0,9.81,0,0,0\\n" for i in range(10)))
>>> m = parse_map({"clock": {"time": "t"}, "joints": {"positions": ["q1"]},
...                "imus": [{"name": "imu0", "acc": ["ax", "ay", "az"], "gyro": "w*"}]})
>>> rec, report = import_log(d / "log.csv", m, "csv")
>>> rec.n_samples, report["streams"]["q"]["repeated_rows"], report["streams"]["q"]["unit_assumed"]
(10, 5, True)
"""

from __future__ import annotations

import csv
import fnmatch
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from bodyschema.recording import (
    MIN_SAMPLES,
    Recording,
    RecordingError,
    check_complete,
    check_finite,
    check_stamps,
)
from sim2real.robot_logs_map import (
    ACC_UNITS,
    ANGLE_UNITS,
    RATE_UNITS,
    TIME_UNITS,
    LogMap,
    MapError,
    Source,
    StreamSpec,
    close_matches,
    load_map,
    parse_map,
)
from sim2real.robot_logs_quirks import clock_report, encoder_quantum, repeated_rows

__all__ = ["CsvLog", "MatLog", "import_log", "load_map", "parse_map"]

#: Keys the import writes itself; an extra of the same name is refused.
_RESERVED = (
    "t", "t_q", "q", "qd", "qdd", "acc", "gyro", "gravity", "ref_quat", "ref_pos", "joint_names",
    "imu_names", "truth_joint_parent", "truth_imu_joint", "import_report", "stamp_origin_ns",
)  # fmt: skip


def _is_glob(s: str) -> bool:
    return any(c in s for c in "*?[")


def _sig_digits(s: str) -> int:
    """Significant digits of a number as printed ("-0.00123" -> 3, "2.2736" -> 5)."""
    mant = s.strip().lstrip("+-").split("e")[0].split("E")[0].replace(".", "").lstrip("0")
    return max(len(mant), 1)


class CsvLog:
    """A CSV log: a header row of column names, then one row per sample (numbers only in the columns the
    map reads). Rows are kept as text until a column is asked for."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.label = Path(path).name
        try:
            with open(path, newline="", encoding="utf-8-sig") as f:  # -sig: a spreadsheet's byte-order mark
                rows = list(csv.reader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise RecordingError(f"{self.label}: not a readable CSV file ({err})") from err
        if not rows or not any(h.strip() for h in rows[0]):
            raise RecordingError(f"{self.label}: empty file (a header row of column names is needed)")
        self.columns = [h.strip() for h in rows[0]]
        dup = sorted({c for c in self.columns if self.columns.count(c) > 1})
        if dup:
            raise RecordingError(f"{self.label}: the header names column(s) {dup} more than once")
        body = rows[1:]
        while body and not any(x.strip() for x in body[-1]):
            body.pop()  # trailing blank lines
        for i, r in enumerate(body):
            if len(r) != len(self.columns):
                raise RecordingError(
                    f"{self.label}: row {i} (line {i + 2}) has {len(r)} fields, "
                    f"the header {len(self.columns)}"
                )
        self._cols = list(zip(*body, strict=True)) if body else [() for _ in self.columns]

    def resolve(self, source: Source, where: str) -> list[str]:
        """The column names ``source`` stands for (a list as given, or a glob's matches in file order)."""
        names = [source] if isinstance(source, str) else list(source)
        if isinstance(source, str) and _is_glob(source):
            hit = fnmatch.filter(self.columns, source)
            if not hit:
                raise MapError(
                    f"{self.label}: {where} = {source!r} matches no column"
                    f"{close_matches(source.strip('*?'), self.columns)}"
                )
            return hit
        for c in names:
            if c not in self.columns:
                raise MapError(
                    f"{self.label}: unknown column {c!r} ({where}){close_matches(c, self.columns)}"
                )
        return names

    def has(self, source: Source) -> bool:
        if isinstance(source, str) and _is_glob(source):
            return bool(fnmatch.filter(self.columns, source))
        return all(c in self.columns for c in ([source] if isinstance(source, str) else source))

    def read(self, source: Source, where: str) -> tuple[np.ndarray, list[str], np.ndarray]:
        """(values (T, c) float64, column names, resolution (c,)): a column's resolution is the step of
        its last printed digit at its largest magnitude, the coarsest rounding its values went through."""
        cols = self.resolve(source, where)
        out = np.empty((len(self._cols[0]), len(cols)))
        res = np.zeros(len(cols))
        for k, c in enumerate(cols):
            text = self._cols[self.columns.index(c)]
            try:
                out[:, k] = np.array(text, dtype=np.float64)
            except ValueError:
                i = next(i for i, s in enumerate(text) if not _parses(s))
                raise RecordingError(
                    f"{self.label}: {where} column {c!r}: row {i} (line {i + 2}) holds {text[i]!r}, "
                    "not a number"
                ) from None
            big = np.max(np.abs(out[:, k]), initial=0.0)
            if text and np.isfinite(big) and big > 0:
                sig = max(_sig_digits(s) for s in text)
                res[k] = 10.0 ** (math.floor(math.log10(big)) - sig + 1)
        return out, cols, res


def _parses(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


_MAT_NUMERIC = {
    b"double",
    b"single",
    b"int8",
    b"uint8",
    b"int16",
    b"uint16",
    b"int32",
    b"uint32",
    b"int64",
    b"uint64",
}


class MatLog:
    """A MATLAB v7.3 file (HDF5). MATLAB stores arrays with their dimensions reversed, so a dataset of
    shape (channels, samples) in HDF5 is read as (samples, channels)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        import h5py

        self.label = Path(path).name
        try:
            self._f = h5py.File(path, "r")
        except OSError as err:
            raise RecordingError(
                f"{self.label}: not a MATLAB v7.3 (HDF5) file ({err}); save it in MATLAB with -v7.3"
            ) from err
        self.columns = sorted(k for k, v in self._f.items() if isinstance(v, h5py.Dataset))

    def close(self) -> None:
        self._f.close()

    def has(self, source: Source) -> bool:
        return all(s in self.columns for s in ([source] if isinstance(source, str) else source))

    def _one(self, name: str, where: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in self.columns:
            raise MapError(
                f"{self.label}: unknown dataset {name!r} ({where}){close_matches(name, self.columns)}"
            )
        ds = self._f[name]
        cls = ds.attrs.get("MATLAB_class", b"double")
        cls = cls if isinstance(cls, bytes) else str(cls).encode()
        if cls not in _MAT_NUMERIC or ds.attrs.get("MATLAB_empty", 0) or ds.ndim != 2:
            raise RecordingError(
                f"{self.label}: dataset {name!r} ({where}) is not a numeric matrix "
                f"(MATLAB class {cls.decode(errors='replace')!r}, shape {ds.shape})"
            )
        raw = ds[()].T
        res = np.zeros(raw.shape[1])
        if np.issubdtype(raw.dtype, np.floating) and raw.size:
            with np.errstate(invalid="ignore"):
                big = np.max(np.abs(np.where(np.isfinite(raw), raw, 0)), axis=0)
            res = np.spacing(big).astype(np.float64)
        return np.asarray(raw, dtype=np.float64), res

    def read(self, source: Source, where: str) -> tuple[np.ndarray, list[str], np.ndarray]:
        """(values (T, c) float64, channel labels, resolution (c,): the float spacing at each channel's
        largest value);
        a list of datasets (one channel each) is stacked as columns."""
        if isinstance(source, str):
            v, res = self._one(source, where)
            return v, [f"{source}[{k}]" for k in range(v.shape[1])], res
        parts = [self._one(s, where) for s in source]
        lens = {p[0].shape[0] for p in parts}
        if len(lens) > 1 or any(p[0].shape[1] != 1 for p in parts):
            shapes = {s: p[0].shape for s, p in zip(source, parts, strict=True)}
            raise RecordingError(
                f"{self.label}: {where}: datasets of one channel and equal length needed, got {shapes}"
            )
        return np.hstack([p[0] for p in parts]), list(source), np.concatenate([p[1] for p in parts])


def _src_text(source: Source) -> str:
    return source if isinstance(source, str) else ", ".join(source)


class _Import:
    """One import in progress: the log, its map, the clocks read so far and the report being filled."""

    def __init__(self, log: CsvLog | MatLog, m: LogMap, fmt: str) -> None:
        self.log, self.m = log, m
        self.clocks: dict[str, np.ndarray] = {}
        self.report: dict[str, Any] = {"source": log.label, "format": fmt, "clocks": {}, "streams": {}}

    def clock(self, name: str, where: str) -> np.ndarray:
        """The stamps of clock ``name`` in seconds, checked: finite, enough, strictly increasing."""
        if name in self.clocks:
            return self.clocks[name]
        v, _, _ = self.log.read(name, where)
        if v.shape[1] != 1:
            raise RecordingError(
                f"{self.log.label}: clock {name!r} ({where}) has {v.shape[1]} channels, not 1"
            )
        t = v[:, 0] * TIME_UNITS[self.m.time_unit]
        label = f"{self.log.label}: clock {name!r}"
        if t.shape[0] < MIN_SAMPLES:
            raise RecordingError(
                f"{label} has {t.shape[0]} sample(s): a recording needs at least {MIN_SAMPLES} "
                "(qdd, the second difference of q, needs three)"
            )
        check_finite(t, label)
        try:
            check_stamps(t, label)
        except RecordingError as err:  # the loader's repair option does not apply to a log
            raise RecordingError(
                str(err).replace("load with repair=True to drop them", "fix the log")
            ) from None
        self.clocks[name] = t
        return t

    def stream(self, spec: StreamSpec, scale: float, key: str) -> tuple[np.ndarray, list[str], np.ndarray]:
        """A stream's values in SI units on its clock, checked for length and finiteness; its unit,
        clock and held-value statistics go into the report under ``key``."""
        t = self.clock(spec.time, spec.where)
        v, labels, res = self.log.read(spec.source, spec.where)
        src = _src_text(spec.source)
        if v.shape[0] != t.shape[0]:
            raise RecordingError(
                f"{self.log.label}: {spec.where} ({src}) has {v.shape[0]} samples, its clock "
                f"{spec.time!r} has {t.shape[0]}"
            )
        check_finite(v, f"{self.log.label}: {spec.where} ({src})", t, tuple(labels))
        v = v * scale if scale != 1.0 else v
        self.report["streams"][key] = {
            "source": list(labels),
            "clock": spec.time,
            "unit": spec.unit,
            "unit_assumed": not spec.unit_stated,
            **repeated_rows(v, t),
        }
        return v, labels, res * scale


def _joint_names(m: LogMap, labels: list[str], n: int, run: _Import) -> tuple[str, ...]:
    """The map's names; else, for a CSV log, the column names with the fixed part of the map's glob taken
    off (``JointPos*`` names column ``JointPosFR_hip`` ``FR_hip``) or the columns listed."""
    if m.joint_names is not None:
        if len(m.joint_names) != n:
            raise MapError(
                f"{run.log.label}: joints.names lists {len(m.joint_names)} joints, the positions have {n}"
            )
        return m.joint_names
    src = m.positions.source
    if isinstance(run.log, MatLog):
        raise MapError(f"{run.log.label}: joints.names is needed: MATLAB datasets do not name their joints")
    if not isinstance(src, str) or not _is_glob(src):
        return tuple(labels)
    head = src[: min(src.find(c) for c in "*?[" if c in src)]
    tail = src[max(src.rfind(c) for c in "*?]") + 1 :]
    names = tuple(c[len(head) : len(c) - len(tail)] for c in labels)
    return names if all(names) and len(set(names)) == len(names) else tuple(labels)


def _joints(run: _Import) -> dict[str, Any]:
    m = run.m
    q, labels, res = run.stream(m.positions, ANGLE_UNITS[m.positions.unit], "q")
    names = _joint_names(m, labels, q.shape[1], run)
    run.report["encoders"] = {j: encoder_quantum(q[:, k], float(res[k])) for k, j in enumerate(names)}
    qd = None
    if m.velocities is not None:
        qd, _, _ = run.stream(m.velocities, RATE_UNITS[m.velocities.unit], "qd")
        if qd.shape[1] != q.shape[1]:
            raise RecordingError(
                f"{run.log.label}: joints.velocities has {qd.shape[1]} joints, joints.positions {q.shape[1]}"
            )
    return {"q": q, "qd": qd, "joint_names": names, "t_q": run.clocks[m.positions.time]}


def _imus(run: _Import) -> dict[str, Any]:
    accs, gyros = [], []
    for imu in run.m.imus:
        a, _, _ = run.stream(imu.acc, ACC_UNITS[imu.acc.unit], f"acc:{imu.name}")
        g, _, _ = run.stream(imu.gyro, RATE_UNITS[imu.gyro.unit], f"gyro:{imu.name}")
        for what, v in (("acc", a), ("gyro", g)):
            if v.shape[1] != 3:
                where = getattr(imu, what).where
                raise RecordingError(
                    f"{run.log.label}: {where} has {v.shape[1]} channels, an IMU needs 3 (x, y, z)"
                )
        accs.append(a)
        gyros.append(g)
    t = run.clocks[run.m.imus[0].acc.time]
    names = tuple(imu.name for imu in run.m.imus)
    return {"t": t, "acc": np.stack(accs, axis=1), "gyro": np.stack(gyros, axis=1), "imu_names": names}


def _extras(run: _Import) -> dict[str, np.ndarray]:
    """Each extra as stored (samples first; one channel becomes 1-D); an optional one the log lacks is
    listed as absent. Extras on the IMU clock's length are checked for NaN like every stream."""
    out: dict[str, np.ndarray] = {}
    absent = []
    n_t = run.clocks[run.m.imus[0].acc.time].shape[0]
    for e in run.m.extras:
        if e.name in _RESERVED:
            raise MapError(f"{run.log.label}: {e.where}.name = {e.name!r} is a field of the recording itself")
        if e.optional and not run.log.has(e.source):
            absent.append(e.name)
            continue
        v, labels, _ = run.log.read(e.source, e.where)
        check_finite(v, f"{run.log.label}: {e.where} ({_src_text(e.source)})", None, tuple(labels))
        out[e.name] = v[:, 0] if v.shape[1] == 1 else v
        info: dict[str, Any] = {"source": labels, "unit": e.unit, "shape": list(out[e.name].shape)}
        if v.shape[0] == n_t:
            info.update(repeated_rows(v, run.clocks[run.m.imus[0].acc.time]))
        run.report["streams"][f"extra:{e.name}"] = info
    run.report["extras"] = {"present": list(out), "absent": absent}
    return out


def import_log(
    path: str | os.PathLike[str], log_map: LogMap | str | os.PathLike[str], fmt: str
) -> tuple[Recording, dict[str, Any]]:
    """Read a ``csv`` or ``mat`` log through its import map; return the recording and the import report.

    The report (also ``extra["import_report"]``) holds, for every clock, its step statistics and gaps;
    for every stream, its source, the unit read (and whether the map stated it or it was assumed), the
    rows that repeat the previous one and the update rate that leaves; for every joint, the encoder
    quantum. Wall-clock stamps (after 1e6 s) count from the whole second before the first, kept as
    ``extra["stamp_origin_ns"]`` as the ROS bag import does; the subtraction is exact.
    """
    m = log_map if isinstance(log_map, LogMap) else load_map(log_map)
    if fmt not in ("csv", "mat"):
        raise ValueError(f"format must be 'csv' or 'mat', got {fmt!r}")
    if m.format is not None and m.format != fmt:
        raise MapError(f"the map is for {m.format!r} logs, the import reads {fmt!r}")
    log = CsvLog(path) if fmt == "csv" else MatLog(path)
    try:
        run = _Import(log, m, fmt)
        imu = _imus(run)
        enc = _joints(run)
        extra = _extras(run)
    finally:
        if isinstance(log, MatLog):
            log.close()
    _finish_report(run)
    t, t_q = imu["t"], enc.pop("t_q")
    origin = math.floor(min(t[0], t_q[0])) if min(t[0], t_q[0]) > 1e6 else 0
    if origin:
        t, t_q = t - origin, t_q - origin
        extra["stamp_origin_ns"] = np.asarray(origin * 1_000_000_000, dtype=np.int64)
    multirate = m.positions.time != m.imus[0].acc.time
    extra["import_report"] = np.asarray(json.dumps(run.report))
    rec = Recording(
        t=t, t_q=t_q if multirate else None, joint_names=enc["joint_names"], q=enc["q"], qd=enc["qd"],
        imu_names=imu["imu_names"], acc=imu["acc"], gyro=imu["gyro"], gravity=m.gravity, extra=extra,
    )  # fmt: skip
    check_complete(rec)
    return rec, run.report


def _finish_report(run: _Import) -> None:
    """Clock statistics and the units of time and gravity (stated or assumed)."""
    for name, t in run.clocks.items():
        run.report["clocks"][name] = clock_report(t, run.m.gap_factor)
    run.report["units"] = {
        "time": {"unit": run.m.time_unit, "assumed": not run.m.time_unit_stated},
        "gravity": {"value": run.m.gravity.tolist(), "assumed": not run.m.gravity_stated},
    }
