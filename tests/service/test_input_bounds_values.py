"""Value bounds of every frame batch and of the API's bodies: stamps within 100 years of the epoch,
accelerometer and gyro readings within 4x the widest MPU-6050 range, joint positions and rates bounded,
NaN and infinities named with the stream and the first index, numbers that are numbers (``true`` is
not 1.0), joints and IMUs per robot capped, JSON nesting bounded. Whatever is refused, what was
accepted before stays stored. Real app, real SQLite store in tmp_path."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.api.security import MAX_JSON_DEPTH
from service.frames import ACC_LIMIT, GYRO_LIMIT, Q_LIMIT, QD_LIMIT, T_LIMIT, FrameBatch, FrameError
from service.ingest.base import Source
from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import Store
from tests.service.access import StrictFarm
from tests.service.builders import frame_batch, frames_body, simulated_store

URL = "/api/v1/robots/arm/frames"
SETTINGS = Settings(database_url="sqlite://", max_joints_per_robot=4, max_imus_per_robot=3)


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = simulated_store(tmp_path / "values.db")
    yield s
    s.close()


@pytest.fixture
def farm() -> StrictFarm:
    return StrictFarm()


@pytest.fixture
def client(store: Store, farm: StrictFarm) -> TestClient:
    return TestClient(create_app(store, settings=SETTINGS, damage=farm))


def test_the_bounds_are_the_stated_ones() -> None:
    assert T_LIMIT == 100 * 365.25 * 86400 == 3_155_760_000.0  # 100 Julian years, s
    assert ACC_LIMIT == pytest.approx(4 * 16 * 9.80665)  # 627.6 m/s²
    assert GYRO_LIMIT == pytest.approx(math.radians(4 * 2000))  # 139.6 rad/s
    assert (Q_LIMIT, QD_LIMIT) == (1e6, 1e4)
    # float64 still resolves a microsecond at the edge of the stamp span
    assert np.spacing(T_LIMIT) < 1e-6


def good_body() -> dict[str, Any]:
    body = frames_body(3, t0=2.0, seed=3)
    body["acc"][0][0] = [0.0, 0.0, 9.81]
    return body


@pytest.mark.parametrize(
    ("field", "index", "value", "message"),
    [
        ("t", (0,), 1e308, "less than or equal to 3155760000"),
        ("t", (2,), T_LIMIT * 1.0001, "less than or equal to 3155760000"),
        ("acc", (1, 0, 2), 1e308, "less than or equal to 627.6"),
        ("acc", (2, 1, 0), -ACC_LIMIT - 1, "greater than or equal to -627.6"),
        ("gyro", (0, 1, 1), GYRO_LIMIT + 0.5, "less than or equal to 139.6"),
        ("q", (1, 1), -2e6, "greater than or equal to -1000000"),
    ],
)
def test_values_beyond_their_bound_are_422_naming_the_sample(
    client: TestClient, store: Store, field: str, index: tuple[int, ...], value: float, message: str
) -> None:
    assert client.post(URL, json=good_body()).status_code == 201
    before = store.sample_count("arm")
    body = frames_body(3, t0=3.0, seed=4)
    row = body[field]
    for i in index[:-1]:
        row = row[i]
    row[index[-1]] = value
    resp = client.post(URL, json=body)
    assert resp.status_code == 422, resp.text
    (err,) = resp.json()["detail"]
    assert err["loc"] == ["body", field, *index]
    assert message in err["msg"]
    assert store.sample_count("arm") == before == 3


def test_values_at_their_bound_are_accepted(client: TestClient, store: Store) -> None:
    body = frames_body(2, t0=T_LIMIT - 1.0)
    body["acc"][0][0] = [ACC_LIMIT, -ACC_LIMIT, 0.0]
    body["gyro"][1][1] = [0.0, GYRO_LIMIT, -GYRO_LIMIT]
    body["q"][0] = [Q_LIMIT, -Q_LIMIT]
    assert client.post(URL, json=body).status_code == 201, client.post(URL, json=body).text
    assert store.sample_count("arm") == 2


@pytest.mark.parametrize("raw", [b"true", b"false", b'"1.0"', b"null"])
def test_only_numbers_are_numbers(client: TestClient, store: Store, raw: bytes) -> None:
    marker = 123.25
    for field, index in (("t", (1,)), ("q", (0, 1)), ("acc", (2, 0, 1)), ("gyro", (1, 1, 2))):
        body = frames_body(3, t0=1.0)
        row = body[field]
        for i in index[:-1]:
            row = row[i]
        row[index[-1]] = marker
        text = json.dumps(body).encode().replace(b"123.25", raw)
        resp = client.post(URL, content=text, headers={"content-type": "application/json"})
        assert resp.status_code == 422, resp.text
        (err,) = resp.json()["detail"]
        assert err["loc"] == ["body", field, *index] and err["type"] == "float_type"
    assert store.robot("arm") is None
    # integers are numbers
    ints = json.dumps(frames_body(3, t0=1.0)).encode().replace(b"1.0,", b"1,", 1)
    assert client.post(URL, content=ints, headers={"content-type": "application/json"}).status_code == 201


def test_damage_numbers_are_strict_and_bounded(client: TestClient, farm: StrictFarm) -> None:
    url = "/api/v1/robots/sim/simulate/damage"
    for value in (True, "0.1", 7.0, -6.3):
        resp = client.post(url, json={"kind": "encoder_fault", "mode": "offset", "value": value})
        assert resp.status_code == 422, value
        assert resp.json()["detail"][0]["loc"] == ["body", "value"]
    for body in ({"kind": "imu_detached", "tether": True}, {"kind": "imu_rotated", "about": [1, True, 0]}):
        assert client.post(url, json=body).status_code == 422, body
    assert farm.calls == []
    ok = client.post(url, json={"kind": "encoder_fault", "mode": "offset", "value": 1})
    assert ok.status_code == 201 and farm.calls == [
        ("sim", "encoder_fault", {"mode": "offset", "value": 1.0})
    ]


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity"])
def test_nan_and_infinity_are_named_with_the_first_index(
    client: TestClient, store: Store, token: str
) -> None:
    body = frames_body(3, t0=1.0)
    body["gyro"][2][1][0] = 123.25
    text = json.dumps(body).replace("123.25", token)
    resp = client.post(URL, content=text, headers={"content-type": "application/json"})
    assert resp.status_code == 422
    (err,) = resp.json()["detail"]
    assert err["loc"] == ["body", "gyro", 2, 1, 0] and err["type"] == "finite_number"
    assert store.robot("arm") is None


@pytest.mark.parametrize(
    ("field", "index", "value", "message"),
    [
        ("t", (1,), np.nan, r"t contains NaN or Inf: first at \[1\]"),
        ("acc", (1, 0, 2), np.inf, r"acc contains NaN or Inf: first at \[1, 0, 2\]"),
        ("gyro", (2, 0, 1), 200.0, r"gyro\[2, 0, 1\] = 200 rad/s is beyond the bound of ±139.6 rad/s"),
        ("acc", (0, 0, 0), -700.0, r"acc\[0, 0, 0\] = -700 m/s² is beyond the bound of ±627.6 m/s²"),
        ("q", (2, 0), 3e6, r"q\[2, 0\] = 3e\+06 rad is beyond the bound of ±1e\+06 rad"),
        ("t", (2,), -4e9, r"t\[2\] = -4e\+09 s is beyond the bound of ±3.156e\+09 s"),
    ],
)
def test_every_source_is_held_to_the_bounds(
    store: Store, field: str, index: tuple[int, ...], value: float, message: str
) -> None:
    """Device sources hand in FrameBatch objects: the same bounds are in its validate(), which the
    pipeline and the store both run. (Negative stamps are allowed there: device clocks may start
    early.)"""
    t = np.array([-0.02, -0.01, 0.0]) if field != "t" else np.array([0.0, 0.01, 0.02])
    b = frame_batch("arm", t.copy())
    getattr(b, field)[index] = value
    with pytest.raises(FrameError, match=message):
        b.validate()
    pipe = Pipeline(store, [], settings=SETTINGS)
    with pytest.raises(FrameError, match=message):
        pipe.submit(b)
    assert pipe.counters()["api"]["malformed"] == 3 and store.robot("arm") is None
    frame_batch("arm", t).validate()  # the same batch without the bad value passes


def test_qd_is_bounded_too() -> None:
    t = np.array([0.0, 0.01])
    b = frame_batch("arm", t)
    qd = np.zeros((2, 1))
    qd[1, 0] = -2e4
    bad = FrameBatch("arm", t, b.joint_names, b.q, b.imu_names, b.acc, b.gyro, qd=qd)
    with pytest.raises(FrameError, match=r"qd\[1, 0\] = -20000 rad/s is beyond the bound of ±1e\+04 rad/s"):
        bad.validate()


# ------------------------------------------------------------------------------------ part caps
def parts_body(joints: list[str], imus: list[str], t0: float = 1.0) -> dict[str, Any]:
    n = 2
    return {
        "t": [t0, t0 + 0.01],
        "joint_names": joints,
        "q": [[0.0] * len(joints)] * n,
        "imu_names": imus,
        "acc": [[[0.0, 0.0, 9.81]] * len(imus)] * n,
        "gyro": [[[0.0, 0.0, 0.0]] * len(imus)] * n,
    }


def test_parts_per_robot_are_capped_in_a_batch_and_in_all(client: TestClient, store: Store) -> None:
    # one batch over the cap (4 joints, 3 IMUs here)
    resp = client.post(URL, json=parts_body([f"j{k}" for k in range(5)], ["i0"]))
    assert resp.status_code == 422
    assert resp.json()["detail"] == "robot 'arm' would have 5 joints (at most 4, max_joints_per_robot)"
    resp = client.post(URL, json=parts_body(["j0"], [f"i{k}" for k in range(4)]))
    assert resp.json()["detail"] == "robot 'arm' would have 4 IMUs (at most 3, max_imus_per_robot)"
    assert store.robot("arm") is None
    # within the cap, then batches that would add parts past it: the robot stays as it was
    assert client.post(URL, json=parts_body(["j0", "j1", "j2"], ["i0", "i1"])).status_code == 201
    assert client.post(URL, json=parts_body(["j3"], ["i2"], t0=2.0)).status_code == 201  # 4 and 3: at the cap
    resp = client.post(URL, json=parts_body(["j4"], ["i3"], t0=3.0))
    assert resp.status_code == 422
    assert resp.json()["detail"] == (
        "robot 'arm' would have 5 joints (at most 4, max_joints_per_robot) and 4 IMUs (at most 3, "
        "max_imus_per_robot)"
    )
    info = store.robot("arm")
    assert sorted(info.joints) == ["j0", "j1", "j2", "j3"] and sorted(info.imus) == ["i0", "i1", "i2"]
    assert store.sample_count("arm") == 4
    # the parts it has keep streaming
    assert client.post(URL, json=parts_body(["j0", "j3"], ["i1"], t0=4.0)).status_code == 201


class Listed(Source):
    """A device source that hands in the given batches once."""

    exhausted = False

    def __init__(self, batches: list[FrameBatch]) -> None:
        super().__init__("dev")
        self._batches = batches

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        self.exhausted = True
        return self._batches


def test_a_device_that_makes_up_parts_is_capped(store: Store) -> None:
    t = np.arange(3) * 0.01
    batches = [frame_batch("dev1", t + k, joints=(f"j{k}",), imus=("imu0",)) for k in range(6)]
    src = Listed(batches)
    with Pipeline(store, [src], settings=SETTINGS) as pipe:
        assert pipe.wait_exhausted(timeout=30)
    assert src.counters.as_dict() == {"received": 18, "stored": 12, "dropped": 0, "malformed": 6}
    assert sorted(store.robot("dev1").joints) == ["j0", "j1", "j2", "j3"]


# ------------------------------------------------------------------------------------ JSON depth
def test_deeply_nested_json_is_422_saying_so(client: TestClient, store: Store) -> None:
    assert client.post(URL, json=good_body()).status_code == 201
    for depth in (MAX_JSON_DEPTH + 1, 1000, 100_000):
        raw = b"[" * depth + b"]" * depth
        for url in (URL, "/api/v1/robots/sim/simulate/damage"):
            resp = client.post(url, content=raw, headers={"content-type": "application/json"})
            assert resp.status_code == 422, (depth, resp.text)
            assert resp.json()["detail"] == [
                {
                    "loc": ["body"],
                    "msg": f"JSON nested deeper than {MAX_JSON_DEPTH} levels",
                    "type": "json_invalid",
                }
            ]
    # a body at the bound is parsed (and refused for what it is: not a frames object)
    raw = b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH
    resp = client.post(URL, content=raw, headers={"content-type": "application/json"})
    assert resp.status_code == 422 and resp.json()["detail"][0]["type"] == "model_attributes_type"
    # brackets inside strings are text, not nesting
    body = good_body()
    body["joint_names"] = ["j1", "j2"]
    text = json.dumps(body)[:-1] + ', "x": "' + "[" * 100 + '"}'
    resp = client.post(URL, content=text, headers={"content-type": "application/json"})
    assert resp.status_code == 422 and resp.json()["detail"][0]["type"] == "extra_forbidden"
    # and a body that is not UTF-8 says that, not something else
    resp = client.post(URL, content=b'{"t": "\xff"}', headers={"content-type": "application/json"})
    assert resp.status_code == 422 and resp.json()["detail"][0]["msg"] == "body is not valid UTF-8"
    assert store.sample_count("arm") == 3
