"""The robust path's consistency step on hand-made cycles (robust/consistency.py): a corridor
walked twice whose loop closures are known true or wrong by construction."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import PoseGraph2D
from rlpgo_gtsam.graph import PoseGraph3D, odometry_edges
from rlpgo_gtsam.groups import group_of
from rlpgo_gtsam.robust.consistency import ChainTree, pairwise_consistency
from rlpgo_gtsam.se2 import adjoint, compose, inverse
from rlpgo_gtsam.se3 import exp_so3

THRESHOLD = 21.1  # chi-square, 3 dof, 0.9999


def _corridor(closures: list[tuple[int, int, tuple[float, float, float]]], n: int = 40,
              sigma: float = 0.01):
    """Poses 1 m apart along x, exact odometry, the given closures (i, j, measured)."""
    values, graph = gtsam.Values(), gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
    for k in range(n):
        values.insert(k, gtsam.Pose2(float(k), 0.0, 0.0))
    for k in range(n - 1):
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, gtsam.Pose2(1.0, 0.0, 0.0), noise))
    for i, j, z in closures:
        graph.add(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z), noise))
    g = PoseGraph2D.from_gtsam(graph, values)
    return g, odometry_edges(g)


def test_true_closures_agree_and_a_wrong_one_goes():
    true = [(k, k + 10, (10.0, 0.0, 0.0)) for k in range(0, 20, 2)]
    wrong = [(5, 30, (0.0, 0.0, 0.0))]  # "these two places are the same": 25 m off
    g, chain = _corridor(true + wrong)
    found = pairwise_consistency(g, chain, THRESHOLD)
    closures = np.flatnonzero(~chain)
    assert found.kept[closures].tolist() == [True] * len(true) + [False]
    assert found.conflicts >= 1 and found.pairs >= len(closures)
    assert not found.ambiguous


def test_a_closure_nothing_contradicts_is_kept():
    """Absence of support is not evidence: a lone closure with no neighbour to agree with
    stays, on a graph where nothing else could test it."""
    g, chain = _corridor([(3, 33, (30.0, 0.0, 0.0))])
    found = pairwise_consistency(g, chain, THRESHOLD)
    assert found.kept[~chain].all()


def test_two_equal_exclusive_sets_are_reported_not_chosen():
    """Three closures say 5 m, three say 15 m between the same stretch: nothing tells them
    apart, and the result says so."""
    first = [(k, k + 5, (5.0, 0.0, 0.0)) for k in (2, 3, 4)]
    second = [(k, k + 5, (15.0, 0.0, 0.0)) for k in (2, 3, 4)]
    g, chain = _corridor(first + second)
    found = pairwise_consistency(g, chain, THRESHOLD)
    assert found.conflicts >= 3
    assert found.ambiguous, "two equally supported, mutually exclusive sets"


def test_chain_segments_carry_their_propagated_covariance():
    """D(a, b) along the chain and its covariance in b's frame: the steps' covariances moved
    by the adjoint of what follows them, summed (first order), as computed step by step."""
    rng = np.random.default_rng(4)
    n = 12
    steps = np.column_stack([rng.normal(1.0, 0.2, n - 1), rng.normal(0.0, 0.2, n - 1),
                             rng.normal(0.0, 0.3, n - 1)])
    values, graph = gtsam.Values(), gtsam.NonlinearFactorGraph()
    pose = np.zeros(3)
    values.insert(0, gtsam.Pose2(*pose))
    sigmas = rng.uniform(0.01, 0.1, (n - 1, 3))
    for k, step in enumerate(steps):
        pose = compose(pose[None], step[None])[0]
        values.insert(k + 1, gtsam.Pose2(*pose))
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, gtsam.Pose2(*step),
                                           gtsam.noiseModel.Diagonal.Sigmas(sigmas[k])))
    g = PoseGraph2D.from_gtsam(graph, values)
    chain = odometry_edges(g)
    tree = ChainTree.build(g, chain, np.linalg.inv(g.information))
    a, b = 2, 9
    relative, covariance = tree.between(np.array([a]), np.array([b]))
    expected = np.zeros((3, 3))
    after = np.zeros(3)  # the steps after step k, composed: the frame change to b
    for k in range(b - 1, a - 1, -1):
        move = adjoint(inverse(after[None]))[0]
        expected += move @ np.diag(sigmas[k] ** 2) @ move.T
        after = compose(steps[k][None], after[None])[0]
    np.testing.assert_allclose(relative[0], after, atol=1e-12)
    np.testing.assert_allclose(covariance[0], expected, rtol=1e-9, atol=1e-15)


def _random_chain_graph(dim: int, rng: np.random.Generator, n: int = 14):
    """A random chain of n poses (2D or 3D) with loop closures that lie apart along the chain,
    nest and cross, each measured exactly, every edge with its own diagonal covariance."""
    dof = 3 if dim == 2 else 6
    closures = [(0, 3), (8, 12), (2, 10), (4, 7), (1, 5), (9, 13)]

    def pose(k: int):
        if dim == 2:
            return gtsam.Pose2(*rng.normal(0.0, 1.0, 3))
        return gtsam.Pose3(gtsam.Rot3(exp_so3(rng.normal(0.0, 0.5, (1, 3)))[0]),
                           rng.normal(0.0, 1.0, 3))

    truth = [pose(k) for k in range(n)]
    values, graph = gtsam.Values(), gtsam.NonlinearFactorGraph()
    between = gtsam.BetweenFactorPose2 if dim == 2 else gtsam.BetweenFactorPose3
    for k, p in enumerate(truth):
        values.insert(k, p)
    for i, j in [(k, k + 1) for k in range(n - 1)] + closures:
        model = gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.01, 0.2, dof))
        graph.add(between(i, j, truth[i].between(truth[j]), model))
    extract = PoseGraph2D.from_gtsam if dim == 2 else PoseGraph3D.from_gtsam
    return extract(graph, values)


@pytest.mark.parametrize("dim", [2, 3])
def test_cycle_covariance_is_the_first_order_one(dim):
    """Every pair of closures' cycle covariance equals J Sigma J^T, J the cycle error's
    derivative in each measurement (finite differences): segments that overlap along the
    chain (closures far apart), nest or cross alike."""
    g = _random_chain_graph(dim, np.random.default_rng(dim))
    group = group_of(g)
    chain = odometry_edges(g)
    closures = np.flatnonzero(~chain)
    a, b = np.triu_indices(len(closures), 1)
    e, f = closures[a], closures[b]
    covariance = np.linalg.inv(g.information)

    def cycles(graph):
        tree = ChainTree.build(graph, chain, covariance)
        measured = group.measured(graph)
        return tree.cycles(graph.edges[e, 0], graph.edges[e, 1], graph.edges[f, 0],
                           graph.edges[f, 1], measured[e], covariance[e], measured[f],
                           covariance[f])

    def moved(edge: int, axis: int):
        step = np.zeros(group.dof)
        step[axis] = 1e-6
        if dim == 2:
            small = step[None]
            changed = g.measured.copy()
            changed[edge] = group.compose(g.measured[[edge]], small)[0]
            return replace(g, measured=changed)
        rotations, translations = g.measured_rotations.copy(), g.measured_translations.copy()
        rotations[edge] = rotations[edge] @ exp_so3(step[None, :3])[0]
        translations[edge] = translations[edge] + g.measured_rotations[edge] @ step[3:]
        return replace(g, measured_rotations=rotations, measured_translations=translations)

    error, total = cycles(g)
    np.testing.assert_allclose(error, 0.0, atol=1e-9)  # exact measurements close every cycle
    expected = np.zeros_like(total)
    for edge in range(g.num_edges):
        jacobian = np.stack([(cycles(moved(edge, d))[0] - error) / 1e-6
                             for d in range(group.dof)], axis=-1)
        expected += jacobian @ covariance[edge] @ np.transpose(jacobian, (0, 2, 1))
    np.testing.assert_allclose(total, expected, rtol=1e-4, atol=1e-9)
