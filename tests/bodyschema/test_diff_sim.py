"""Every farm damage kind on the simulated UR5e and quadruped, through the same path as the worker
(impacts dropped, fast estimate, signal health with the baseline as layout, diff): exactly one finding,
of the injected kind, on the injected part; a healthy second window gives none."""

from __future__ import annotations

import pytest

from bodyschema.diff import diff_bodies
from bodyschema.estimate import estimate_topology
from bodyschema.health import signal_health
from bodyschema.impacts import drop_impacts
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from simulators.simulation import Simulation

pytestmark = pytest.mark.slow

WINDOW = 30.0
CASES = {
    "ur5e": [
        ("imu_moved", {"imu": "imu2", "to": "wrist_2"}),
        ("imu_detached", {"imu": "imu5"}),
        ("imu_dead", {"imu": "imu8", "mode": "zero"}),
        ("joint_locked", {"joint": "shoulder_lift"}),
        ("encoder_fault", {"joint": "elbow"}),
        ("link_lost", {"joint": "wrist_1"}),
    ],
    "quadruped": [
        ("imu_moved", {"imu": "imu4", "to": "fl_knee"}),
        ("imu_detached", {"imu": "imu10"}),
        ("imu_dead", {"imu": "imu17"}),
        ("joint_locked", {"joint": "hr_knee"}),
        ("encoder_fault", {"joint": "hl_hip_flex"}),
        ("link_lost", {"joint": "fr_knee"}),
    ],
}


def judge(base: Topology, rec: Recording) -> list[tuple[str, str]]:
    cur = estimate_topology(drop_impacts(rec))
    health = signal_health(rec, base, current=cur)
    return sorted((f.kind, f.part) for f in diff_bodies(base, cur, health).findings)


@pytest.mark.parametrize(
    ("robot", "kind", "args"),
    [(r, k, a) for r, cases in CASES.items() for k, a in cases],
    ids=[f"{r}-{k}" for r, cases in CASES.items() for k, _ in cases],
)
def test_each_damage_is_one_finding_on_the_right_part(robot: str, kind: str, args: dict, seed: int) -> None:
    sim = Simulation(robot, seed=seed % 1000)
    sim.advance(seconds=10.0)  # past the start transient
    base = estimate_topology(drop_impacts(sim.advance(seconds=WINDOW)))
    assert base.same_structure(sim.truth()) and base.unique
    assert judge(base, sim.advance(seconds=WINDOW)) == []
    truth = sim.apply_damage(kind, **args).findings[0]
    sim.advance(seconds=2.0)
    assert judge(base, sim.advance(seconds=WINDOW)) == [(kind, truth.part)]


#: Simulation seeds for the encoder-offset check. A 0.3 rad offset is not always told apart from normal
#: variation of the encoder-to-gyro relation: on ur5e wrist_1 it was missed on 3 of seeds 600-629 (never
#: reported as anything else), so the test asserts a detection rate on a fixed set, not every seed.
OFFSET_SEEDS = range(600, 610)


@pytest.mark.slow
@pytest.mark.parametrize(("robot", "joint"), [("ur5e", "wrist_1"), ("quadruped", "fl_hip_flex")])
def test_encoder_offset_against_the_baseline_fingerprint(robot: str, joint: str) -> None:
    from bodyschema.health import fingerprints

    found = 0
    for seed in OFFSET_SEEDS:
        sim = Simulation(robot, seed=seed)
        sim.advance(seconds=10.0)
        base = estimate_topology(drop_impacts(sim.advance(seconds=WINDOW)))
        rec = sim.advance(seconds=WINDOW)
        fps = fingerprints(rec, base, current=estimate_topology(drop_impacts(rec)))
        assert joint in fps
        sim.apply_damage("encoder_fault", joint=joint, mode="offset", value=0.3)
        sim.advance(seconds=2.0)
        rec = sim.advance(seconds=WINDOW)
        cur = estimate_topology(drop_impacts(rec))
        d = diff_bodies(base, cur, signal_health(rec, base, current=cur, fingerprints=fps))
        got = [(f.kind, f.part) for f in d.findings]
        assert got in ([], [("encoder_fault", f"joint:{joint}")]), (seed, got)  # never a wrong finding
        if got:
            assert "shifted" in d.findings[0].detail
            found += 1
    assert found >= 8, f"encoder offset found on {found}/{len(OFFSET_SEEDS)} seeds"
