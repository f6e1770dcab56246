"""``sim2real`` on the two measured robot logs (Go1 trot, iCub walk) against their URDFs.

What must hold on each log: every named effect comes with a 95 % interval that contains its value;
the held-out gain per channel of the extended model against the rigid one; the iCub's encoder and
motion-capture predictions on the time offset and the mount rotation; and a recording lacking extras
runs with what it has and says what it could not do. Where a log falls short of a requirement the
test states the measured figure and is marked as an expected failure (strict: it fails the day the
model meets it, so the mark is removed then).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cli.main import main
from sim2real.robot_logs import import_log
from sim2real.robots import robot_sim2real
from tests.robot_data import MAPS, ROBOTS

GO1 = ROBOTS / "go1-trot"
ICUB = ROBOTS / "icub-walking"

needs_logs = pytest.mark.skipif(
    not ((GO1 / "go1.csv").is_file() and (ICUB / "sync-walkingFrontAndBackGoodTrial.mat").is_file()),
    reason=f"robot logs missing in {ROBOTS} (set BODYHEALTH_ROBOTS_DIR)",
)
#: The requirement: the extension removes at least this share of the rigid model's held-out
#: residual energy in a channel.
MIN_GAIN = 0.3


def _go1():
    return import_log(GO1 / "go1.csv", MAPS / "go1-trot.toml", "csv")[0]


def _icub():
    path = ICUB / "sync-walkingFrontAndBackGoodTrial.mat"
    return import_log(path, MAPS / "icub-walking.toml", "mat")[0]


def _intervals_hold(report: dict) -> None:
    """Every named IMU effect has one 95 % interval per parameter, containing its value."""
    for c in report["causes"]:
        if c["effect"] == "noise":
            continue
        values = np.ravel(next(iter(c["params"].values())))
        assert len(c["interval"]) == values.size, c["effect"]
        for v, (lo, hi) in zip(values, c["interval"], strict=True):
            assert lo <= v <= hi, (c["effect"], v, lo, hi)
    for e in report["robot_effects"]:
        if e.get("named") and "value" in e:
            for v, (lo, hi) in zip(e["value"], e["interval"], strict=True):
                assert lo <= v <= hi, e["effect"]


@pytest.fixture(scope="module")
def go1_result() -> dict:
    return robot_sim2real(_go1(), GO1 / "go1.urdf")


@needs_logs
def test_go1_names_effects_with_intervals_and_gains(go1_result: dict) -> None:
    out = go1_result
    assert set(out["predictions"]) == {"encoders"}
    rep = out["predictions"]["encoders"]
    _intervals_hold(rep)
    assert "time_offset" in [c["effect"] for c in rep["causes"]]
    gains = rep["held_out"]["channel_gain"]
    assert gains["gyro"] >= MIN_GAIN and gains["acc"] >= MIN_GAIN, gains
    # Point feet: the gyro is fully predicted only where three or more feet are down.
    assert 0.2 < rep["notes"]["gyro_fully_predicted"] < 0.8
    assert any("mocap" in c for c in out["could_not"])
    # The held accelerometer (updates at ~201 Hz in a 400 Hz log) is expected to lag by ~1.2 ms.
    delay = next(e for e in rep["robot_effects"] if e["effect"] == "acc_delay")
    assert delay["expected"] == pytest.approx(0.5 / 201.4 - 0.5 / 399.0, abs=1e-4)


@needs_logs
def test_go1_without_forces_says_what_it_could_not_do() -> None:
    rec = _go1()
    rec = replace(rec, extra={k: v for k, v in rec.extra.items() if k != "foot_force"})
    out = robot_sim2real(rec, GO1 / "go1.urdf")
    assert out["predictions"] == {}
    assert any("no foot forces" in c for c in out["could_not"])


@pytest.fixture(scope="module")
def icub_result() -> dict:
    return robot_sim2real(_icub(), ICUB / "iCubGenova04.urdf")


@needs_logs
@pytest.mark.slow
def test_icub_names_effects_with_intervals(icub_result: dict) -> None:
    out = icub_result
    assert set(out["predictions"]) == {"encoders", "mocap"}
    assert out["imu_mount"]["source"] == "sensor root_link_imu_acc"
    enc = out["predictions"]["encoders"]
    for rep in out["predictions"].values():
        _intervals_hold(rep)
    contacts = enc["notes"]["contacts"]
    # The README: 65 % double support and 13-14 % single stance per foot: each foot down ~0.79.
    assert all(0.7 < f < 0.95 for f in contacts["down_fraction"])
    names = [e["effect"] for e in enc["robot_effects"] if e.get("named")]
    assert "leg_compliance" in names
    assert enc["held_out"]["channel_gain"]["acc"] >= MIN_GAIN


@needs_logs
@pytest.mark.slow
def test_icub_gyro_gain(icub_result: dict) -> None:
    """The sole's compliance under the ground reaction's moment is what the rigid gyro missed most
    (it removed 0.21 of the residual with the joints' flex alone)."""
    assert icub_result["predictions"]["encoders"]["held_out"]["channel_gain"]["gyro"] >= MIN_GAIN


@needs_logs
@pytest.mark.slow
def test_icub_soles_turn_alike_under_their_moments(icub_result: dict) -> None:
    """Both feet's sole compliances, named per axis, have one sign and agree within a factor of two:
    the same foot on either leg, not a fit to noise. Where it was named, the accelerometer's bias
    beyond a sensor's datasheet is read as the model's error."""
    enc = icub_result["predictions"]["encoders"]
    (legs,) = [e for e in enc["robot_effects"] if e["effect"] == "leg_compliance"]
    value = dict(zip(legs["columns"], legs["value"], strict=True))
    unit = dict(zip(legs["columns"], legs["units"], strict=True))
    soles = sorted({c.split("[leg")[0] for c in value if "[sole_" in c})
    assert {"compliance[sole_x]", "compliance[sole_y]"} <= set(soles)
    for s in soles:
        a, b = value[f"{s}[leg 0]"], value[f"{s}[leg 1]"]
        assert a * b > 0 and 0.5 < a / b < 2.0, (s, a, b)
        assert unit[f"{s}[leg 0]"] == "rad/(N m)" and 1e-4 < abs(a) < 1e-2  # 0.06-6 deg at 10 N m
    for c in enc["causes"]:
        if c["effect"] == "acc_bias" and max(map(abs, c["params"]["vector"])) > 2.4:
            assert c["reading"].endswith("the rigid model's error on that axis")


@needs_logs
@pytest.mark.slow
def test_icub_time_offsets_close_over_the_encoders_and_vicon_clocks(icub_result: dict) -> None:
    """The IMU's offsets against the encoders and against the Vicon differ by the lag between the two
    predictions themselves (no IMU in it): the recording's two clocks, and a model that holds."""
    close = icub_result["agreement"]["time_offset"]["closure"]
    assert close["closes"]
    ((lo, hi),) = close["between_predictions"]["interval"]
    assert hi < 0  # the encoders run ahead of the Vicon: the offsets cannot agree
    assert lo <= close["expected"][0] <= hi


@needs_logs
@pytest.mark.slow
def test_icub_mount_rotations_close_over_the_turn_between_the_predictions(icub_result: dict) -> None:
    """Likewise the mount: the two estimates differ by the rotation between the predictions' base
    rates, on every axis."""
    assert icub_result["agreement"]["mounting_rotation"]["closure"]["closes"]


@needs_logs
@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="measured: with the soles' compliance in the model the encoders put the IMU 3.5 ms "
    "[2.3, 4.8] behind them, the Vicon 0.1 ms [-1.5, 1.7]; the encoders run 2.7 ms [1.6, 3.8] ahead "
    "of the Vicon",
)
def test_icub_predictions_agree_on_the_time_offset(icub_result: dict) -> None:
    """Encoders and Vicon, each the IMU's offset in its own final model: 95 % intervals overlap."""
    assert icub_result["agreement"]["time_offset"]["agree"]


