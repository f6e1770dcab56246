"""The robot gravity case: Eq. 11 sensor networks leave a residual whose named cause is gravity."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.discrepancy import analyze
from bodyschema.discrepancy.network_gravity import gravity_case, topology_accuracy
from bodyschema.rigid_motion import ReferenceMotion, reference_motion, smooth_random_motion
from sim2real.report import robot_references
from simulators.simulation import simulate


def test_topology_accuracy_counts_parents_and_imus() -> None:
    truth_p, truth_i = {"a": None, "b": "a", "c": "b"}, {"i0": "a", "i1": "b", "i2": "c", "i3": None}
    assert topology_accuracy(truth_p, truth_i, truth_p, truth_i) == {
        "exact": True,
        "joint_parent": 1.0,
        "imu_joint": 1.0,
    }
    acc = topology_accuracy({"a": None, "b": None, "c": "b"}, {**truth_i, "i2": "b"}, truth_p, truth_i)
    assert acc == {"exact": False, "joint_parent": pytest.approx(2 / 3), "imu_joint": 0.75}


def test_a_gravity_free_reference_gets_the_whole_gravity_named(rng: np.random.Generator) -> None:
    # the measured IMU feels gravity (any direction, 9.81); the reference predicts without it, as Eq. 11
    g = rng.normal(size=3)
    g *= 9.81 / np.linalg.norm(g)
    m = smooth_random_motion(20.0, 100.0, rng)
    ref = reference_motion(m["t"], m["quat"], m["pos"], g, cutoff=10.0)
    measured_acc = np.einsum("tji,tj->ti", ref.R, ref.acc_world - g)
    free = ReferenceMotion(ref.t, ref.R, ref.omega, ref.acc_world, np.zeros(3))
    rep = analyze(free, ref.omega, measured_acc)
    assert rep.names[0] == "gravity"
    fit = np.asarray(rep.params["gravity"]["vector"])
    assert np.allclose(fit, g, atol=0.02), (fit, g)
    assert rep.residual_before["acc_rms"] > 3.0 and rep.residual_after["acc_rms"] < 0.02
    st = rep.structure_before["acc"]["r2"]["orientation"]  # a world-fixed residual: the orientation family
    assert min(st) > 0.99


@pytest.mark.slow
def test_eq11_leaves_gravity_which_eq24_removes(seed: int) -> None:
    # a fixed recording (the network training is what takes time); the seed drives the networks.
    # 30 s is enough for every bound below: the gap between the forms is a share of gravity the
    # networks cannot absorb (about 1-2 m/s²) against the sensor's own errors (0.1-0.2 m/s²), which the
    # length does not change; the held-out selection keeps 8 blocks of 3.75 s (375 samples each); and
    # the fitted magnitude's error from 0.1 m/s² noise over 3000 samples is far under the 8 % allowed.
    # (On 60 s the training and the two analyses took twice the CPU for the same verdicts.)
    rec = simulate("ur5e", seconds=30.0, seed=7, imu_model="mpu6050")
    net_seed = seed % 1000
    imus = ["imu2", "imu5", "imu8", "imu11"]  # one per moving link group, off the vertical-axis base link
    case = gravity_case(rec, seed=net_seed, imus=imus, references=robot_references(rec, "ur5e"))
    eq11, eq24 = case.forms["eq11"], case.forms["eq24"]
    # the residual: without the gravity term the networks absorb part of gravity in bent accelerations
    # but leave about 1-2 m/s² (1.76 on this recording at this test's seed, 19 times Eq. 24's); with it
    # the sensor's own errors and the network's fit remain (0.1-0.2 m/s²)
    assert eq11.acc_rms > 4 * eq24.acc_rms
    assert eq11.acc_rms > 0.5
    # the cause, on the exact kinematics: gravity, with the recording's magnitude and direction
    kin = case.analyses["kinematics"]
    for imu in imus:
        assert "gravity" in kin.named[imu], (imu, kin.named[imu])
    g = kin.cause("gravity")
    assert g is not None
    assert g["params"]["norm"] == pytest.approx(9.81, rel=0.08)
    assert g["params"]["angle_to_recording_deg"] < 8.0
    # ... while on the Eq. 11 networks themselves, which bend their accelerations and biases towards
    # it, what is named is not gravity's magnitude: under 1 m/s² in the bench gravity runs with the
    # earlier selection, 6.0 m/s² here with the evidence-based one (this test's seed; 2.3 to 9.2 per IMU)
    gn = case.analyses["network"].cause("gravity")
    assert gn is None or abs(gn["params"]["norm"] - 9.81) > 1.0, gn
    # topology: Eq. 24 at least as accurate as Eq. 11
    a11, a24 = eq11.accuracy, eq24.accuracy
    assert a24["joint_parent"] >= a11["joint_parent"] and a24["imu_joint"] >= a11["imu_joint"]
    assert a24["imu_joint"] > 0.8
    d = case.to_json()
    assert d["residual_gain"]["acc"] > 0.9
    # the "Eq. 11 + named effects" trace exists exactly when the analysis named effects on the network
    trace_imu = case.settings["trace_imu"]
    worst_named = set(case.analyses["network"].reports[trace_imu].params) - {"noise"}
    assert set(case.traces) == {"t", "eq11", "eq24"} | ({"eq11_fitted"} if worst_named else set())
