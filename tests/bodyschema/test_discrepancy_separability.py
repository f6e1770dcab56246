"""Effects a recording cannot tell apart are named jointly, with a joint value whose interval covers
the truth; effects it can tell apart stay separate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.discrepancy import analyze, prepare
from bodyschema.discrepancy.effects import predict
from bodyschema.discrepancy.evidence import critical_wald
from bodyschema.discrepancy.separability import groups, joint_cut, overlaps, signature_columns
from bodyschema.rigid_motion import reference_motion, smooth_random_motion

BIAS = np.array([0.12, -0.08, 0.05])  # m/s², well above the detection limit at this noise


def _translation(seed: int):
    """60 s of smooth translation at 100 Hz with a fixed, tilted orientation (a translation trial)."""
    rng = np.random.default_rng(seed)
    m = smooth_random_motion(60.0, 100.0, rng, max_rate=3.0, max_accel=2.0)
    quat = np.tile(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_quat(scalar_first=True), (m["t"].size, 1))
    return reference_motion(m["t"], quat, m["pos"], cutoff=None), rng


def _rotation(seed: int):
    """The same translation while the sensor tumbles through attitudes far apart (yaw and roll all
    round, pitch up to ±80°): every axis sees gravity both ways."""
    rng = np.random.default_rng(seed)
    m = smooth_random_motion(60.0, 100.0, rng, max_rate=3.0, max_accel=2.0)
    t = m["t"]
    w = rng.uniform(0.3, 0.6, 3)
    angles = np.stack([np.pi * np.sin(w[0] * t), 1.4 * np.sin(w[1] * t + 1.0), np.pi * np.sin(w[2] * t)], 1)
    quat = Rotation.from_euler("zyx", angles).as_quat(scalar_first=True)
    return reference_motion(t, quat, m["pos"], cutoff=None), rng


def _readings(ref, rng: np.random.Generator, params: dict) -> tuple[np.ndarray, np.ndarray]:
    gyro, acc = predict(ref, params)
    return gyro + rng.normal(0.0, 0.002, gyro.shape), acc + rng.normal(0.0, 0.02, acc.shape)


def test_the_cut_follows_the_critical_value() -> None:
    """An unseen partner at its detection limit moves the named effect by 1.96 standard errors at the
    cut: rho sqrt(w) / sqrt(1 - rho^2) = z."""
    w = critical_wald(0.01 / 12, 3, 30)
    rho = joint_cut(w)
    assert rho * np.sqrt(w) / np.sqrt(1.0 - rho**2) == pytest.approx(1.959964, rel=1e-6)
    assert 0.3 < rho < 0.5


@pytest.mark.parametrize(("motion", "joint"), [(_translation, True), (_rotation, False)])
def test_bias_and_gravity_overlap_only_without_rotation(motion, joint: bool) -> None:
    ref, rng = motion(0)
    gyro, acc = _readings(ref, rng, {"acc_bias": {"vector": BIAS.tolist()}})
    prob = prepare(ref, gyro, acc, cutoff=None)
    sig = signature_columns(prob, {"acc_bias": {"vector": BIAS.tolist()}}, ["acc_bias", "gravity"], 2.0)
    (ov,) = overlaps(sig, ["acc_bias"], ["acc_bias", "gravity"], level=0.01 / 12)
    assert (ov.correlation > 0.99) if joint else (ov.correlation < ov.cut)
    assert groups([ov], ["acc_bias"]) == ([["acc_bias", "gravity"]] if joint else [])


def test_a_bias_without_rotation_is_named_jointly_with_gravity() -> None:
    """Without rotation the bias cannot be told from a gravity tilt: not named alone, but jointly, with
    the joint value (as an accelerometer bias) covering the truth."""
    ref, rng = _translation(1)
    gyro, acc = _readings(ref, rng, {"acc_bias": {"vector": BIAS.tolist()}})
    rep = analyze(ref, gyro, acc, cutoff=None)
    assert "acc_bias" not in rep.names and "gravity" not in rep.names
    j = rep.joint_cause("acc_bias")
    assert j is not None and {"acc_bias", "gravity"} <= set(j.effects), rep.joint_names
    assert j.effects[0] == "acc_bias" and "orientation" in j.separate_by
    lo, hi = np.array(j.interval).T
    assert np.all((lo <= BIAS) & (BIAS <= hi)), (j.params, j.interval)
    out = rep.to_json()
    assert out["joint"][0]["effect"] == j.label and out["joint"][0]["parametrization"] == "acc_bias"


def test_a_gravity_tilt_without_rotation_is_the_same_joint_value() -> None:
    """A hidden gravity tilt on the same motion reads as the bias it looks like: the joint value is the
    tilt carried over through the reported map."""
    ref, rng = _translation(2)
    g = Rotation.from_rotvec([0.01, -0.008, 0.0]).apply(ref.gravity)
    gyro, acc = _readings(ref, rng, {"gravity": {"vector": g.tolist()}})
    rep = analyze(ref, gyro, acc, cutoff=None)
    j = rep.joint_cause("gravity")
    assert j is not None and j.effects[0] == "acc_bias", (rep.names, rep.joint_names)
    want = np.asarray(j.maps["gravity"]) @ (g - ref.gravity)
    lo, hi = np.array(j.interval).T
    assert np.all((lo <= want) & (want <= hi)), (want, j.interval)


def test_with_rotation_bias_and_gravity_are_named_apart() -> None:
    """Tumbling separates the two: gravity is named alone with its tilt, and the bias is not named
    jointly with gravity (a lever arm, whose steady centripetal part looks like a bias, may still
    share its name) and keeps its value."""
    ref, rng = _rotation(3)
    g = Rotation.from_rotvec([0.01, -0.008, 0.0]).apply(ref.gravity)
    params = {"acc_bias": {"vector": BIAS.tolist()}, "gravity": {"vector": g.tolist()}}
    gyro, acc = _readings(ref, rng, params)
    rep = analyze(ref, gyro, acc, cutoff=None)
    assert "gravity" in rep.names, (rep.names, rep.joint_names)
    assert np.allclose(rep.cause("gravity").params["vector"], g, atol=0.003)
    j = rep.joint_cause("acc_bias")
    assert "acc_bias" in rep.names or "gravity" not in j.effects, rep.joint_names
    value = rep.cause("acc_bias").params if j is None else j.params
    assert np.allclose(value["vector"], BIAS, atol=0.003)
