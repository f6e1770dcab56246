"""The fast estimator on random kinematic trees (fresh seed per run, logged by the ``seed`` fixture)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bodyschema.estimate import estimate_topology
from bodyschema.fast import PATH_SETTINGS, FastEstimator, FastOptions, fast_fit, fit_path, noise_level
from simulators.kinematic_tree import random_robot_recording


def contract(joint_parent, imu_joint, u):
    """The truth with joint ``u`` removed: its child link merged into its parent link."""
    jp = {j: (joint_parent[u] if p == u else p) for j, p in joint_parent.items() if j != u}
    ij = {i: (joint_parent[u] if j == u else j) for i, j in imu_joint.items()}
    return jp, ij


def test_noise_level_recovers_white_noise_under_smooth_motion(rng):
    t = np.arange(3000) / 100
    smooth = np.sin(2 * np.pi * 0.5 * t)[:, None, None] * np.ones((1, 2, 3))
    sigma = np.array([1e-3, 5e-3])
    x = smooth + rng.normal(size=(3000, 2, 3)) * sigma[None, :, None]
    est = noise_level(x)
    np.testing.assert_allclose(est, sigma, rtol=0.1)


def test_random_trees_are_recovered_exactly(rng):
    for _ in range(3):
        n = int(rng.integers(5, 26))
        rec = random_robot_recording(rng, n_joints=n, seconds=20.0)
        fit = fast_fit(rec)
        assert fit.path == "synced"
        np.testing.assert_array_equal(fit.dependency, rec.truth_dependency)
        topo = estimate_topology(rec)
        assert topo.joint_parent == rec.truth_parent_map
        assert topo.imu_joint == rec.truth_imu_map
        assert topo.unique and not topo.undetermined
        assert min(topo.confidence.values()) > 0.9
        assert set(topo.confidence) == {f"imu:{i}" for i in rec.imu_names} | {
            f"joint:{j}" for j in rec.joint_names
        }


def test_short_window_without_velocities_is_exact(rng):
    """10 s of data, joint velocities derived from positions by the recording (no qd given)."""
    n = int(rng.integers(5, 16))
    rec = replace(random_robot_recording(rng, n_joints=n, seconds=10.0), qd=None)
    topo = estimate_topology(rec)
    assert topo.joint_parent == rec.truth_parent_map
    assert topo.imu_joint == rec.truth_imu_map


def test_joint_held_still_is_undetermined_and_nothing_false_is_said(rng):
    n = int(rng.integers(5, 20))
    still = int(rng.integers(n))
    rec = random_robot_recording(rng, n_joints=n, seconds=20.0, still=(still,))
    u = rec.joint_names[int(np.argmin(np.abs(rec.qd).sum(axis=0)))]
    topo = estimate_topology(rec)
    assert topo.undetermined == (u,)
    assert topo.confidence[f"joint:{u}"] == 0.0
    # any IMU or joint could ride the still joint's link unseen: no placement is more than even odds
    assert max(topo.confidence.values()) <= 0.5
    assert topo.excitation[u] < 1e-9
    # everything else is exact on the tree with the still joint contracted
    jp, ij = contract(rec.truth_parent_map, rec.truth_imu_map, u)
    assert {j: p for j, p in topo.joint_parent.items() if j != u} == jp
    assert topo.imu_joint == ij
    assert "insufficient_excitation" in topo.to_json()


@pytest.mark.slow
def test_link_without_imus_gives_truth_or_candidates(rng):
    for _ in range(2):
        n = int(rng.integers(5, 20))
        bare = int(rng.integers(n))
        rec = random_robot_recording(rng, n_joints=n, seconds=20.0, bare_links=(bare,))
        topo = estimate_topology(rec)
        exact = topo.joint_parent == rec.truth_parent_map and topo.imu_joint == rec.truth_imu_map
        among = any(
            c.joint_parent == rec.truth_parent_map and c.imu_joint == rec.truth_imu_map
            for c in topo.candidates
        )
        if topo.unique:
            assert exact
        else:
            assert exact or among
            assert topo.candidates


def test_middle_link_without_imus_needs_two_hinge_models(rng):
    """A bare link with a child: the child is attached across two joints, the tree still comes out."""
    parent = [-1, 0, 1, 1, 2]  # joint 1's child link (carrying joints 2 and 3) has no IMU
    rec = random_robot_recording(rng, n_joints=5, seconds=20.0, parent=parent, bare_links=(1,))
    topo = estimate_topology(rec)
    # two children hang under the bare link, so the order of its joint is determined by the rows
    assert topo.unique
    assert topo.joint_parent == rec.truth_parent_map
    assert topo.imu_joint == rec.truth_imu_map


def test_all_joints_still_is_all_undetermined(rng):
    rec = random_robot_recording(rng, n_joints=4, seconds=10.0, still=(0, 1, 2, 3))
    topo = estimate_topology(rec)
    assert set(topo.undetermined) == set(rec.joint_names)
    assert all(topo.confidence[f"joint:{j}"] == 0.0 for j in rec.joint_names)
    assert all(v is None for v in topo.imu_joint.values())


def test_estimator_class_learns_the_tree_and_passes_its_settings_on(rng):
    rec = random_robot_recording(rng, n_joints=5, seconds=10.0)
    est = FastEstimator().fit(rec)
    np.testing.assert_array_equal(est.dependency_, rec.truth_dependency)
    assert est.undetermined_.size == 0 and est.result_.dependency is est.dependency_
    # IMUs share a group exactly when they ride the same link; base IMUs are group -1
    same_link = np.equal.outer(np.array(rec.truth_imu_joint), np.array(rec.truth_imu_joint))
    np.testing.assert_array_equal(np.equal.outer(est.group_, est.group_), same_link)
    np.testing.assert_array_equal(est.group_ == -1, np.array(rec.truth_imu_joint) == "")
    # each setting reaches the fit: an excitation floor above every joint's RMS velocity (absolute or
    # in gyro-noise units) leaves every joint undetermined; a fit ratio no model meets attaches nothing
    top = float(np.sqrt(np.mean(rec.qd**2, axis=0)).max())
    for kw in ({"min_excitation": 2 * top}, {"min_excitation_snr": 1e9}):
        assert FastEstimator(**kw).fit(rec).undetermined_.tolist() == list(range(5)), kw
    strict = FastEstimator(fit_ratio=1e-6).fit(rec)
    assert not strict.dependency_.any()


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda r: r.select(slice(0, 20)), "at least"),
        (lambda r: replace(r, q=None, qd=None, qdd=None), "positions q"),
        # positions only, on one clock: the timed path needs the band's edges and the lag search inside
        (lambda r: replace(r.select(slice(0, 90)), qd=None, qdd=None), "the recording spans 0.89 s"),
    ],
)
def test_bad_input_is_refused_clearly(rng, mutate, message):
    rec = random_robot_recording(rng, n_joints=3, seconds=2.0)
    with pytest.raises(ValueError, match=message):
        fast_fit(mutate(rec))


def test_options_and_keywords_are_one_setting(rng):
    """One FastOptions for the function, the class and estimate_topology; a setting the recording's path
    does not use is one rule everywhere: not applied, and named in ``unused`` when stated."""
    rec = random_robot_recording(rng, n_joints=4, seconds=10.0)
    opts = FastOptions(fit_ratio=10.0, rel_tol=1e-3)
    by_options = fast_fit(rec, opts)
    estimator = FastEstimator(opts).fit(rec)
    by_keywords = FastEstimator(replace(opts, fit_ratio=25.0), fit_ratio=10.0).fit(rec)
    for fit in (estimator.result_, by_keywords.result_):
        assert fit.edges == by_options.edges
        np.testing.assert_array_equal(fit.imu_confidence, by_options.imu_confidence)
    topo = estimate_topology(rec, fit_ratio=10.0, rel_tol=1e-3)
    assert topo.confidence == estimate_topology(rec, options=opts).confidence
    assert FastEstimator(fit_ratio=3.0).fit_ratio == 3.0 and FastEstimator().options == FastOptions()
    # measured velocities: the synced path, where the band is no setting; positions only: the timed one
    banded = fast_fit(rec, FastOptions(band=5.0, rel_tol=1e-3))
    assert (banded.path, banded.unused, banded.edges) == ("synced", ("band",), fast_fit(rec, opts).edges)
    positions = replace(rec, qd=None, qdd=None)
    assert fit_path(positions) == "timed" and fast_fit(positions, opts).unused == ("rel_tol",)
    assert PATH_SETTINGS["synced"] | PATH_SETTINGS["timed"] == set(FastOptions.__dataclass_fields__)
    with pytest.raises(TypeError, match="FastOptions"):
        FastEstimator(fit_raito=3.0)
    with pytest.raises(ValueError, match=r"fit_ratio=0\.0, band=-1\.0 out of range"):
        FastOptions(fit_ratio=0.0, band=-1.0)
