"""The learned topology methods on simulated robots: ``network``, ``mlp`` and ``network-paper``.

``network`` and ``mlp`` must give the true tree where ``docs/bench/topology.md`` says they do;
``network-paper`` must fail the way ``docs/topology.md`` says it does: the paper's variance statistic
drops the joint an IMU's own link turns about (a column of constant norm has zero variance), so the
IMUs below the first link lose their own parent joint and are placed on an ancestor of it.

The robots and seeds are fixed draws, checked with their neighbours (other recording seeds, other
network seeds) so that none of these tests sits on a knife edge; the numbers are in the docstrings.
Every training is one CPU thread (:func:`bodyschema.threads.set_torch_threads`, as the service and
the benchmark run it); the whole file takes about a minute of CPU.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from bodyschema.dependency import NetworkDependency, dependency_from_jacobian, network_jacobian
from bodyschema.estimate import estimate_topology, topology_from_dependency
from bodyschema.fast import insufficient_excitation
from bodyschema.recording import Recording
from bodyschema.threads import set_torch_threads
from bodyschema.topology import Topology
from simulators.kinematic_tree import random_robot_recording
from simulators.simulation import simulate

pytestmark = pytest.mark.slow

NET_SEED = 0


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread() -> Iterator[None]:
    import torch

    before = torch.get_num_threads()
    set_torch_threads()
    yield
    set_torch_threads(before)


def _catalog(robot: str, seconds: float, seed: int = 0) -> Recording:
    """A catalog robot as the topology benchmark records it (MPU-6050 errors, observable excitation)."""
    return simulate(robot, seconds=seconds, seed=seed, imu_model="mpu6050", excitation="observable")


def _exact(topo: Topology, rec: Recording) -> bool:
    return topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map


def _ancestors(parent: dict[str, str | None], joint: str) -> set[str]:
    """Joints strictly above ``joint`` in the tree ``parent``."""
    out: set[str] = set()
    cur = parent[joint]
    while cur is not None:
        out.add(cur)
        cur = parent[cur]
    return out


def _extract(rec: Recording, jbar: np.ndarray, statistic: str) -> tuple[NetworkDependency, Topology]:
    """Steps 2-5 of :mod:`bodyschema.dependency` and the tree, as ``network_dependency`` and
    ``estimate_topology`` run them (and the benchmark, which trains once for both statistics)."""
    derived = rec.derived()
    assert derived.qd is not None
    und = insufficient_excitation(derived.qd, rec.gyro)
    res = dependency_from_jacobian(jbar, statistic, und, rng=np.random.default_rng(NET_SEED + 1))
    topo = topology_from_dependency(
        res.dependency,
        rec.imu_names,
        rec.joint_names,
        undetermined=[rec.joint_names[j] for j in res.undetermined],
        method="network" if statistic == "moment" else "network-paper",
        evidence=res.evidence,
    )
    return res, topo


# ------------------------------------------------------------------------------------------ network
@pytest.mark.parametrize("robot_seed", [0, 3])
def test_network_learns_small_random_trees_exactly(robot_seed: int) -> None:
    """3 joints, 2 IMUs per link, 10 s, 40 epochs, through ``estimate_topology``.

    Over robot seeds 0-7 all eight trees came out exact, with the weakest true dependency feature at
    0.48-0.71 and the strongest false one at 0.001-0.016: a wide margin, not a lucky draw; network
    seeds 1 and 2 give the exact trees of robots 0 and 3 too.
    """
    rec = random_robot_recording(
        np.random.default_rng(robot_seed), n_joints=3, seconds=10.0, imus_per_link=(2, 2), base_imus=0
    )
    topo = estimate_topology(rec, method="network", epochs=40, seed=NET_SEED)
    assert topo.method == "network"
    assert topo.joint_parent == rec.truth_parent_map
    assert topo.imu_joint == rec.truth_imu_map
    assert topo.unique and not topo.undetermined


# ------------------------------------------------------------------------- network and network-paper
#: Catalog robots on which the networks fit well enough for the variance statistic to show its flaw:
#: a 30 s quadruped and a 60 s UR5e (30 s of UR5e leaves the networks too loose: the own joint keeps a
#: variance that Eq. 16's normalization lifts back above δ on some IMUs).
CATALOG_CASES = [("quadruped", 30.0), ("ur5e", 60.0)]


@pytest.fixture(scope="module")
def trained() -> dict[str, tuple[Recording, np.ndarray]]:
    """One training of the sensor networks per catalog case, shared by both statistics (as the
    benchmark does): the recording and the Jacobian norms (K, S, 4, N)."""
    out = {}
    for robot, seconds in CATALOG_CASES:
        rec = _catalog(robot, seconds)
        jbar = network_jacobian(rec, kind="network", epochs=40, seed=NET_SEED).jbar
        out[robot] = (rec, jbar)
    return out


@pytest.mark.parametrize("robot", [r for r, _ in CATALOG_CASES])
def test_network_second_moment_learns_the_catalog_robot_exactly(
    trained: dict[str, tuple[Recording, np.ndarray]], robot: str
) -> None:
    rec, jbar = trained[robot]
    res, topo = _extract(rec, jbar, "moment")
    np.testing.assert_array_equal(res.dependency, rec.truth_dependency)
    assert _exact(topo, rec) and topo.unique


@pytest.mark.parametrize("robot", [r for r, _ in CATALOG_CASES])
def test_network_paper_variance_drops_each_imus_own_parent_joint(
    trained: dict[str, tuple[Recording, np.ndarray]], robot: str
) -> None:
    """The documented failure, entry by entry, on the same trained networks that ``network`` gets
    exactly right. For the IMUs below the first link (16 on the quadruped, 10 on the UR5e) the
    variance feature of the own joint is a fraction of the second moment's (at most 0.38 of it over
    the draws below), and it falls below δ. Measured on recording seeds 0-3 (network seed 0) and
    network seeds 1-2 (recording seed 0): all 16 quadruped IMUs every time; all 10 UR5e IMUs on four
    of the six, 9 of 10 on the other two (one wrist_3 IMU kept 0.08-0.13 against δ 0.05-0.09). An IMU
    that loses its own joint is hung on a strict ancestor of it."""
    rec, jbar = trained[robot]
    moment, _ = _extract(rec, jbar, "moment")
    paper, topo = _extract(rec, jbar, "variance")
    joints = list(rec.joint_names)
    # IMUs whose link hangs below another joint: their own joint is not their only dependency
    deep = [
        (k, imu, joints.index(j))
        for k, imu in enumerate(rec.imu_names)
        if (j := rec.truth_imu_map[imu]) is not None and rec.truth_parent_map[j] is not None
    ]
    assert len(deep) == {"quadruped": 16, "ur5e": 10}[robot]
    rows = [k for k, _, _ in deep]
    own = [j for _, _, j in deep]
    # the truth has the entry and the second moment sees it; the variance sees a fraction of it
    assert rec.truth_dependency[rows, own].all()
    assert moment.dependency[rows, own].all()
    assert (paper.features[rows, own] < 0.5 * moment.features[rows, own]).all()
    dropped = ~paper.dependency[rows, own]
    assert (paper.features[rows, own][dropped] < paper.delta).all()
    assert dropped.sum() >= 0.75 * len(deep), dropped
    # so the tree is wrong in exactly that way: IMUs sit on an ancestor of their own joint, none
    # anywhere else
    assert not _exact(topo, rec)
    above = 0
    for _, imu, _ in deep:
        true_joint = rec.truth_imu_map[imu]
        placed = topo.imu_joint[imu]
        assert (
            placed == true_joint or placed is None or placed in _ancestors(rec.truth_parent_map, true_joint)
        ), (imu, placed, true_joint)
        above += placed != true_joint
    assert above >= 0.75 * len(deep)


def test_network_paper_through_estimate_topology_on_the_quadruped(
    trained: dict[str, tuple[Recording, np.ndarray]],
) -> None:
    """The method as the service and the CLI call it (its own training, same seed): the same wrong
    tree as above, with every one of the 16 leg IMUs below a hip abductor moved up the leg and no
    other IMU moved (so on recording seeds 0 and 1, from the shared training)."""
    rec, jbar = trained["quadruped"]
    topo = estimate_topology(rec, method="network-paper", epochs=40, seed=NET_SEED)
    assert topo.method == "network-paper" and not _exact(topo, rec)
    _, extracted = _extract(rec, jbar, "variance")
    assert topo.same_structure(extracted)
    moved = {imu for imu in rec.imu_names if topo.imu_joint[imu] != rec.truth_imu_map[imu]}
    below_abductor = {
        imu for imu, j in rec.truth_imu_map.items() if j is not None and j.endswith(("hip_flex", "knee"))
    }
    assert len(below_abductor) == 16 and moved == below_abductor
    for imu in moved:
        assert topo.imu_joint[imu] in _ancestors(rec.truth_parent_map, rec.truth_imu_map[imu]), imu


# ---------------------------------------------------------------------------------------------- mlp
@pytest.mark.parametrize("robot", ["paper-4", "quadruped"])
def test_mlp_learns_the_robots_the_benchmark_names(robot: str) -> None:
    """The MLP baseline is exact only on paper-4 and the quadruped in the benchmark (60 s, 40
    epochs); so here. 15 s recordings were not enough (exact on 1 of 6 draws); at 60 s both robots
    were exact on recording seeds 0-2 with network seed 0 and on network seeds 1-2 with recording
    seed 0. On small random trees it is not (exact on 4-8 of 10 draws, whatever the size tried)."""
    rec = _catalog(robot, 60.0)
    topo = estimate_topology(rec, method="mlp", epochs=40, seed=NET_SEED)
    assert topo.method == "mlp"
    assert topo.joint_parent == rec.truth_parent_map
    assert topo.imu_joint == rec.truth_imu_map
