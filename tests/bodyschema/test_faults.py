"""Fault injection: each fault changes exactly what it says, from its start on, and is recorded."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.faults import FaultError, inject, inject_all, injected_faults, parse_fault
from bodyschema.recording import Recording
from simulators.recording_io import load_recording, save_recording


def _rec(n: int = 400, qd: bool = True) -> Recording:
    t = np.arange(n) * 0.01
    rng = np.random.default_rng(3)
    q = np.c_[np.sin(t), 0.5 + 0.3 * np.cos(2 * t), -0.4 * np.sin(3 * t)]
    acc = rng.normal(0, 0.05, (n, 1, 3)) + np.array([0.0, 0.0, 9.81])
    gyro = rng.normal(0, 0.2, (n, 1, 3))
    kw = {"qd": np.gradient(q, t, axis=0)} if qd else {}
    return Recording(t=t, joint_names=("a", "b", "c"), q=q, imu_names=("base",), acc=acc, gyro=gyro, **kw)


def test_encoder_frozen_holds_last_reading_and_zeroes_rates():
    rec = _rec()
    out = inject(rec, parse_fault("encoder_frozen:joint=b,at=1.5"))
    i = 150
    assert np.all(out.q[i:, 1] == rec.q[i - 1, 1])
    assert np.all(out.qd[i:, 1] == 0.0)
    np.testing.assert_array_equal(out.q[:i], rec.q[:i])
    np.testing.assert_array_equal(out.q[:, [0, 2]], rec.q[:, [0, 2]])
    np.testing.assert_array_equal(out.acc, rec.acc)


def test_encoder_offset_adds_degrees_from_start_only():
    rec = _rec()
    out = inject(rec, parse_fault("encoder_offset:joint=a,deg=2,at=1"))
    d = out.q[:, 0] - rec.q[:, 0]
    np.testing.assert_allclose(d[100:], np.radians(2.0), rtol=0, atol=1e-15)
    assert np.all(d[:100] == 0.0)
    np.testing.assert_array_equal(out.qd, rec.qd)  # an offset leaves the rates alone


def test_encoder_sign_flips_reading_and_rates():
    rec = _rec()
    out = inject(rec, parse_fault("encoder_sign:joint=c"))
    np.testing.assert_array_equal(out.q[:, 2], -rec.q[:, 2])
    np.testing.assert_array_equal(out.qd[:, 2], -rec.qd[:, 2])
    np.testing.assert_array_equal(out.q[:, :2], rec.q[:, :2])
    assert rec.q[5, 2] != out.q[5, 2]  # the input is untouched


@pytest.mark.parametrize(("axis", "vec"), [("x", (1, 0, 0)), ("y", (0, 1, 0)), ("z", (0, 0, 1))])
def test_imu_rotated_turns_both_readings(axis, vec):
    rec = _rec()
    out = inject(rec, parse_fault(f"imu_rotated:imu=base,deg=2,axis={axis},at=2"))
    a, b = rec.acc[200:, 0], out.acc[200:, 0]
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    v = np.asarray(vec, float)
    # the component along the axis is kept, the angle about it is 2 deg
    np.testing.assert_allclose(b @ v, a @ v, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), np.linalg.norm(a, axis=1), rtol=1e-12)
    assert np.all(np.degrees(np.arccos(np.clip(cos, -1, 1))) <= 2.0 + 1e-9)
    g_perp = rec.gyro[200:, 0] - np.outer(rec.gyro[200:, 0] @ v, v)
    o_perp = out.gyro[200:, 0] - np.outer(out.gyro[200:, 0] @ v, v)
    ang = np.degrees(np.arctan2(np.cross(g_perp, o_perp) @ v, np.sum(g_perp * o_perp, axis=1)))
    np.testing.assert_allclose(ang, 2.0, atol=1e-9)
    np.testing.assert_array_equal(out.gyro[:200], rec.gyro[:200])


def test_imu_silent_repeats_last_reading_then_resumes():
    rec = _rec()
    out = inject(rec, parse_fault("imu_silent:imu=base,seconds=0.5,at=1"))
    np.testing.assert_array_equal(out.acc[100:150, 0], np.tile(rec.acc[99, 0], (50, 1)))
    np.testing.assert_array_equal(out.gyro[100:150, 0], np.tile(rec.gyro[99, 0], (50, 1)))
    np.testing.assert_array_equal(out.acc[150:], rec.acc[150:])
    assert injected_faults(out)[0]["stop_s"] == pytest.approx(1.5)


def test_random_start_is_seeded_and_recorded(tmp_path):
    rec = _rec()
    f = parse_fault("encoder_offset:joint=a,deg=1,at=random")
    a, b, c = inject(rec, f, seed=7), inject(rec, f, seed=7), inject(rec, f, seed=8)
    np.testing.assert_array_equal(a.q, b.q)
    assert injected_faults(a)[0]["start_s"] != injected_faults(c)[0]["start_s"]
    both = inject_all(rec, [f, parse_fault("encoder_sign:joint=b")], seed=7)
    save_recording(both, tmp_path / "x.npz")
    back = load_recording(tmp_path / "x.npz")
    np.testing.assert_array_equal(back.q, both.q)
    assert [x["kind"] for x in injected_faults(back)] == ["encoder_offset", "encoder_sign"]
    assert injected_faults(back)[0]["start_s"] == injected_faults(a)[0]["start_s"]


@pytest.mark.parametrize(
    "spec",
    ["bogus:joint=a", "encoder_offset:joint=a", "encoder_sign:joint=a,deg=1",
     "imu_rotated:imu=base,deg=2,axis=w", "encoder_offset:joint=a,deg=x", "encoder_sign:joint"],
)  # fmt: skip
def test_bad_specs_refused(spec):
    with pytest.raises(FaultError):
        parse_fault(spec)


def test_unknown_joint_and_late_start_refused():
    rec = _rec()
    with pytest.raises(FaultError, match="unknown joint"):
        inject(rec, parse_fault("encoder_sign:joint=zz"))
    with pytest.raises(FaultError, match="after the encoder stream ends"):
        inject(rec, parse_fault("encoder_sign:joint=a,at=100"))


def test_cli_inject_round_trips(tmp_path, capsys):
    from cli.main import main

    save_recording(_rec(), tmp_path / "a.npz")
    rc = main(
        ["inject", str(tmp_path / "a.npz"), "--fault", "encoder_sign:joint=b", "-o", str(tmp_path / "b.npz")]
    )
    assert rc == 0
    assert injected_faults(load_recording(tmp_path / "b.npz"))[0]["params"] == {"joint": "b"}
    rc = main(
        ["inject", str(tmp_path / "a.npz"), "--fault", "encoder_sign:joint=q", "-o", str(tmp_path / "c.npz")]
    )
    assert rc == 2 and not (tmp_path / "c.npz").exists()
    assert "unknown joint 'q'" in capsys.readouterr().err
