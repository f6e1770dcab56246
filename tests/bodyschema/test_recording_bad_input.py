"""Bad recordings and bad robot logs: one line naming the stream and the first bad index, exit 1, and no
file written (nor an existing one touched)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from bodyschema.recording import MIN_SAMPLES, Recording, RecordingError
from cli.main import main
from sim2real.robot_logs import import_log
from simulators.recording_io import Blocks, load_recording, save_recording

HEADER = "t,q1,q2,ax,ay,az,wx,wy,wz"
MAP = """
[clock]
time = "t"
[joints]
positions = "q*"
[[imus]]
name = "imu0"
acc = ["ax", "ay", "az"]
gyro = "w*"
"""


def _csv_rows(n: int) -> list[list[str]]:
    return [
        [f"{0.01 * i:.2f}", f"{0.001 * i}", f"{-0.002 * i}", "0", "0.1", "9.81", "0.01", "0", "0"]
        for i in range(n)
    ]


def _write_log(d: Path, rows: list[list[str]], map_text: str = MAP) -> tuple[Path, Path]:
    (d / "log.csv").write_text(HEADER + "\n" + "".join(",".join(r) + "\n" for r in rows))
    (d / "map.toml").write_text(map_text)
    return d / "log.csv", d / "map.toml"


def _import_fails(d: Path, capsys, fmt: str = "csv", log: Path | None = None) -> str:
    """Run the import; check exit 1, one stderr line, no output (nor temporary) file; return the line."""
    log = log or d / f"log.{fmt}"
    before = sorted(p.name for p in d.iterdir())
    assert main(["import", fmt, str(log), "--map", str(d / "map.toml"), "-o", str(d / "rec.npz")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert sorted(p.name for p in d.iterdir()) == before  # nothing written, nothing left behind
    return err.strip()


@pytest.mark.parametrize(
    ("row", "col", "value", "message"),
    [
        (
            5,
            4,
            "nan",
            "imus[0].acc (ax, ay, az) contains NaN or Inf at index 5 (t = 0.05 s), 'ay'; 1 value(s)",
        ),
        (7, 2, "inf", "joints.positions (q*) contains NaN or Inf at index 7 (t = 0.07 s), 'q2'"),
        (3, 0, "nan", "clock 't' contains NaN or Inf at index 3"),
        (4, 7, "abc", "imus[0].gyro column 'wy': row 4 (line 6) holds 'abc', not a number"),
        (6, 1, "", "joints.positions column 'q1': row 6 (line 8) holds '', not a number"),
    ],
)
def test_nan_inf_and_text_in_a_csv_stream(tmp_path, row, col, value, message) -> None:
    rows = _csv_rows(10)
    rows[row][col] = value
    log, map_path = _write_log(tmp_path, rows)
    with pytest.raises(RecordingError) as err:
        import_log(log, map_path, "csv")
    assert str(err.value).startswith(f"log.csv: {message}")


def test_the_command_says_it_in_one_line_and_writes_nothing(tmp_path, capsys) -> None:
    rows = _csv_rows(10)
    rows[5][4] = "nan"
    _write_log(tmp_path, rows)
    assert _import_fails(tmp_path, capsys) == (
        "bodyhealth import: error: log.csv: imus[0].acc (ax, ay, az) contains NaN or Inf at index 5 "
        "(t = 0.05 s), 'ay'; 1 value(s) in all"
    )


@pytest.mark.parametrize("n", [0, 1, MIN_SAMPLES - 1])
def test_empty_and_too_short_logs_state_the_minimum(tmp_path, n) -> None:
    log, map_path = _write_log(tmp_path, _csv_rows(n))
    with pytest.raises(RecordingError) as err:
        import_log(log, map_path, "csv")
    assert str(err.value) == (
        f"log.csv: clock 't' has {n} sample(s): a recording needs at least {MIN_SAMPLES} "
        "(qdd, the second difference of q, needs three)"
    )


def test_time_going_backwards_is_named(tmp_path, capsys) -> None:
    rows = _csv_rows(10)
    rows[6][0] = "0.04"
    _write_log(tmp_path, rows)
    assert "log.csv: clock 't' goes backwards at index 6 (0.05 s -> 0.04 s" in _import_fails(tmp_path, capsys)
    rows[6][0] = "0.05"
    log, map_path = _write_log(tmp_path, rows)
    with pytest.raises(
        RecordingError,
        match=r"^log.csv: clock 't' has duplicate stamps at index 6 \(0.05 s, 1 in all\); fix the log$",
    ):
        import_log(log, map_path, "csv")


def test_unknown_column_lists_close_matches(tmp_path, capsys) -> None:
    _write_log(tmp_path, _csv_rows(10), MAP.replace('"ay"', '"aY_"'))
    line = _import_fails(tmp_path, capsys)
    assert line.startswith(
        "bodyhealth import: error: log.csv: unknown column 'aY_' (imus[0].acc); close matches: ay"
    )
    _write_log(tmp_path, _csv_rows(10), MAP.replace('"q*"', '"joint*"'))
    assert "joints.positions = 'joint*' matches no column" in _import_fails(tmp_path, capsys)


def test_unknown_map_key_lists_close_matches(tmp_path, capsys) -> None:
    _write_log(tmp_path, _csv_rows(10), MAP + 'velocites = "v*"\n')
    line = _import_fails(tmp_path, capsys)
    assert (
        "map.toml: unknown key imus[0].velocites (known: name, acc, gyro, acc_unit, gyro_unit, time)" in line
    )
    _write_log(tmp_path, _csv_rows(10), MAP.replace("[joints]", "[joints]\nvelocites = 'v*'"))
    assert "unknown key joints.velocites; close matches: velocities" in _import_fails(tmp_path, capsys)


def test_a_row_with_a_missing_field_is_named(tmp_path, capsys) -> None:
    rows = _csv_rows(10)
    rows[2] = rows[2][:-1]
    _write_log(tmp_path, rows)
    assert _import_fails(tmp_path, capsys).endswith("log.csv: row 2 (line 4) has 8 fields, the header 9")


def _write_mat(path: Path, data: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3 file as MATLAB writes one: each matrix stored transposed, with its class attribute."""
    with h5py.File(path, "w") as f:
        for k, v in data.items():
            f.create_dataset(k, data=np.atleast_2d(v).T).attrs["MATLAB_class"] = np.bytes_(b"double")