@needs_logs
@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="measured: about x and y they agree; about z the encoders give +0.4 deg [-0.35, 1.15], "
    "the Vicon -0.9 deg [-1.34, -0.52]",
)
def test_icub_predictions_agree_on_the_mount_rotation(icub_result: dict) -> None:
    assert icub_result["agreement"]["mounting_rotation"]["agree"]


@needs_logs
@pytest.mark.slow
def test_icub_without_pose_or_wrenches_runs_on_encoders(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A shorter recording lacking the base pose, the wrenches and the IMU's own orientation."""
    from simulators.recording_io import save_recording

    rec = _icub()
    keep = slice(0, 2500)  # 25 s
    drop = {"base_pos", "base_rot", "lf_wrench", "rf_wrench", "imu_rot"}
    extra = {
        k: (v[keep] if v.ndim and v.shape[0] == rec.t.size else v)
        for k, v in rec.extra.items()
        if k not in drop
    }
    short = replace(
        rec, t=rec.t[keep], q=rec.q[keep], qd=None, acc=rec.acc[keep], gyro=rec.gyro[keep], extra=extra
    )
    path = tmp_path / "short.npz"
    save_recording(short, path)
    assert main(["sim2real", str(path), "--model", str(ICUB / "iCubGenova04.urdf"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["predictions"]) == {"encoders"}
    assert any("mocap" in c for c in out["could_not"])
    assert any(c.startswith("sole compliance: the recording has no foot wrenches") for c in out["could_not"])


@needs_logs
def test_a_urdf_of_another_robot_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from simulators.recording_io import save_recording

    path = tmp_path / "go1.npz"
    save_recording(_go1(), path)
    assert main(["sim2real", str(path), "--model", str(ICUB / "iCubGenova04.urdf")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none of the legs' joints" in err[0]
