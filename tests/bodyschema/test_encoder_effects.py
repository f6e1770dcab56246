"""Encoder effects seen through the IMUs, on a synthetic arm whose motion and readings are exact.

The arm: a vertical base joint, then two parallel horizontal joints, an IMU on every link; each IMU
has its own affine errors (gyro matrix and bias, accelerometer gains and biases: the analysis fits
them out) and white noise. Fixed seeds; the hidden-effect suite on simulated robots is in
tests/sim2real/test_encoder_hidden.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.discrepancy.encoders import EncoderOptions, analyze_encoders, predict_imus
from bodyschema.forward_kinematics import RobotChain
from bodyschema.recording import Recording

G = np.array([0.0, 0.0, -9.81])


def _chain() -> RobotChain:
    imu_R = np.array([np.eye(3), np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.eye(3)])
    return RobotChain(
        joint_names=("base", "shoulder", "elbow"),
        parent=(None, 0, 1),
        axis=np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]]),
        point=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3], [0.4, 0.0, 0.3]]),
        imu_names=("imu0", "imu1", "imu2"),
        imu_joint=(0, 1, 2),
        imu_R=imu_R,
        imu_p=np.array([[0.05, 0.0, 0.2], [0.2, 0.05, 0.3], [0.6, -0.05, 0.3]]),
    )


def _recording(seed: int, *, seconds: float = 40.0, tau: float = 0.0, gain=(1.0, 1.0, 1.0), offset=(0, 0, 0)):
    """A recording with encoders at 250 Hz (14-bit) and IMUs at 100 Hz on stamps of their own, where
    the encoders read ``gain * theta + offset`` and the IMU samples lag them by ``tau``."""
    rng = np.random.default_rng(seed)
    t_q = np.arange(0.0, seconds, 1 / 250)
    freq = rng.uniform(0.2, 1.2, (3, 3))
    phase = rng.uniform(0, 2 * np.pi, (3, 3))

    def theta(tt: np.ndarray) -> np.ndarray:
        return np.stack(
            [0.4 * np.sin(2 * np.pi * freq[j] * tt[:, None] + phase[j]).sum(1) for j in range(3)], 1
        )

    t = np.arange(0.3, seconds - 0.3, 1 / 100)
    fine = np.arange(0.0, seconds, 1 / 1000)
    imu = predict_imus(_chain(), t - tau, fine, theta(fine), G)
    A = np.eye(3) + rng.normal(0.0, 0.01, (3, 3, 3))
    gyro = np.einsum("kab,tkb->tka", A, imu[:, :, :3]) + rng.normal(0, 0.02, (3, 3))
    gyro += rng.normal(0.0, 0.003, gyro.shape)
    acc = imu[:, :, 3:] * rng.uniform(0.98, 1.02, (3, 3)) + rng.normal(0, 0.3, (3, 3))
    acc += rng.normal(0.0, 0.03, acc.shape)
    lsb = 2 * np.pi / 2**14
    q = np.round((theta(t_q) * np.asarray(gain) + np.asarray(offset)) / lsb) * lsb
    names = _chain().joint_names
    return Recording(t=t, joint_names=names, q=q, imu_names=_chain().imu_names, acc=acc, gyro=gyro, t_q=t_q)


def _analyze(rec: Recording, **opts):
    return analyze_encoders(_chain(), rec, EncoderOptions(**opts))


def test_nothing_is_named_on_an_arm_whose_encoders_are_right() -> None:
    rep = _analyze(_recording(0))
    assert rep.names == []
    # a base offset turns the whole arm about gravity: nothing any IMU reads changes
    base = rep.limit("encoder_offset[base]")
    assert base is not None and not base.observable
    assert "encoder_offset[base]: not named, no IMU reading changes with it here" in rep.summary()
    limits = {x.name: x.detection_limit for x in rep.not_named if x.observable}
    assert len(limits) == 9  # the time offset, 2 offsets, 3 gains, 3 dead bands
    assert 0.0 < limits["encoder_scale[shoulder]"] < 0.01
    assert 0.0 < limits["encoder_time_offset"] < 0.002


@pytest.mark.parametrize(
    ("kwargs", "name", "truth"),
    [
        ({"gain": (1.0, 1.0, 1.03)}, "encoder_scale[elbow]", 1.03),
        ({"tau": 0.01}, "encoder_time_offset", 0.01),
        ({"offset": (0.0, 0.02, 0.0)}, "encoder_offset[shoulder]", 0.02),
    ],
)
def test_a_hidden_encoder_effect_is_named_alone_with_its_value(kwargs: dict, name: str, truth: float) -> None:
    rep = _analyze(_recording(1, **kwargs))
    assert rep.names == [name]
    (cause,) = rep.causes
    assert abs(cause.value - truth) <= 3 * cause.stderr
    assert cause.interval[0] < truth < cause.interval[1]
    assert cause.p_value < 1e-6 and cause.detection_limit < abs(truth - (1.0 if "scale" in name else 0.0))


def test_bad_input_is_refused_with_a_clear_error() -> None:
    import dataclasses

    rec = _recording(2, seconds=30.0)
    two = dataclasses.replace(rec, joint_names=("base", "shoulder"), q=rec.q[:, :2])
    with pytest.raises(ValueError, match=r"joints \['elbow'\] of the model are not in the recording"):
        analyze_encoders(_chain(), two)
    other = dataclasses.replace(rec, imu_names=("a", "b", "c"))
    with pytest.raises(ValueError, match="none of the recording's IMUs"):
        analyze_encoders(_chain(), other)
    bad = rec.acc.copy()
    bad[100, 1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        analyze_encoders(_chain(), dataclasses.replace(rec, acc=bad))
    short = rec.window(0.0, 20.0)
    with pytest.raises(ValueError, match="too short"):
        analyze_encoders(_chain(), short)


def test_the_imus_the_model_carries_are_compared_in_the_recording_s_order() -> None:
    import dataclasses

    rec = _recording(1, gain=(1.0, 1.0, 1.03))
    order = [2, 0, 1]
    shuffled = dataclasses.replace(
        rec,
        imu_names=tuple(rec.imu_names[i] for i in order),
        acc=rec.acc[:, order],
        gyro=rec.gyro[:, order],
        joint_names=rec.joint_names[::-1],
        q=rec.q[:, ::-1],
    )
    a, b = _analyze(rec), _analyze(shuffled)
    assert a.names == b.names == ["encoder_scale[elbow]"]
    assert a.causes[0].value == pytest.approx(b.causes[0].value, abs=1e-9)
    assert b.meta["imu_names"] == ["imu2", "imu0", "imu1"]


def test_the_jacobian_computed_per_imu_is_the_full_central_difference() -> None:
    # a joint's column is computed on the IMUs below it only; the others must be exactly zero, and
    # a column taken over from the last Jacobian at the same point must be the one computed there
    from bodyschema.discrepancy.encoders import _Problem

    rec = _recording(3, seconds=30.0, gain=(1.0, 1.01, 1.0))
    prob = _Problem(
        _chain(),
        rec.encoder_t,
        rec.q,
        rec.t,
        np.concatenate([rec.gyro, rec.acc], axis=2),
        G,
        EncoderOptions(),
    )
    x = prob.null.copy()
    which = list(range(len(prob.candidates)))
    J, r0 = prob.jacobian(x, which)
    for i, c in enumerate(which):
        xp, xm = x.copy(), x.copy()
        xp[c] += prob.step[c]
        xm[c] -= prob.step[c]
        full = (prob._residual(xp) - prob._residual(xm)) / (2 * prob.step[c])
        assert np.allclose(J[..., i], full, rtol=1e-9, atol=1e-9 * np.abs(full).max())
        assert np.array_equal(J[..., i] == 0.0, full == 0.0)
    J2, r2 = prob.jacobian(x, which[::-1])
    assert np.array_equal(J2, J[..., ::-1]) and np.array_equal(r2, r0)