MAT_MAP = """
[clock]
time = "time"
[joints]
positions = "pos"
names = ["a", "b"]
[[imus]]
name = "imu0"
acc = "acc"
gyro = "gyro"
"""


def test_mismatched_lengths_in_a_mat_file(tmp_path, capsys) -> None:
    t = np.arange(10) * 0.01
    _write_mat(
        tmp_path / "log.mat",
        {"time": t[:, None], "pos": np.zeros((10, 2)), "acc": np.zeros((9, 3)), "gyro": np.zeros((10, 3))},
    )
    (tmp_path / "map.toml").write_text(MAT_MAP)
    assert _import_fails(tmp_path, capsys, "mat").endswith(
        "log.mat: imus[0].acc (acc) has 9 samples, its clock 'time' has 10"
    )
    (tmp_path / "map.toml").write_text(MAT_MAP.replace('["a", "b"]', '["a", "b", "c"]'))
    _write_mat(
        tmp_path / "log.mat",
        {"time": t[:, None], "pos": np.zeros((10, 2)), "acc": np.zeros((10, 3)), "gyro": np.zeros((10, 3))},
    )
    assert _import_fails(tmp_path, capsys, "mat").endswith(
        "joints.names lists 3 joints, the positions have 2"
    )


def test_a_file_that_is_not_matlab_v73(tmp_path, capsys) -> None:
    (tmp_path / "log.mat").write_bytes(b"MATLAB 5.0 MAT-file" + bytes(200))
    (tmp_path / "map.toml").write_text(MAT_MAP)
    assert "log.mat: not a MATLAB v7.3 (HDF5) file" in _import_fails(tmp_path, capsys, "mat")


def test_a_failed_import_leaves_an_existing_recording_as_it_was(tmp_path, capsys) -> None:
    rows = _csv_rows(10)
    rows[5][4] = "nan"
    _write_log(tmp_path, rows)
    (tmp_path / "rec.npz").write_bytes(b"the recording accepted before")
    assert "contains NaN or Inf at index 5" in _import_fails(tmp_path, capsys)
    assert (tmp_path / "rec.npz").read_bytes() == b"the recording accepted before"
    _write_log(tmp_path, _csv_rows(10))  # fixed: now it is replaced, and nothing else is left beside it
    assert main(["import", "csv", str(tmp_path / "log.csv"), "--map", str(tmp_path / "map.toml"),
                 "-o", str(tmp_path / "rec.npz")]) == 0  # fmt: skip
    assert load_recording(tmp_path / "rec.npz").n_samples == 10
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv", "map.toml", "rec.npz"]


