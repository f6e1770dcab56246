"""Source specs and the farm source (pacing, injection while stepping, simulated robots in the store)."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.ingest.farm import FarmSource
from service.ingest.pipeline import Pipeline
from service.ingest.replay import ReplaySource
from service.ingest.spec import SpecError, farm_catalog, open_source, parse_speed_suffix
from service.settings import Settings
from service.store import Store, open_store
from simulators.recording_io import save_recording


class StandInFarm:
    """The farm's interface on random numbers: ``advance`` returns the new samples per robot."""

    def __init__(self, robots: dict[str, str], seed: int = 0, rate: float = 100.0) -> None:
        self._robots = robots
        self._rng = np.random.default_rng(seed)
        self.rate = rate
        self.n = 0
        self.injected: list[tuple[str, str, dict]] = []
        self._busy = threading.Lock()

    @property
    def robot_names(self) -> list[str]:
        return list(self._robots)

    def catalog_name(self, name: str) -> str:
        return self._robots[name]

    def advance(self, seconds: float) -> dict[str, Recording]:
        assert self._busy.acquire(blocking=False), "advance and apply_damage ran at the same time"
        try:
            k = round(seconds * self.rate)
            t = (self.n + 1 + np.arange(k)) / self.rate
            self.n += k
            return {
                name: Recording(
                    t=t,
                    joint_names=["j1", "j2"],
                    q=self._rng.normal(size=(k, 2)),
                    imu_names=["i0"],
                    acc=self._rng.normal(size=(k, 1, 3)),
                    gyro=self._rng.normal(size=(k, 1, 3)),
                )
                for name in self._robots
            }
        finally:
            self._busy.release()

    def apply_damage(self, robot: str, kind: str, **params: object) -> dict:
        assert self._busy.acquire(blocking=False), "advance and apply_damage ran at the same time"
        try:
            self.injected.append((robot, kind, params))
            return {"changed": True, "findings": [{"kind": kind, **params}]}
        finally:
            self._busy.release()


class FakeClock:
    def __init__(self) -> None:
        self.now = 50.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += max(s, 0.0)


def test_farm_source_paces_to_speed() -> None:
    clock = FakeClock()
    src = FarmSource(StandInFarm({"a-1": "a"}), speed=2.0, step_seconds=0.1, clock=clock, sleep=clock.sleep)
    start, total = clock.now, 0
    while src.sim_seconds < 3.0 - 1e-9:
        got = src.read(0.02)
        total += sum(b.n_samples for b in got)
        # Never ahead of 2x the wall clock (the first step is due at once).
        assert src.sim_seconds <= (clock.now - start) * 2.0 + 0.1 + 1e-9
    assert total == 300 and clock.now - start == pytest.approx(1.45, abs=0.03)


def test_farm_source_catches_up_in_bounded_reads() -> None:
    clock = FakeClock()
    src = FarmSource(
        StandInFarm({"a-1": "a"}),
        speed=1.0,
        step_seconds=0.1,
        max_steps_per_read=5,
        clock=clock,
        sleep=clock.sleep,
    )
    src.read(0.1)
    clock.now += 2.0  # the reader was held up for 2 s: 20 steps behind
    assert sum(b.n_samples for b in src.read(0.1)) == 50  # no more than 5 steps in one read


def test_farm_into_store_marks_simulated_and_injects_while_running(store: Store) -> None:
    farm = StandInFarm({"ur5e-1": "ur5e", "paper-3-1": "paper-3"})
    src = FarmSource(farm, speed=math.inf, step_seconds=0.05, max_steps_per_read=2)
    with Pipeline(store, [src]):
        for i in range(20):
            src.apply_damage("ur5e-1", "imu_moved", imu=f"imu{i}")
    assert len(farm.injected) == 20
    infos = {r.name: r for r in store.robots()}
    assert set(infos) == {"ur5e-1", "paper-3-1"}
    assert (
        infos["ur5e-1"].simulated
        and infos["ur5e-1"].catalog == "ur5e"
        and infos["paper-3-1"].catalog == "paper-3"
    )
    c = src.counters.as_dict()
    assert c["received"] == c["stored"] > 0 and c["dropped"] == 0
    assert store.sample_count() == c["stored"]
    rec = store.read_window("ur5e-1", 1.0)
    assert rec.joint_names == ("j1", "j2") and np.all(np.diff(rec.t) > 0)


# -------------------------------------------------------------------------------------- specs
def test_speed_suffix_and_farm_catalog() -> None:
    assert parse_speed_suffix("x.npz") == ("x.npz", 1.0)
    assert parse_speed_suffix("x.npz@2.5") == ("x.npz", 2.5)
    assert parse_speed_suffix("user@host/x.npz") == ("user@host/x.npz", 1.0)
    assert parse_speed_suffix("a@MAX") == ("a", math.inf)
    for bad in ("a@0", "a@-3", "a@nan"):
        with pytest.raises(SpecError):
            parse_speed_suffix(bad)
    assert farm_catalog("ur5e*3, paper-3") == ["ur5e", "ur5e", "ur5e", "paper-3"]
    for bad in ("", ",", "ur5e*0", "ur5e*x", "*2"):
        with pytest.raises(SpecError):
            farm_catalog(bad)


