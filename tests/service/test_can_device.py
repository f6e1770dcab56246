"""Device description and counter clock shared by the CAN and serial transports; CAN spec errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.ingest.can import open_from_spec
from service.ingest.can_layout import encode_samples
from service.ingest.can_mapping import SignalMap
from service.ingest.can_regroup import SampleAssembler
from service.ingest.device import DeviceClock, DeviceConfig, DeviceConfigError


@settings(max_examples=200, deadline=None)
@given(
    bits=st.sampled_from([8, 16, 32]),
    start=st.integers(0, 2**32),
    steps=st.lists(st.integers(-300, 300), min_size=1, max_size=60),
    split=st.integers(0, 60),
)
def test_vectorised_unwrap_equals_one_by_one(bits, start, steps, split):
    """index_many gives exactly what index gives frame by frame, batches cut anywhere, restarts included."""
    raw = (start + np.cumsum(steps)) % (1 << bits)
    one, many = DeviceClock(bits), DeviceClock(bits)
    want = [one.index(int(r)) for r in raw]
    got = np.concatenate([many.index_many(raw[:split]), many.index_many(raw[split:])]).tolist()
    assert got == want and many.resets == one.resets


def test_counter_wrap_and_device_restart_on_can():
    cfg = DeviceConfig("r1", 0.01, ["j1"], [])
    asm = SampleAssembler(SignalMap.for_config(cfg))
    counters = np.array([65533, 65534, 65535, 0, 1, 60000, 60001, 60002])  # wraps; then a restart
    ids, data = encode_samples(counters, np.zeros((8, 1)), np.zeros((8, 0, 3)), np.zeros((8, 0, 3)))
    asm.add_many([int(ids[0])] * 8, [data[t, 0].tobytes() for t in range(8)])
    (batch,) = asm.take(flush=True)
    np.testing.assert_allclose(batch.t, np.arange(65533, 65541) * 0.01)
    assert asm.clock.resets == 1


def test_device_config_errors_name_the_problem(tmp_path):
    with pytest.raises(DeviceConfigError, match="period_s"):
        DeviceConfig("r", -1.0, ["a"], [])
    with pytest.raises(DeviceConfigError, match="unique"):
        DeviceConfig("r", 0.01, ["a", "a"], [])
    with pytest.raises(DeviceConfigError, match="robot"):
        DeviceConfig("", 0.01, ["a"], [])
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DeviceConfigError, match=r"bad\.json"):
        DeviceConfig.load(tmp_path / "bad.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(DeviceConfigError, match="object"):
        DeviceConfig.load(tmp_path / "list.json")
    (tmp_path / "nop.json").write_text(json.dumps({"robot": "r"}))
    with pytest.raises(DeviceConfigError, match="period_s"):
        DeviceConfig.load(tmp_path / "nop.json")
    cfg = DeviceConfig("r", 0.005, ["a"], ["i"], {"can": {"layout": "fd"}})
    cfg.save(tmp_path / "ok.json")
    assert DeviceConfig.load(tmp_path / "ok.json") == cfg
    assert DeviceConfig.load(tmp_path / "ok.json").extra == {"can": {"layout": "fd"}}


def test_can_spec_errors():
    with pytest.raises(ValueError, match="INTERFACE:CHANNEL"):
        open_from_spec("slcan?robot=r&joints=a")
    with pytest.raises(DeviceConfigError, match="config=PATH"):
        open_from_spec("virtual:x")
    with pytest.raises(DeviceConfigError, match="cannot read DBC"):
        open_from_spec("virtual:x?robot=r&joints=a&dbc=/nonexistent.dbc")
    with pytest.raises(ValueError, match="layout"):
        open_from_spec("virtual:x?robot=r&joints=a&imus=" + ",".join(f"i{k}" for k in range(129)))
    with pytest.raises(ValueError, match="incomplete"):
        open_from_spec("virtual:x?robot=r&joints=a&incomplete=maybe")
