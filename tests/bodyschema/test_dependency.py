"""Jacobian statistic, dependency feature, δ by Eq. 19 with DPGMM clusters."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bodyschema.dependency import (
    choose_delta,
    cluster_vote,
    dependency_feature,
    dependency_from_jacobian,
    eq19_score,
    invariant_jacobian,
    jacobian_statistic,
)
from bodyschema.networks import rpy_to_matrix


class _Hinge:
    """An exact 'network': link 1 turns about z by θ0, link 2 about its x by θ1 (two IMUs)."""

    n_imus = 2

    def pose(self, theta: torch.Tensor):
        zero = torch.zeros_like(theta[:, 0])
        R1 = rpy_to_matrix(torch.stack([zero, zero, theta[:, 0]], -1))
        R2 = R1 @ rpy_to_matrix(torch.stack([theta[:, 1], zero, zero], -1))
        b1 = torch.stack([torch.cos(theta[:, 0]), torch.sin(theta[:, 0]), zero], -1) * 0.3
        b2 = b1 + (R2 @ torch.tensor([0.0, 0.2, 0.0], dtype=theta.dtype))
        return torch.stack([R1, R2]), torch.stack([b1, b2])


def test_variance_drops_the_own_joint_and_the_second_moment_keeps_it(rng):
    """docs/design.md §3: a link turning about one fixed axis has a constant Jacobian-column norm."""
    theta = torch.as_tensor(rng.uniform(-2, 2, size=(200, 2)))
    jbar = invariant_jacobian(_Hinge(), theta).numpy()
    var = jacobian_statistic(jbar, "variance").max(axis=1)
    mom = jacobian_statistic(jbar, "moment").max(axis=1)
    assert var[0, 0] < 1e-20  # IMU 1 on joint 0: the paper's statistic says "no dependency"
    assert mom[0, 0] > 0.05  # the second moment sees it
    assert mom[0, 1] < 1e-20 and var[0, 1] < 1e-20  # and neither invents joint 1 for IMU 1
    res = dependency_from_jacobian(np.repeat(jbar, 2, axis=0), "moment", rng=np.random.default_rng(0))
    assert res.dependency.astype(int).tolist() == [[1, 0], [1, 0], [1, 1], [1, 1]]
    with pytest.raises(ValueError, match="unknown statistic"):
        jacobian_statistic(jbar, "median")


def test_feature_normalizes_and_finds_base_rows():
    stat = np.zeros((3, 4, 2))
    stat[0, 1] = [3.0, 4.0]
    stat[1, 2] = [2.0, 0.0]
    stat[2, 0] = [1e-9, 1e-9]  # an IMU the networks find independent of every joint
    feats, on_base = dependency_feature(stat)
    np.testing.assert_allclose(feats[0], [0.6, 0.8])
    np.testing.assert_allclose(feats[1], [1.0, 0.0])
    assert on_base.tolist() == [False, False, True]
    assert not feats[2].any()


def test_delta_falls_in_the_gap_for_noisy_features():
    """A worked example (fixed draw): 4 links x 3 IMUs, rows alike within a link as Prop. 1 says.

    The DPGMM can merge two links when their rows are close (a few percent of random draws of this
    kind), which is why this is a fixed example and not a property over random draws.
    """
    rng = np.random.default_rng(3)
    rows = np.array([[1, 0, 0, 0], [1, 1, 0, 0], [1, 1, 1, 0], [1, 0, 0, 1]], dtype=bool)
    link = np.where(rows, rng.uniform(0.3, 1.0, rows.shape), rng.uniform(0, 0.03, rows.shape))
    raw = np.repeat(link, 3, axis=0) * rng.uniform(0.9, 1.1, (12, 4))
    D = np.repeat(rows, 3, axis=0)
    feats = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    delta, labels = choose_delta(feats, rng=rng)
    assert feats[~D].max() < delta < feats[D].min()
    assert len(np.unique(labels)) == 4
    res = dependency_from_jacobian(raw[:, None, None, :] ** 0.5, "moment", rng=np.random.default_rng(0))
    np.testing.assert_array_equal(res.dependency, D)


def test_eq19_prefers_clusters_that_agree():
    x_good = np.array([[1, 0], [1, 0], [1, 1], [1, 1]], dtype=float)
    x_bad = np.array([[1, 0], [0, 0], [1, 1], [1, 0]], dtype=float)
    labels = np.array([0, 0, 1, 1])
    assert eq19_score(x_good, labels) > eq19_score(x_bad, labels)


def test_delta_keeps_a_weak_dependency_shared_by_a_link():
    """Measured features of a 3-joint robot (2 IMUs per link): the first two IMUs ride a link two
    joints down, so their dependency on the upper joint is weak (0.18-0.20) but shared; the noise
    floor is below 0.04. Two empty bands are equally wide; the lower one is the noise floor."""
    feats = np.array(
        [
            [0.982, 0.038, 0.183],
            [0.002, 0.009, 1.0],
            [0.978, 0.034, 0.204],
            [0.002, 1.0, 0.004],
            [0.002, 0.004, 1.0],
            [0.008, 1.0, 0.027],
        ]
    )
    truth = np.array([[1, 0, 1], [0, 0, 1], [1, 0, 1], [0, 1, 0], [0, 0, 1], [0, 1, 0]], dtype=bool)
    delta, _ = choose_delta(feats, rng=np.random.default_rng(0))
    assert 0.04 < delta < 0.18
    np.testing.assert_array_equal(feats > delta, truth)


def test_a_lone_spurious_entry_does_not_set_delta():
    """One IMU's network picked up 0.122 on a joint its link-mate shows at 0.028: δ must stay in the
    band between that and the weakest true dependency, not drop to the narrow band under 0.028."""
    feats = np.array(
        [
            [0.575, 0.818, 0.001],
            [1.0, 0.01, 0.001],
            [1.0, 0.016, 0.002],
            [0.837, 0.028, 0.547],
            [0.67, 0.742, 0.003],
            [0.256, 0.122, 0.959],
        ]
    )
    delta, _ = choose_delta(feats, rng=np.random.default_rng(0))
    assert 0.122 < delta < 0.256


def test_vote_keeps_clear_entries_of_two_links_in_one_cluster():
    # a wrist link (IMUs 2, 3) and its parent (0, 1) in one cluster: the wrist joint's column is
    # split evenly and far from δ, so neither half is overruled
    feats = np.array([[0.5, 0.5, 0.01], [0.5, 0.5, 0.02], [0.4, 0.4, 0.35], [0.4, 0.4, 0.3]])
    dep = cluster_vote(feats, 0.1, np.zeros(4, dtype=int))
    np.testing.assert_array_equal(dep[:, 2], [False, False, True, True])
    # twelve IMUs of one link, one of them just over δ on a joint the rest do not see
    feats = np.full((12, 2), [0.99, 0.02])
    feats[5, 1] = 0.13
    dep = cluster_vote(feats, 0.1, np.zeros(12, dtype=int))
    assert not dep[:, 1].any() and dep[:, 0].all()