def test_open_replay_spec(tmp_path, rng: np.random.Generator) -> None:
    n = 30
    rec = Recording(
        t=np.arange(n) / 100,
        joint_names=["j"],
        q=np.zeros((n, 1)),
        imu_names=["i"],
        acc=rng.normal(size=(n, 1, 3)),
        gyro=np.zeros((n, 1, 3)),
    )
    path = tmp_path / "run 1.npz"
    save_recording(rec, path)
    src = open_source(f"replay:{path}@max?robot=arm&chunk=0.2&loop=1&resume=0", Settings())
    assert isinstance(src, ReplaySource)
    assert (src.robot, src.speed, src.loop, src.resume) == ("arm", math.inf, True, False)
    assert [b.n_samples for b in src.read()[:3]] == [20, 10, 20]
    with pytest.raises(ValueError, match=r"robot name 'run 1' is not allowed.*\?robot=NAME"):
        open_source(f"replay:{path}", Settings())  # the file name is no robot name: say how to give one
    save_recording(rec, tmp_path / "run-1.npz")
    plain = open_source(f"replay:{tmp_path / 'run-1.npz'}", Settings())
    assert (plain.robot, plain.speed, plain.loop) == ("run-1", 1.0, False)


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("replay", "KIND:ARGS"),
        ("telepathy:x", "unknown source kind"),
        ("replay:x.npz?colour=red", "colour"),
        ("farm:ur5e?speed=3", "speed"),
        ("replay:/no/such/file.npz", "not a readable"),
    ],
)
def test_bad_specs_say_why(spec: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        open_source(spec, Settings())


def test_serial_and_can_specs_are_delegated() -> None:
    """Both transports ship, so both specs must reach their own module (and its own refusals)."""
    src = open_source("serial:loop://?robot=r1&period=0.01&joints=j1,j2&imus=", Settings())
    assert type(src).__module__ == "service.ingest.serial"
    src.close()
    src = open_source("can:virtual:spec-test?robot=r2&joints=j1&imus=imu0", Settings())
    assert type(src).__module__ == "service.ingest.can" and src.config.robot == "r2"
    src.close()
    with pytest.raises(ValueError, match="CAN source needs INTERFACE:CHANNEL"):
        open_source("can:slcan", Settings())


@pytest.mark.slow
def test_real_farm_spec(db_url: str) -> None:
    src = open_source("farm:paper-3,ur5e@max?seed=1&step=0.05", Settings())
    assert isinstance(src, FarmSource) and sorted(src.robot_names) == ["paper-3-1", "ur5e-1"]
    with open_store(db_url) as store:
        with Pipeline(store, [src]) as pipe:
            for _ in range(200):
                if all(store.robot(n) and (store.robot(n).last_frame_t or 0) >= 0.5 for n in src.robot_names):
                    break
                pipe.wait_exhausted(timeout=0.1)
        info = store.robot("ur5e-1")
        assert info.simulated and info.catalog == "ur5e" and len(info.joints) == 6
        rec = store.read_window("ur5e-1", 0.5)
        # the settings' default sensing is the robot preset: IMUs at 100 Hz, encoders at 250 Hz, jittered
        assert rec.n_imus == len(info.imus) and rec.sample_rate == pytest.approx(100.0, rel=0.02)
        assert rec.is_multirate and rec.encoder_rate == pytest.approx(250.0, rel=0.02)


def test_farm_in_a_child_process_gives_the_same_frames_and_ends_with_close() -> None:
    """The spec's farm runs in a child process by default (``process=1``); it yields the frames the same
    farm yields in the reader thread (``process=0``), raises the farm's errors, and its child ends on
    close."""
    from service.ingest.farm import FarmProcess

    spec = "farm:paper-1@max?seed=3&step=0.1&sensing=robot"
    child, here = open_source(spec, Settings()), open_source(spec + "&process=0", Settings())
    assert isinstance(child.farm, FarmProcess) and not isinstance(here.farm, FarmProcess)
    assert child.farm.sensing == here.farm.sensing and child.robot_names == here.robot_names
    got = [child.read() for _ in range(3)]
    want = [here.read() for _ in range(3)]
    assert [len(b) for b in got] == [len(b) for b in want] and sum(len(b) for b in got) > 0
    for a, b in zip([x for g in got for x in g], [x for w in want for x in w], strict=True):
        assert a.robot == b.robot
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.gyro, b.gyro)
        np.testing.assert_array_equal(a.q, b.q)
    with pytest.raises(ValueError, match="unknown IMU 'nope'"):
        child.apply_damage("paper-1-1", "imu_dead", imu="nope")
    proc = child.farm._proc
    child.close()
    assert not proc.is_alive() and proc.exitcode == 0
    with pytest.raises(SpecError, match="process must be 0 or 1"):
        open_source("farm:paper-1?process=yes", Settings())
