"""``Recording.validate``: each contract rule's message, and which rule speaks first when several break."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bodyschema.recording import Recording, RecordingError

T = 6


def _fields(**change: Any) -> dict[str, Any]:
    kw: dict[str, Any] = {
        "t": np.arange(T) * 0.01,
        "joint_names": ("a", "b"),
        "q": np.zeros((T, 2)),
        "imu_names": ("i0",),
        "acc": np.zeros((T, 1, 3)),
        "gyro": np.zeros((T, 1, 3)),
    }
    kw.update(change)
    return kw


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"t": np.array([0.0, 0.02, 0.01])}, "t goes backwards at index 2"),
        ({"t_q": np.arange(10) * 0.005 + 5.0, "q": np.zeros((10, 2))}, "do not overlap in time"),
        ({"joint_names": ("a", "a")}, "joint_names must be unique"),
        ({"imu_names": ("i", "i"), "acc": np.zeros((T, 2, 3))}, "imu_names must be unique"),
        ({"q": np.zeros((T, 3))}, "q must have shape (6, 2) (on t), got (6, 3)"),
        ({"t_q": np.arange(10) * 0.005}, "q must have shape (10, 2) (on t_q), got (6, 2)"),
        ({"qdd": np.full((T, 2), np.nan)}, "qdd contains NaN or Inf"),
        ({"gyro": np.zeros((T, 1, 2))}, "gyro must have shape (6, 1, 3), got (6, 1, 2)"),
        ({"gravity": np.zeros(2)}, "gravity must have shape (3,)"),
        ({"q": None}, "a recording needs joint positions q or a reference motion ref_quat"),
        ({"ref_quat": np.zeros((T, 3))}, "ref_quat must have shape (6, 4), got (6, 3)"),
        ({"ref_pos": np.zeros((T, 4))}, "ref_pos must have shape (6, 3), got (6, 4)"),
        ({"truth_joint_parent": ("x",)}, "truth_joint_parent must have one entry per joint"),
        ({"truth_imu_joint": ("x", "y")}, "truth_imu_joint must have one entry per IMU"),
    ],
)
def test_each_rule_names_its_field(change: dict[str, Any], message: str) -> None:
    with pytest.raises(RecordingError) as err:
        Recording(**_fields(**change))
    assert message in str(err.value)


def test_the_first_broken_rule_in_contract_order_is_reported() -> None:
    broken = {
        "joint_names": ("a", "a"),
        "q": np.zeros((T, 3)),
        "acc": np.zeros((T, 2, 3)),
        "gravity": np.zeros(2),
        "ref_pos": np.zeros((T, 4)),
        "truth_imu_joint": (),
    }
    order = ["joint_names", "q", "acc", "gravity", "ref_pos", "truth_imu_joint"]
    for i, name in enumerate(order):
        with pytest.raises(RecordingError, match=f"^{name} "):
            Recording(**_fields(**{k: broken[k] for k in order[i:]}))


def test_a_valid_recording_passes() -> None:
    rec = Recording(
        **_fields(ref_pos=np.zeros((T, 3)), truth_joint_parent=("x", "y"), truth_imu_joint=("a",))
    )
    assert (rec.n_samples, rec.n_joints, rec.n_imus) == (T, 2, 1)