def _rec(T: int = 20, **change) -> Recording:
    kw = {
        "t": np.arange(T) * 0.01,
        "joint_names": ("j1",),
        "q": np.sin(np.arange(T) * 0.1)[:, None],
        "imu_names": ("imu0",),
        "acc": np.zeros((T, 1, 3)),
        "gyro": np.zeros((T, 1, 3)),
    }
    kw.update(change)
    return Recording(**kw)


def test_save_failing_half_way_writes_nothing(tmp_path) -> None:
    path = tmp_path / "rec.npz"
    save_recording(_rec(), path)
    before = path.read_bytes()

    def rows():
        yield np.zeros((10, 1, 3))
        raise RuntimeError("the source died")

    with pytest.raises(RuntimeError, match="the source died"):
        save_recording(_rec(), path, blocks={"acc": Blocks(rows)})
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["rec.npz"]


def test_not_an_npz_file_is_named_as_such(tmp_path) -> None:
    text = tmp_path / "notes.npz"
    text.write_text("joint angles, see spreadsheet\n")
    with pytest.raises(RecordingError) as err:
        load_recording(text)
    msg = str(err.value)
    assert msg == f"{text}: not an .npz recording: not a readable zip archive (it starts with b'joint an')"
    assert "pickle" not in msg
    np.save(tmp_path / "one.npy", np.zeros(3))
    (tmp_path / "one.npy").rename(tmp_path / "one.npz")
    with pytest.raises(RecordingError, match=r"one.npz: not an .npz recording: a single .npy array"):
        load_recording(tmp_path / "one.npz")
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(RecordingError, match=r"empty.npz: not an .npz recording: .*\(an empty file\)"):
        load_recording(tmp_path / "empty.npz")


def test_zero_length_and_too_short_recordings(tmp_path) -> None:
    with pytest.raises(RecordingError, match=r"^t is empty \(0 samples\): a recording needs at least one$"):
        _rec(0)
    np.savez(tmp_path / "zero.npz", **{k: getattr(_rec(5), k)[:0] for k in ("t", "acc", "gyro", "q")},
             imu_names=np.array(["imu0"]), joint_names=np.array(["j1"]))  # fmt: skip
    with pytest.raises(RecordingError, match=r"zero.npz: t is empty \(0 samples\)"):
        load_recording(tmp_path / "zero.npz")
    save_recording(_rec(MIN_SAMPLES - 1), tmp_path / "short.npz")  # a chunk in memory may be that short
    with pytest.raises(
        RecordingError, match=rf"short.npz: t has {MIN_SAMPLES - 1} sample\(s\): .* at least 3"
    ):
        load_recording(tmp_path / "short.npz")


def test_mismatched_lengths_in_a_recording_file(tmp_path) -> None:
    rec = _rec()
    np.savez(tmp_path / "m.npz", t=rec.t, q=rec.q[:-1], acc=rec.acc, gyro=rec.gyro,
             imu_names=np.array(["imu0"]), joint_names=np.array(["j1"]))  # fmt: skip
    with pytest.raises(RecordingError, match=r"m.npz: q must have shape \(20, 1\) \(on t\), got \(19, 1\)"):
        load_recording(tmp_path / "m.npz")


@pytest.mark.parametrize("command", ["topology", "kinematics"])
def test_estimators_refuse_a_recording_with_nan_at_load(tmp_path, capsys, command) -> None:
    gyro = np.zeros((20, 1, 3))
    gyro[7, 0, 2] = np.nan
    save_recording(_rec(gyro=gyro), tmp_path / "rec.npz")  # NaN is allowed in memory (a store window)
    assert main([command, str(tmp_path / "rec.npz")]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"bodyhealth {command}: error: {tmp_path / 'rec.npz'}: gyro contains NaN or Inf at index 7 "
        "(t = 0.07 s), 'imu0'; 1 value(s) in all\n"
    )
