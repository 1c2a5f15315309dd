"""The SE(2) array maths against GTSAM's Pose2, row by row, on random poses (large angles,
tiny angles, angles at +-pi included)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import se2


def _poses(rng: np.random.Generator, k: int = 200) -> np.ndarray:
    poses = np.column_stack([rng.normal(0, 50, (k, 2)), rng.uniform(-np.pi, np.pi, k)])
    poses[:5, 2] = [0.0, 1e-12, -3e-9, np.pi - 1e-12, -np.pi + 1e-12]
    return poses


def _pose2(row: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(*row)


def _row(pose: gtsam.Pose2) -> np.ndarray:
    return np.array([pose.x(), pose.y(), pose.theta()])


def _close(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> None:
    difference = a - b
    difference[..., 2] = se2.wrap(difference[..., 2])  # angles agree modulo 2 pi
    np.testing.assert_allclose(difference, 0.0, atol=tol * max(1.0, np.abs(b).max()))


@pytest.fixture(scope="module")
def pairs():
    rng = np.random.default_rng(7)
    return _poses(rng), _poses(rng)


def test_compose_inverse_between_match_pose2(pairs):
    a, b = pairs
    _close(se2.compose(a, b),
           np.array([_row(_pose2(p) * _pose2(q)) for p, q in zip(a, b, strict=True)]))
    _close(se2.inverse(a), np.array([_row(_pose2(p).inverse()) for p in a]))
    _close(se2.between(a, b), np.array([_row(_pose2(p).between(_pose2(q)))
                                         for p, q in zip(a, b, strict=True)]))


def test_adjoint_and_logmap_match_pose2(pairs):
    a, _ = pairs
    np.testing.assert_allclose(se2.adjoint(a), np.array([_pose2(p).AdjointMap() for p in a]),
                               rtol=0, atol=1e-9 * np.abs(a).max())
    # GTSAM's Logmap at tiny angles is ill-conditioned in both implementations alike (their
    # angle sources differ by rounding): compare away from 0 strictly, near 0 loosely
    expected = np.array([gtsam.Pose2.Logmap(_pose2(p)) for p in a])
    got = se2.logmap(a)
    far = np.abs(a[:, 2]) > 1e-6
    np.testing.assert_allclose(got[far], expected[far], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got[~far], expected[~far], rtol=0, atol=1e-5)


def test_chain_composes_the_steps_from_the_origin():
    rng = np.random.default_rng(3)
    steps = np.column_stack([rng.normal(1, 0.2, (60, 2)), rng.normal(0, 0.5, 60)])
    pose, expected = gtsam.Pose2(), [np.zeros(3)]
    for step in steps:
        pose = pose * _pose2(step)
        expected.append(_row(pose))
    _close(se2.chain(steps), np.array(expected), tol=1e-12)


def test_the_chordal_cost_of_an_angle_is_the_frobenius_distance():
    rng = np.random.default_rng(5)
    residuals = rng.uniform(-np.pi, np.pi, 100)
    r = se2.rotation_matrices(residuals)
    frobenius = np.sum((r - np.eye(2)) ** 2, axis=(1, 2))  # ||R_i R~ - R_j||^2 = ||R(r) - I||^2
    np.testing.assert_allclose(se2.chordal_edge_costs(residuals), frobenius, rtol=1e-12,
                               atol=1e-15)
    assert se2.CHORDAL_ROOT ** 2 == pytest.approx(se2.CHORDAL_SCALE)
