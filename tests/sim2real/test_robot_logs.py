"""Importing the two measured robot logs (Go1 CSV, iCub MATLAB v7.3) through the shipped maps.

The expected values are counted here from the files themselves (the csv module, h5py), independently of
the importer, or taken from /work/shared/data/robots/README.md with the tolerance its rounding leaves.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from cli.main import main
from sim2real.robot_logs import import_log
from sim2real.robot_logs_map import MapError, load_map
from sim2real.robot_logs_quirks import QUANTUM_SCALE_TOL
from simulators.recording_io import load_recording, save_recording
from tests.robot_data import MAPS, ROBOTS

GO1 = ROBOTS / "go1-trot" / "go1.csv"
ICUB = ROBOTS / "icub-walking" / "sync-walkingFrontAndBackGoodTrial.mat"
GO1_MAP = MAPS / "go1-trot.toml"
ICUB_MAP = MAPS / "icub-walking.toml"

needs_logs = pytest.mark.skipif(
    not (GO1.is_file() and ICUB.is_file()),
    reason=f"robot logs missing in {ROBOTS} (set BODYHEALTH_ROBOTS_DIR to the folder holding go1-trot/ "
    "and icub-walking/)",
)

GO1_JOINTS = tuple(f"{leg}_{part}" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf"))
ICUB_JOINTS = (
    "neck_pitch neck_roll neck_yaw torso_pitch torso_roll torso_yaw l_shoulder_pitch l_shoulder_roll "
    "l_shoulder_yaw l_elbow r_shoulder_pitch r_shoulder_roll r_shoulder_yaw r_elbow l_hip_pitch l_hip_roll "
    "l_hip_yaw l_knee l_ankle_pitch l_ankle_roll r_hip_pitch r_hip_roll r_hip_yaw r_knee r_ankle_pitch "
    "r_ankle_roll"
).split()


@pytest.fixture(scope="module")
def go1():
    return import_log(GO1, GO1_MAP, "csv")


@pytest.fixture(scope="module")
def icub():
    return import_log(ICUB, ICUB_MAP, "mat")


@pytest.fixture(scope="module")
def go1_rows() -> list[dict[str, str]]:
    with open(GO1, newline="") as f:
        return list(csv.DictReader(f))


def _repeats(rows: list[dict[str, str]], cols: list[str]) -> int:
    """Rows whose ``cols`` read exactly as on the previous row (as text: no float parsing involved)."""
    vals = [tuple(r[c] for c in cols) for r in rows]
    return sum(a == b for a, b in itertools.pairwise(vals))


@needs_logs
def test_go1_imports_with_its_map(go1, go1_rows) -> None:
    rec, rep = go1
    assert rec.joint_names == GO1_JOINTS
    assert (rec.n_samples, rec.imu_names, rec.is_multirate, rec.qd) == (10148, ("trunk_imu",), False, None)
    t = np.array([float(r["Time(s)"]) for r in go1_rows])
    assert np.array_equal(rec.t, t)  # 42.58 s: no wall-clock origin to take off
    np.testing.assert_array_equal(rec.acc[:, 0, 1], [float(r["BaseAy"]) for r in go1_rows])
    np.testing.assert_array_equal(rec.q[:, 2], [float(r["JointPosFR_calf"]) for r in go1_rows])
    np.testing.assert_array_equal(rec.extra["foot_force"][:, 3], [float(r["RL_Force"]) for r in go1_rows])
    # README: 400 Hz, steps 2.4-3.4 ms; the stamps are printed to 0.1 ms, so each step is a multiple of
    # it up to the float error of two 6-digit numbers (< 1e-12 s).
    c = rep["clocks"]["Time(s)"]
    assert abs(c["median_step_s"] - 2.5e-3) < 1e-12 and abs(c["rate_hz"] - 400) < 1e-6
    assert abs(c["min_step_s"] - 2.4e-3) < 1e-12 and abs(c["max_step_s"] - 3.4e-3) < 1e-12
    assert c["gaps"]["count"] == 0 and c["jitter_std_s"] == pytest.approx(np.diff(t).std(), rel=1e-12)


@needs_logs
def test_go1_held_accelerometer_is_measured(go1, go1_rows) -> None:
    rec, rep = go1
    steps = rec.n_samples - 1
    acc, gyro = rep["streams"]["acc:trunk_imu"], rep["streams"]["gyro:trunk_imu"]
    n_acc = _repeats(go1_rows, ["BaseAx", "BaseAy", "BaseAz"])
    assert acc["repeated_rows"] == n_acc and acc["repeat_fraction"] == n_acc / steps
    # README's "49.5 %" is rounded to 0.1 %: the counted fraction lies within half of that.
    assert abs(acc["repeat_fraction"] - 0.495) <= 0.0005
    assert acc["update_rate_hz"] == pytest.approx((steps - n_acc) / (rec.t[-1] - rec.t[0]), rel=1e-12)
    assert 195 < acc["update_rate_hz"] < 205  # "about 200 Hz": half the 400 Hz rows carry a new value
    assert gyro["repeated_rows"] == _repeats(go1_rows, ["BaseWx", "BaseWy", "BaseWz"]) < 0.001 * steps
    assert acc["unit"] == "m/s^2" and acc["unit_assumed"] is False


@needs_logs
def test_go1_encoder_quantum_is_geared_not_a_power_of_two(go1) -> None:
    _, rep = go1
    hip = rep["encoders"]["FR_hip"]
    # The hip column is printed to 1 µrad: its one-count steps read 60 or 61 µrad, a geared 14-bit
    # encoder (2^14 counts through 6.33:1 = 2π/103,711 rad); the mean is known to ± the resolution.
    assert hip["resolution_rad"] == pytest.approx(1e-6)
    assert abs(hip["quantum_rad"] - 2 * math.pi / (2**14 * 6.33)) < hip["resolution_rad"]
    assert hip["matches_power_of_two"] is False and hip["bits"] == 17
    # Columns over 1 rad are printed to 10 µrad only: too coarse to decide at 5 %.
    assert rep["encoders"]["FR_calf"]["matches_power_of_two"] is None


@needs_logs
def test_icub_imports_with_its_map(icub) -> None:
    rec, rep = icub
    assert rec.joint_names == tuple(ICUB_JOINTS) and rec.imu_names == ("root_link_imu",)
    with h5py.File(ICUB, "r") as f:
        time = f["estimatorJointsTime"][()].ravel()
        origin = math.floor(time[0])
        assert int(rec.extra["stamp_origin_ns"]) == origin * 10**9
        assert np.array_equal(rec.t + origin, time)  # the whole-second shift is exact
        assert np.array_equal(rec.q, f["estimatorJointsPos"][()].T)
        assert np.array_equal(rec.qd, f["estimatorJointsVel"][()].T)  # measured velocities -> qd
        assert np.array_equal(rec.acc[:, 0], f["imuAcc"][()].T)
        assert np.array_equal(rec.gyro[:, 0], f["imuOmega"][()].T)
        assert np.array_equal(rec.extra["lf_wrench"], f["lfWrench"][()].T)
        assert np.array_equal(rec.extra["lf_force_z"], f["lfForceZ"][()].ravel())
    assert rep["extras"] == {
        "present": ["base_pos", "base_rot", "lf_force_z", "rf_force_z", "lf_wrench", "rf_wrench", "imu_rot"],
        "absent": [],
    }
    # README: median step 10.05 ms, 8.4-11.4 ms (rounded to 0.01 and 0.1 ms).
    c = rep["clocks"]["estimatorJointsTime"]
    assert abs(c["median_step_s"] - 10.05e-3) <= 0.005e-3
    assert abs(c["min_step_s"] - 8.4e-3) <= 0.05e-3 and abs(c["max_step_s"] - 11.4e-3) <= 0.05e-3


@needs_logs
def test_icub_encoder_quantum_is_2pi_over_4096(icub) -> None:
    _, rep = icub
    assert set(rep["encoders"]) == set(ICUB_JOINTS)
    for joint, e in rep["encoders"].items():
        assert e["bits"] == 12 and e["matches_power_of_two"] is True, joint
        assert abs(e["quantum_rad"] / (2 * math.pi / 4096) - 1) <= QUANTUM_SCALE_TOL, joint


@needs_logs
@pytest.mark.parametrize("which", ["go1", "icub"])
def test_round_trip_is_bit_for_bit(which: str, request, tmp_path) -> None:
    rec, rep = request.getfixturevalue(which)
    save_recording(rec, tmp_path / "rec.npz")
    back = load_recording(tmp_path / "rec.npz")
    for name in ("t", "q", "qd", "acc", "gyro", "gravity"):
        a, b = getattr(rec, name), getattr(back, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    assert (back.joint_names, back.imu_names) == (rec.joint_names, rec.imu_names)
    assert set(back.extra) == set(rec.extra)
    for k, v in rec.extra.items():
        w = back.extra[k]
        assert v.dtype == w.dtype and v.shape == w.shape and v.tobytes() == w.tobytes(), k
    assert json.loads(str(back.extra["import_report"])) == rep


def _copy_without(src: Path, dst: Path, drop: set[str]) -> None:
    """Another recording of the same robot: the MAT file with some datasets left out."""
    with h5py.File(src, "r") as a, h5py.File(dst, "w") as b:
        for k in a:
            if k not in drop and isinstance(a[k], h5py.Dataset) and not k.startswith("#"):
                a.copy(k, b)


@needs_logs
def test_a_recording_lacking_optional_extras_imports_with_the_same_map(tmp_path) -> None:
    other = tmp_path / "other.mat"
    _copy_without(ICUB, other, {"lfWrench", "rfWrench", "imuRot", "imgTime"})
    rec, rep = import_log(other, ICUB_MAP, "mat")
    assert rep["extras"]["absent"] == ["lf_wrench", "rf_wrench", "imu_rot"]
    assert "lf_wrench" not in rec.extra and rec.extra["base_pos"].shape == (8851, 3)


@needs_logs
def test_a_required_stream_missing_is_named_with_close_matches(tmp_path) -> None:
    other = tmp_path / "other.mat"
    _copy_without(ICUB, other, {"imuOmega"})
    with pytest.raises(MapError, match=r"^other.mat: unknown dataset 'imuOmega' \(imus\[0\]\.gyro\)") as err:
        import_log(other, load_map(ICUB_MAP), "mat")
    assert {"imuAcc", "imuRot"} <= set(str(err.value).split("close matches: ")[1].split(", "))


@needs_logs
def test_cli_json_is_the_report_kept_in_the_recording(tmp_path, capsys) -> None:
    out = tmp_path / "go1.npz"
    assert main(["import", "csv", str(GO1), "--map", str(GO1_MAP), "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["samples"], doc["joints"], doc["imus"], doc["multirate"]) == (10148, 12, 1, False)
    assert doc["report"] == json.loads(str(load_recording(out).extra["import_report"]))
    assert main(["import", "mat", str(ICUB), "--map", str(ICUB_MAP), "-o", str(tmp_path / "i.npz")]) == 0
    text = capsys.readouterr().out
    assert "acc:root_link_imu: m/s^2; repeats 0.6 % of rows" in text
    assert "26 with a quantum 2pi/2^bits" in text


MULTI_MAP = """
[clock]
unit = "ms"
[joints]
positions = "pos"
names = ["a", "b"]
unit = "deg"
velocities = "vel"
velocity_unit = "deg/s"
time = "t_enc"
[[imus]]
name = "imu0"
acc = ["ax", "ay", "az"]
acc_unit = "g"
gyro = "gyro"
time = "t_imu"
"""


def test_separate_clocks_make_a_multirate_recording_and_units_are_converted(tmp_path) -> None:
    """Encoders at 500 Hz and the IMU at 200 Hz on their own clocks (in ms), angles in degrees, the
    accelerometer in g: the recording holds SI units and the report says which units were stated."""
    te, ti = np.arange(50) * 2.0, np.arange(20) * 5.0 + 0.3
    rng = np.random.default_rng(7)
    pos, acc = rng.normal(size=(50, 2)), rng.normal(size=(20, 3))
    with h5py.File(tmp_path / "log.mat", "w") as f:
        for k, v in {"t_enc": te[:, None], "t_imu": ti[:, None], "pos": pos, "vel": 2 * pos,
                     "gyro": np.zeros((20, 3))}.items():  # fmt: skip
            f.create_dataset(k, data=v.T).attrs["MATLAB_class"] = np.bytes_(b"double")
        for i, axis in enumerate("xyz"):
            f.create_dataset(f"a{axis}", data=acc[:, i][None, :]).attrs["MATLAB_class"] = np.bytes_(b"double")
    (tmp_path / "map.toml").write_text(MULTI_MAP)
    rec, rep = import_log(tmp_path / "log.mat", tmp_path / "map.toml", "mat")
    assert rec.is_multirate and rec.t_q.shape == (50,) and rec.t.shape == (20,)
    np.testing.assert_allclose(rec.t_q, te * 1e-3, rtol=1e-15)
    np.testing.assert_allclose(rec.q, np.deg2rad(pos), rtol=1e-15)
    np.testing.assert_allclose(rec.qd, np.deg2rad(2 * pos), rtol=1e-15)
    np.testing.assert_allclose(rec.acc[:, 0], acc * 9.80665, rtol=1e-15)
    assert rep["clocks"]["t_enc"]["rate_hz"] == pytest.approx(500) and rep["clocks"]["t_imu"][
        "rate_hz"
    ] == pytest.approx(200)
    assert rep["streams"]["q"]["unit"] == "deg" and rep["streams"]["q"]["unit_assumed"] is False
    assert (rep["streams"]["gyro:imu0"]["unit"], rep["streams"]["gyro:imu0"]["unit_assumed"]) == (
        "rad/s",
        True,
    )
    assert rep["streams"]["gyro:imu0"]["repeat_fraction"] == 1.0  # an all-zero gyro: every row repeats
    assert rep["units"]["gravity"]["assumed"] is True and rep["units"]["time"] == {
        "unit": "ms",
        "assumed": False,
    }


def test_building_the_cli_parser_loads_no_log_reader() -> None:
    code = (
        "import sys\nfrom cli.main import build_parser\n"
        "build_parser().parse_args(['import', 'mat', 'x.mat', '--map', 'm.toml', '-o', 'o.npz'])\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('h5py', 'sim2real')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "[]"
