"""Pose3 core: SE(3) maths against GTSAM, the 3D g2o reader against gtsam.readG2o and its
errors, priors and FIX, the chordal estimate and the certified relaxation on exact graphs."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

import rlpgo_gtsam.relaxation.stiefel as spatial
from rlpgo_gtsam import se3
from rlpgo_gtsam.chordal import chordal_rotations
from rlpgo_gtsam.errors import G2oFormatError, GraphError, SolverError
from rlpgo_gtsam.graph import PoseGraph3D, chi2, edge_chi2
from rlpgo_gtsam.groups import SE3
from rlpgo_gtsam.initializers import initializer_names, make_initializer
from rlpgo_gtsam.io import g2o_text, read_g2o, write_g2o
from rlpgo_gtsam.linear import DenseCholesky
from rlpgo_gtsam.relaxation import Status, certify, staircase, synchronize
from rlpgo_gtsam.relaxation.blocks import polar_svd
from rlpgo_gtsam.relaxation.newton import newton_point
from rlpgo_gtsam.se3 import pose_matrices
from rlpgo_gtsam.translations import TranslationStep, poses_with_rotations

DATA = Path("/work/shared/datasets/3d")


def _rotations(rng: np.random.Generator, k: int, scale: float = 1.0) -> np.ndarray:
    return se3.exp_so3(scale * rng.normal(size=(k, 3)))


def _exact_graph(rng: np.random.Generator, n: int = 40, closures: int = 15,
                 noise: float = 0.0) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values,
                                              np.ndarray, np.ndarray]:
    """A random 3D trajectory with odometry and loop closures; measurements exact (or with
    ``noise``); values: the truth perturbed, the first pose exact."""
    steps_r = _rotations(rng, n, 0.3)
    rotations, translations = [np.eye(3)], [np.zeros(3)]
    for k in range(1, n):
        rotations.append(rotations[-1] @ steps_r[k])
        translations.append(translations[-1] + rotations[-2] @ rng.normal(size=3))
    rotations, translations = np.array(rotations), np.array(translations)
    pairs = [(k, k + 1) for k in range(n - 1)]
    while len(pairs) < n - 1 + closures:
        i, j = sorted(rng.choice(n, 2, replace=False).tolist())
        if j > i + 1 and (i, j) not in pairs:
            pairs.append((i, j))
    graph = gtsam.NonlinearFactorGraph()
    info = np.diag([50.0, 60.0, 70.0, 5.0, 6.0, 7.0])
    info[0, 4] = info[4, 0] = 2.0
    for i, j in pairs:
        r_ij, t_ij = se3.between(rotations[[i]], translations[[i]], rotations[[j]],
                                 translations[[j]])
        r_ij = r_ij @ se3.exp_so3(noise * rng.normal(size=(1, 3)))
        measured = gtsam.Pose3(gtsam.Rot3(r_ij[0]), t_ij[0] + noise * rng.normal(size=3))
        graph.add(gtsam.BetweenFactorPose3(i, j, measured,
                                           gtsam.noiseModel.Gaussian.Information(info)))
    values = gtsam.Values()
    wrong_r = rotations @ _rotations(rng, n, 0.2)
    wrong_r[0] = rotations[0]
    wrong_t = translations + rng.normal(size=(n, 3)) * np.r_[0, np.ones(n - 1)][:, None]
    for k in range(n):
        values.insert(k, gtsam.Pose3(gtsam.Rot3(wrong_r[k]), wrong_t[k]))
    return graph, values, rotations, translations


# --- SE(3) maths -------------------------------------------------------------------------

def test_se3_against_gtsam():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(6, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    w = np.vstack([rng.normal(size=(30, 3)), 1e-12 * rng.normal(size=(4, 3)),
                   1e-6 * rng.normal(size=(4, 3)), np.pi * axes, (np.pi - 1e-7) * axes])
    expected = np.array([gtsam.Rot3.Expmap(v).matrix() for v in w])
    assert np.allclose(se3.exp_so3(w), expected, atol=1e-14)
    logs = se3.log_so3(expected)
    gtsam_logs = np.array([gtsam.Rot3.Logmap(gtsam.Rot3(r)) for r in expected])
    # at exactly pi, w and -w are the same rotation
    assert np.allclose(np.minimum(np.abs(logs - gtsam_logs).max(1),
                                  np.abs(logs + gtsam_logs).max(1)), 0, atol=1e-12)
    assert np.allclose(se3.exp_so3(logs), expected, atol=1e-14)
    t = rng.normal(size=(len(w), 3))
    keep = slice(0, 38)  # away from pi, where the sign of Log is a convention
    pose_logs = np.array([gtsam.Pose3.Logmap(gtsam.Pose3(gtsam.Rot3(r), v))
                          for r, v in zip(expected, t, strict=True)])
    assert np.allclose(se3.logmap(expected, t)[keep], pose_logs[keep], atol=1e-11)
    q = se3.rotations_to_quaternions(expected)
    for quaternion, r in zip(q, expected, strict=True):
        g = gtsam.Rot3(r).toQuaternion()
        assert np.allclose(np.abs(quaternion @ [g.x(), g.y(), g.z(), g.w()]), 1.0, atol=1e-14)
    assert np.allclose(se3.quaternions_to_rotations(q), expected, atol=1e-14)
    noisy = expected + 0.1 * rng.normal(size=expected.shape)
    projected = se3.project_to_so3(noisy)
    assert np.allclose(np.linalg.det(projected), 1.0)
    assert np.allclose(projected @ np.transpose(projected, (0, 2, 1)), np.eye(3), atol=1e-14)
    adjoints = np.array([gtsam.Pose3(gtsam.Rot3(r), v).AdjointMap()
                         for r, v in zip(expected, t, strict=True)])
    assert np.allclose(se3.adjoint(expected, t), adjoints, atol=1e-12)
    r_ab, t_ab = se3.between(expected[:5], t[:5], expected[5:10], t[5:10])
    for k in range(5):
        a = gtsam.Pose3(gtsam.Rot3(expected[k]), t[k])
        b = gtsam.Pose3(gtsam.Rot3(expected[5 + k]), t[5 + k])
        assert np.allclose(a.between(b).matrix()[:3], np.c_[r_ab[k], t_ab[k]], atol=1e-13)


def test_edge_chi2_is_gtsam_error():
    graph, values, _, _ = _exact_graph(np.random.default_rng(2), noise=0.1)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert np.isclose(edge_chi2(g, g.poses).sum(), chi2(graph, values),
                      rtol=1e-12)


# --- the 3D reader -----------------------------------------------------------------------

@pytest.mark.parametrize("name", ["tinyGrid3D", "smallGrid3D"])
def test_reader_matches_gtsam(name):
    path = DATA / f"{name}.g2o"
    if not path.exists():
        pytest.skip(f"{path} absent")
    graph, values = read_g2o(path)
    expected_graph, expected_values = gtsam.readG2o(str(path), True)
    assert graph.size() == expected_graph.size()
    for k in range(graph.size()):
        ours, theirs = graph.at(k), expected_graph.at(k)
        assert ours.keys() == theirs.keys()
        assert np.allclose(ours.measured().matrix(), theirs.measured().matrix(), atol=1e-12)
        assert np.allclose(ours.noiseModel().information(), theirs.noiseModel().information(),
                           rtol=1e-12, atol=1e-12)
    assert sorted(values.keys()) == sorted(expected_values.keys())
    for key in values.keys():
        assert np.allclose(values.atPose3(key).matrix(), expected_values.atPose3(key).matrix(),
                           atol=1e-12)
    assert np.isclose(chi2(graph, values), chi2(expected_graph, expected_values), rtol=1e-12)


def test_writer_round_trip(tmp_path):
    graph, values, _, _ = _exact_graph(np.random.default_rng(3), n=8, closures=3, noise=0.1)
    graph.add(gtsam.PriorFactorPose3(2, values.atPose3(2), gtsam.noiseModel.Constrained.All(6)))
    path = tmp_path / "g.g2o"
    write_g2o(path, graph, values)
    back, back_values = read_g2o(path)
    for key in values.keys():  # 15 significant digits of a quaternion: equal to 1e-14
        assert np.allclose(back_values.atPose3(key).matrix(), values.atPose3(key).matrix(),
                           atol=1e-14)
    assert g2o_text(back, back_values).count("\n") == path.read_text().count("\n")
    assert np.isclose(chi2(back, back_values), chi2(graph, values), rtol=1e-12)
    assert isinstance(back.at(back.size() - 1), gtsam.PriorFactorPose3)


_VERTEX = "VERTEX_SE3:QUAT {} 0 0 0 0 0 0 1"
_INFO = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
_EDGE = "EDGE_SE3:QUAT {} {} 1 0 0 0 0 0 1 " + _INFO


@pytest.mark.parametrize(("lines", "line", "reason"), [
    ([_VERTEX.format(0), _VERTEX.format(1), "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0"], 3,
     "needs 30 numbers after the tag, found 11"),
    ([_VERTEX.format(0), "VERTEX_SE3:QUAT 1 0 0 0 0 0 1", _EDGE.format(0, 1)], 2,
     "needs 8 numbers after the tag, found 7"),
    ([_VERTEX.format(0), "VERTEX_SE3:QUAT 1 nan 0 0 0 0 0 1", _EDGE.format(0, 1)], 2,
     "field 2 is not finite"),
    ([_VERTEX.format(0), _VERTEX.format(1), "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 0 " + _INFO], 3,
     "quaternion (0.0, 0.0, 0.0, 0.0) is zero"),
    ([_VERTEX.format(0), _VERTEX.format(1), "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1"], 3,
     "a planar line in a 3D file"),
    ([_VERTEX.format(0), _VERTEX.format(1), _EDGE.format(0, 2)], 3,
     "refers to vertex 2, which no VERTEX_SE3:QUAT line defines"),
    ([_VERTEX.format(0), _VERTEX.format(1), _EDGE.format(0, 1).replace(_INFO, "-" + _INFO)], 3,
     "not positive definite"),
    ([_VERTEX.format(0), _VERTEX.format(0)], 2, "id 0 defined twice (first on line 1)"),
    ([_VERTEX.format(0), _VERTEX.format(1), _EDGE.format(0, 1), "FIX 7"], 4,
     "FIX refers to vertex 7"),
])
def test_reader_errors_name_the_line(tmp_path, lines, line, reason):
    path = tmp_path / "bad.g2o"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(G2oFormatError) as caught:
        read_g2o(path)
    assert str(caught.value).startswith(f"{path}:{line}: ")
    assert reason in str(caught.value)


def test_reader_normalizes_quaternions_and_chains_odometry(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 2 " + _INFO + "\n"
                    "EDGE_SE3:QUAT 1 2 0 1 0 0 0 0.7071067811865476 0.7071067811865476 "
                    + _INFO + "\n")
    graph, values = read_g2o(path)
    assert np.allclose(graph.at(0).measured().rotation().matrix(), np.eye(3))
    assert np.allclose(values.atPose3(2).translation(), [1, 1, 0])
    assert np.isclose(chi2(graph, values), 0.0, atol=1e-20)


# --- priors, FIX, initializers -----------------------------------------------------------

def test_fix_and_priors_are_honoured(tmp_path):
    graph, values, _, _ = _exact_graph(np.random.default_rng(4), n=12, closures=4, noise=0.05)
    path = tmp_path / "g.g2o"
    graph.add(gtsam.PriorFactorPose3(3, values.atPose3(3), gtsam.noiseModel.Constrained.All(6)))
    graph.add(gtsam.PriorFactorPose3(7, values.atPose3(7), gtsam.noiseModel.Constrained.All(6)))
    write_g2o(path, graph, values)
    graph, values = read_g2o(path)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert g.anchor == 3 and g.fixed.tolist() == [3, 7]
    for name in initializer_names(SE3):
        result = make_initializer(name).run(g)
        for key in (3, 7):
            assert np.allclose(result.values.atPose3(key).matrix(),
                               values.atPose3(key).matrix(), atol=1e-9), name
    soft = gtsam.NonlinearFactorGraph()
    for k in range(graph.size() - 2):
        soft.add(graph.at(k))
    prior = gtsam.Pose3(gtsam.Rot3.Rodrigues(0.1, 0.2, 0.3), np.array([1.0, 2.0, 3.0]))
    soft.add(gtsam.PriorFactorPose3(5, prior, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    g = PoseGraph3D.from_gtsam(soft, values)
    assert g.anchor == 5 and len(g.fixed) == 0
    result = make_initializer("chordal").run(g)
    assert np.allclose(result.values.atPose3(5).matrix(), prior.matrix(), atol=1e-12)


def test_graph_errors_name_what_they_refuse():
    graph, values, _, _ = _exact_graph(np.random.default_rng(5), n=5, closures=1)
    graph.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    with pytest.raises(GraphError, match="unsupported factor BetweenFactorPose2"):
        PoseGraph3D.from_gtsam(graph, values)
    values.insert(9, gtsam.Pose3())
    with pytest.raises(GraphError, match="connected components"):
        PoseGraph3D.from_gtsam(_exact_graph(np.random.default_rng(5), n=5, closures=1)[0],
                               values)


# --- chordal and certified on exact graphs -----------------------------------------------

def test_chordal_recovers_an_exact_graph():
    graph, values, rotations, _ = _exact_graph(np.random.default_rng(6))
    g = PoseGraph3D.from_gtsam(graph, values)
    assert np.allclose(chordal_rotations(g), rotations, atol=1e-10)


def test_rounding_at_rank_3_keeps_the_blocks_as_the_svd_route_would():
    """At rank 3 with every block a rotation the rounding returns ``X_i^T``; the rank-3 SVD
    route (taken here with a zero column) gives the same rotations once the anchor is turned
    back; a block with a negative determinant sends rank 3 to the SVD route as well."""

    graph, values = gtsam.readG2o(str(DATA / "smallGrid3D.g2o"), True)
    g = PoseGraph3D.from_gtsam(graph, values)
    rotations, certificate = synchronize(g)
    assert certificate.rank == 3
    x = spatial._stack(rotations)

    def anchored(r):
        return r[g.anchor].T @ r

    kept = spatial._round(x)
    assert np.array_equal(kept, rotations)
    svd = spatial._round(np.hstack([x, np.zeros((len(x), 1))]))
    assert np.allclose(anchored(kept), anchored(svd), rtol=0, atol=1e-14)
    x[3:6] = np.diag([1.0, 1.0, -1.0]) @ x[3:6]  # block 1 reflected
    mixed = spatial._round(x)
    assert np.allclose(np.linalg.det(mixed), 1.0)
    assert np.allclose(anchored(mixed)[2:], anchored(svd)[2:], rtol=0, atol=1e-12)


def test_the_dense_chordal_through_the_connection_laplacian_is_the_pairwise_one():
    """The certified relaxation's small graphs hand their connection Laplacian to the chordal
    estimate: the same rotations as the pairwise normal equations, held poses kept; a
    matrix whose factor fails (here all zeros) hands over to the pairwise solve."""

    graph, values, _, _ = _exact_graph(np.random.default_rng(4), n=12, closures=4, noise=0.3)
    graph.add(gtsam.PriorFactorPose3(3, values.atPose3(3), gtsam.noiseModel.Constrained.All(6)))
    graph.add(gtsam.PriorFactorPose3(7, values.atPose3(7), gtsam.noiseModel.Constrained.All(6)))
    cases = [(graph, values)] + [gtsam.readG2o(str(DATA / f"{name}.g2o"), True)
                                 for name in ("tinyGrid3D", "smallGrid3D")]
    for graph, values in cases:
        g = PoseGraph3D.from_gtsam(graph, values)
        connection = spatial.SpatialProblem(g).connection
        assert connection is not None
        pairwise = chordal_rotations(g)
        dense = chordal_rotations(g, connection)
        assert np.allclose(dense, pairwise, rtol=0, atol=1e-12)
        held, held_poses = g.held
        assert np.array_equal(dense[held], held_poses[:, :, :3])
        assert np.array_equal(chordal_rotations(g, np.zeros_like(connection)), pairwise)


def test_certified_recovers_an_exact_graph_and_refuses_a_wrong_estimate():
    graph, values, rotations, translations = _exact_graph(np.random.default_rng(7), n=60,
                                                          closures=25)
    g = PoseGraph3D.from_gtsam(graph, values)
    start = rotations @ _rotations(np.random.default_rng(8), g.num_poses, 0.3)
    found, certificate = synchronize(g, start, gradient_tolerance=1e-12)
    assert certificate.status == Status.CERTIFIED, certificate.describe()
    assert certificate.describe().startswith("certified optimal")
    poses = poses_with_rotations(g, found)
    found, positions = poses[:, :, :3], poses[:, :, 3]
    assert np.allclose(found, rotations, atol=1e-8)
    assert np.allclose(positions, translations, atol=1e-8)
    wrong = certify(g, start)
    assert not wrong.certified and wrong.status == Status.NOT_OPTIMAL
    assert wrong.suboptimality_bound > 0


def test_certified_on_a_noisy_graph_is_certified_and_refined_by_gtsam():
    graph, values, _, _ = _exact_graph(np.random.default_rng(9), n=50, closures=20, noise=0.05)
    result = make_initializer("certified").run(PoseGraph3D.from_gtsam(graph, values))
    assert result.certificate.certified, result.certificate.describe()
    assert result.poses.shape == (50, 3, 4)
    chordal = make_initializer("chordal").run(PoseGraph3D.from_gtsam(graph, values))
    assert result.chi2 <= chordal.chi2 * 1.5


@pytest.mark.parametrize("case", ["tinyGrid3D", "generated"])
def test_the_dense_path_of_small_graphs_agrees_with_the_sparse_one(monkeypatch, case):
    """Below the dense sizes (Q of rows < dense_below, normal equations of fewer unknowns
    than the linear solver's threshold) the relaxation, the chordal estimate and the
    translation step are solved densely: the same certificate and estimate as the sparse
    path, to round-off (both from the trust region: Newton's start is left out here, see
    the next test)."""
    import rlpgo_gtsam.linear as linear

    monkeypatch.setattr(spatial, "_NEWTON_BELOW", 0)

    if case == "tinyGrid3D":
        graph, values = gtsam.readG2o(str(DATA / "tinyGrid3D.g2o"), True)
    else:
        graph, values, _, _ = _exact_graph(np.random.default_rng(3), n=40, closures=20,
                                           noise=0.05)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert 3 * g.num_poses < spatial.manifold().dense_below
    assert 3 * (g.num_poses - 1) < linear._DENSE_BELOW
    assert spatial.SpatialProblem(g).dense
    dense = make_initializer("certified").run(g)
    monkeypatch.setattr(spatial, "_DENSE_BELOW", 0)
    monkeypatch.setattr(spatial, "_DENSE_Q_BELOW", 0)
    monkeypatch.setattr(linear, "_DENSE_BELOW", 0)
    assert not spatial.SpatialProblem(g).dense
    sparse = make_initializer("certified").run(g)
    a, b = dense.certificate, sparse.certificate
    assert a.status == b.status == Status.CERTIFIED and a.rank == b.rank == 3
    scale = abs(b.estimate_cost)
    for field in ("lower_bound", "estimate_cost"):
        assert getattr(a, field) == pytest.approx(getattr(b, field), rel=1e-10)
    assert abs(a.min_eigenvalue - b.min_eigenvalue) <= 1e-10 * scale
    assert a.suboptimality_bound <= a.tolerance * 3 * g.num_poses
    assert np.allclose(dense.poses, sparse.poses, atol=1e-9)
    assert dense.chi2 == pytest.approx(sparse.chi2, rel=1e-10)


def test_skew_is_the_cross_product_and_vee_inverts_it():
    w, v = np.random.default_rng(0).normal(size=(2, 7, 3))
    assert np.allclose(se3.skew(w) @ v[:, :, None], np.cross(w, v)[:, :, None], atol=1e-15)
    assert np.array_equal(se3.vee(se3.skew(w)), w)


@pytest.mark.parametrize("case", ["tinyGrid3D", "generated", "exact"])
def test_newtons_start_on_small_graphs_reaches_the_trust_regions_optimum(monkeypatch, case):
    """Below ``_NEWTON_BELOW`` rows the staircase starts from Newton's point
    (:func:`~rlpgo_gtsam.relaxation.newton.newton_point`): the same certificate as the
    trust region alone, whose
    rotations (run to a gradient 1e-6 times its default tolerance) agree to 1e-9; S is
    verified there without the trust region, which would take no iteration (the same
    rotations and certificate to the bit as the staircase run from that point); an exact
    graph is recovered."""

    rng = np.random.default_rng(3)
    if case == "tinyGrid3D":
        graph, values = gtsam.readG2o(str(DATA / "tinyGrid3D.g2o"), True)
    else:
        graph, values, truth, _ = _exact_graph(rng, n=40, closures=20,
                                               noise=0.05 if case == "generated" else 0.0)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert 3 * g.num_poses < spatial._NEWTON_BELOW
    iterations = []
    trust_region = staircase.trust_region

    def counted(*args, **kwargs):
        y, ended = trust_region(*args, **kwargs)
        iterations.append(args[7].iterations)
        return y, ended

    monkeypatch.setattr(staircase, "trust_region", counted)
    newton, a = synchronize(g)
    assert iterations == []
    with monkeypatch.context() as patch:  # the staircase from Newton's point
        patch.setattr(spatial, "_verified_at_once", lambda *args: None)
        climbed, c = synchronize(g)
    assert iterations == [0]
    assert np.array_equal(climbed, newton)
    assert (c.status, c.lower_bound, c.estimate_cost, c.min_eigenvalue, c.rank) == \
        (a.status, a.lower_bound, a.estimate_cost, a.min_eigenvalue, a.rank)
    monkeypatch.setattr(spatial, "_NEWTON_BELOW", 0)
    tight, b = synchronize(g, gradient_tolerance=1e-12)
    assert iterations[1] > 0 or case == "exact"  # the chordal estimate is exact there
    assert a.status == b.status == Status.CERTIFIED and a.rank == b.rank == 3
    scale = abs(b.estimate_cost) + 1.0
    assert abs(a.estimate_cost - b.estimate_cost) <= 1e-10 * scale
    assert abs(a.lower_bound - b.lower_bound) <= 1e-10 * scale
    assert abs(a.min_eigenvalue - b.min_eigenvalue) <= 1e-10 * scale
    assert np.allclose(newton, tight, atol=1e-7)
    if case == "exact":
        assert np.allclose(newton, truth, atol=1e-9)


def test_newtons_damping_takes_a_start_where_the_hessian_is_indefinite():
    """smallGrid3D's chordal estimate has an indefinite Newton Hessian (S has eigenvalues
    down to -3.4 there): the damped steps still reach the gradient tolerance, at the trust
    region's cost."""
    import math


    graph, values = gtsam.readG2o(str(DATA / "smallGrid3D.g2o"), True)
    g = PoseGraph3D.from_gtsam(graph, values)
    problem = spatial.SpatialProblem(g)
    x = spatial._stack(chordal_rotations(g))
    tolerance = 1e-6 * math.sqrt(problem.n) * problem.scale
    y, converged = newton_point(problem, x, tolerance, g.anchor, None)
    assert converged
    stiefel = spatial.manifold()
    qy = problem.apply(y)
    gradient = 2.0 * (qy - stiefel.times(stiefel.multipliers(y, qy), y))
    assert np.linalg.norm(gradient) <= tolerance
    reached, _ = staircase.trust_region(problem, stiefel, x, 300, tolerance)
    assert problem.cost(y) == pytest.approx(problem.cost(reached), rel=1e-10)


def test_the_small_graph_path_recovers_an_exact_graph_and_refuses_a_wrong_estimate(
        monkeypatch):
    """A small graph (below ``_NEWTON_BELOW`` rows) is certified at Newton's point without
    the staircase's trust region: the ground truth recovered, rotations and positions; a
    wrong estimate of it refused by the certificate."""

    graph, values, rotations, translations = _exact_graph(np.random.default_rng(11), n=12,
                                                          closures=6)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert 3 * g.num_poses < spatial._NEWTON_BELOW
    calls = []
    trust_region = staircase.trust_region
    monkeypatch.setattr(staircase, "trust_region",
                        lambda *args, **kwargs: calls.append(1) or trust_region(*args,
                                                                                **kwargs))
    result = make_initializer("certified").run(g)
    assert calls == []
    certificate = result.certificate
    assert certificate.status == Status.CERTIFIED and certificate.rank == 3
    assert certificate.describe().startswith("certified optimal")
    assert np.allclose(result.poses[:, :, :3], rotations, atol=1e-8)
    assert np.allclose(result.poses[:, :, 3], translations, atol=1e-8)
    assert result.chi2 < 1e-12
    wrong = certify(g, rotations @ _rotations(np.random.default_rng(12), g.num_poses, 0.3))
    assert wrong.status == Status.NOT_OPTIMAL and not wrong.certified
    assert wrong.min_eigenvalue < -wrong.tolerance and wrong.suboptimality_bound > 0


def test_the_small_graph_path_hands_a_relaxation_that_is_not_exact_to_the_staircase(
        monkeypatch):
    """Where S is not positive semidefinite at Newton's point (a small graph with 0.8 rad of
    rotation noise), the staircase runs from that point and escapes: the same rotations and
    certificate, to the bit, as the staircase from Newton's point, not certified."""
    from rlpgo_gtsam.synthetic import generate

    sample = generate(20, 0.8, 0.1, 1.0, 0.5, np.random.default_rng(2),
                      noisy_measurements=True, group=SE3)
    g = PoseGraph3D.from_gtsam(sample.graph, sample.initial)
    assert 3 * g.num_poses < spatial._NEWTON_BELOW
    rotations, certificate = synchronize(g)
    assert certificate.rank > 3 and not certificate.certified
    assert certificate.describe().startswith("NOT certified")
    monkeypatch.setattr(spatial, "_verified_at_once", lambda *args: None)
    climbed, staircase_certificate = synchronize(g)
    assert np.array_equal(rotations, climbed)
    for field in ("status", "lower_bound", "estimate_cost", "min_eigenvalue", "rank"):
        assert getattr(certificate, field) == getattr(staircase_certificate, field)


def test_the_dense_pairwise_solve_is_the_sparse_one(monkeypatch):
    """Below ``_DENSE_BELOW`` unknowns :func:`solve_block_pairwise` scatters each residual's
    block into dense normal equations: the same minimizer as the sparse LU's, to round-off,
    with held unknowns in any order, several right-hand sides and weights (one at zero,
    left out)."""
    import rlpgo_gtsam.linear as linear

    rng = np.random.default_rng(13)
    n, m = 15, 40
    edges = np.array([rng.choice(n, 2, replace=False) for _ in range(m)])
    edges[: n - 1] = np.c_[np.arange(n - 1), np.arange(1, n)]  # a chain: connected
    a_i, a_j = rng.normal(size=(2, m, 3, 3))
    b = rng.normal(size=(m, 3, 4))
    held = np.array([9, 2, 5])
    held_values = rng.normal(size=(3, 3, 4))
    weights = rng.uniform(0.5, 2.0, size=m)
    weights[20] = 0.0
    dense = linear.solve_block_pairwise(n, edges, a_i, a_j, b, held, held_values,
                                                weights)
    monkeypatch.setattr(linear, "_DENSE_BELOW", 0)
    sparse = linear.solve_block_pairwise(n, edges, a_i, a_j, b, held, held_values,
                                                 weights)
    assert np.array_equal(dense[held], held_values)
    assert np.allclose(dense, sparse, rtol=0, atol=1e-10 * np.abs(sparse).max())


@pytest.mark.parametrize("noise", [0.05, 0.5])
def test_a_dense_q_verified_by_arpack_agrees_with_the_sparse_path(monkeypatch, noise):
    """Between the dense eigenvalue size and ``_DENSE_Q_BELOW`` rows, Q is dense, its
    factors dense Cholesky factors (S + eta I's proves S's inertia, then ARPACK's
    shift-invert runs through it): the same certificate and estimate as the sparse LU path,
    to round-off, on a graph that certifies at rank 3 and on one whose staircase climbs."""

    graph, values, _, _ = _exact_graph(np.random.default_rng(5), n=80, closures=40,
                                       noise=noise)
    g = PoseGraph3D.from_gtsam(graph, values)
    assert spatial.manifold().dense_below <= 3 * g.num_poses < spatial._DENSE_Q_BELOW
    problem = spatial.SpatialProblem(g)
    assert problem.dense
    factor = problem.factor(spatial.manifold().diagonal(g.num_poses, problem.scale))
    assert isinstance(factor, DenseCholesky)
    assert spatial.manifold().negative_pivots(factor) == 0
    dense = make_initializer("certified").run(g)
    monkeypatch.setattr(spatial, "_DENSE_Q_BELOW", 0)
    assert not spatial.SpatialProblem(g).dense
    sparse = make_initializer("certified").run(g)
    a, b = dense.certificate, sparse.certificate
    assert a.status == b.status and a.rank == b.rank
    assert (a.status, a.rank == 3) == ((Status.CERTIFIED, True) if noise < 0.1 else
                                       (Status.NOT_TIGHT, False))
    scale = abs(b.estimate_cost)
    for field in ("lower_bound", "estimate_cost"):
        assert getattr(a, field) == pytest.approx(getattr(b, field), rel=1e-9)
    assert abs(a.min_eigenvalue - b.min_eigenvalue) <= 1e-9 * scale
    assert np.allclose(dense.poses, sparse.poses, atol=1e-7)
    assert dense.chi2 == pytest.approx(sparse.chi2, rel=1e-9)


def test_the_isotropic_translation_step_is_the_same_with_a_dense_laplacian(monkeypatch):
    """Below ``_DENSE_LAPLACIAN_BELOW`` free poses the CG translation step's incidence and
    scalar Laplacian are dense arrays: the same positions as the sparse ones, to round-off,
    and GTSAM's chi2 there the same."""
    import rlpgo_gtsam.linear as linear
    from rlpgo_gtsam.synthetic import generate

    sample = generate(80, 0.05, 0.1, 1.0, 0.5, np.random.default_rng(4),
                      noisy_measurements=True, group=SE3)
    g = PoseGraph3D.from_gtsam(sample.graph, sample.initial)
    assert linear._DENSE_BELOW <= 3 * (g.num_poses - 1)
    assert g.num_poses - 1 < linear._DENSE_LAPLACIAN_BELOW
    step = TranslationStep(g)
    rotations = chordal_rotations(g)
    a_j, b = step.whitened(rotations)
    held, held_poses = g.held
    held_t = held_poses[:, :, 3]
    solved = []
    for below in (linear._DENSE_LAPLACIAN_BELOW, 0):
        monkeypatch.setattr(linear, "_DENSE_LAPLACIAN_BELOW", below)
        positions = linear.solve_isotropic(g.num_poses, g.edges, a_j, b, held, held_t)
        assert positions is not None  # the isotropic step ran, not the 3n fallback
        solved.append((positions, step.solve(rotations)[1]))
    (dense, dense_chi2), (sparse, sparse_chi2) = solved
    assert np.allclose(dense, sparse, atol=1e-10)
    assert dense_chi2 == pytest.approx(sparse_chi2, rel=1e-12)
    exact = linear.solve_block_pairwise(g.num_poses, g.edges, -a_j, a_j, b, held, held_t)
    assert np.allclose(dense, exact, atol=1e-8)


def test_an_undetermined_pose_is_named_alike_by_the_dense_and_the_sparse_solve(monkeypatch):
    """A dense factor that fails hands over to the sparse LU, whose pivots name the pose."""
    import rlpgo_gtsam.linear as linear

    blocks = np.broadcast_to(np.eye(3), (3, 3, 3))
    edges = np.array([[0, 1], [1, 3], [0, 3]])  # pose 2 is in no edge
    messages = []
    for dense_below in (0, 10**6):
        monkeypatch.setattr(linear, "_DENSE_BELOW", dense_below)
        with pytest.raises(SolverError, match="undetermined") as error:
            linear.solve_block_pairwise(4, edges, -blocks, blocks, np.ones((3, 3)),
                                                np.array([0]), np.zeros((1, 3)))
        messages.append(str(error.value))
        solved = linear.solve_block_pairwise(3, edges[:1], -blocks[:1], blocks[:1],
                                                     np.ones((1, 3)), np.array([0, 2]),
                                                     np.zeros((2, 3)))
        assert np.allclose(solved, [[0, 0, 0], [1, 1, 1], [0, 0, 0]])
    assert messages[0] == messages[1]


def test_certified_above_rank_three_polishes_its_rounded_rotations(monkeypatch):
    """Heavy rotation noise: the staircase ends above rank 3, not exact; the rounded
    rotations are polished at rank 3 into proper rotations no higher in cost, the anchor
    kept."""

    graph, values, rotations, _ = _exact_graph(np.random.default_rng(1), n=60, closures=40,
                                               noise=0.5)
    g = PoseGraph3D.from_gtsam(graph, values)
    found, certificate = synchronize(g)
    assert certificate.rank > 3 and certificate.status == Status.NOT_TIGHT
    assert np.allclose(np.linalg.det(found), 1.0)
    assert np.allclose(found[0], rotations[0], atol=1e-12)
    monkeypatch.setattr(staircase, "polish", lambda problem, manifold, x, *args, **kw: x)
    _, plain = synchronize(g)
    assert certificate.estimate_cost <= plain.estimate_cost
    assert certificate.lower_bound == pytest.approx(plain.lower_bound, rel=1e-12)


def test_the_blocks_products_on_fields_equal_the_small_matrix_products(monkeypatch):
    """From 50 poses the Stiefel blocks' projection, multipliers, Lambda V and Hessian run
    on (3, r, n) fields: the same numbers as the (n, 3, r) matrix products, at ranks 3 and 5,
    and the projection lands in the tangent space."""

    manifold = spatial.manifold()
    rng = np.random.default_rng(4)
    n = 80
    for r in (3, 5):
        x = manifold.retract(rng.normal(size=(3 * n, r)))
        v, qv, qx = (rng.normal(size=(3 * n, r)) for _ in range(3))
        fields = (manifold.project(x, v), manifold.multipliers(x, qx))
        lam = fields[1]
        fields += (manifold.times(lam, v), manifold.hessian(x, lam, v, qv))
        monkeypatch.setattr(spatial, "_FIELDS_FROM", n + 1)
        stacks = (manifold.project(x, v), manifold.multipliers(x, qx))
        stacks += (manifold.times(lam, v), manifold.hessian(x, lam, v, qv))
        monkeypatch.undo()
        for a, b in zip(fields, stacks, strict=True):
            assert a.shape == b.shape and np.allclose(a, b, rtol=0, atol=1e-12)
        xb, pb = x.reshape(n, 3, r), fields[0].reshape(n, 3, r)
        sym = pb @ xb.transpose(0, 2, 1)
        assert np.allclose(sym + sym.transpose(0, 2, 1), 0.0, atol=1e-12)


def test_truncated_cg_stops_at_half_the_gradient_tolerance_on_parking_garage(
        monkeypatch, hessian_products):
    """parking-garage's last trust-region step starts at a gradient just above the
    tolerance: CG stopping at half the tolerance (the 3D manifold's cg_floor) takes fewer
    Hessian products than CG solving to its relative target, and the staircase is certified
    at the same cost."""

    graph, values = gtsam.readG2o(str(DATA / "parking-garage.g2o"), True)
    g = PoseGraph3D.from_gtsam(graph, values)
    products = hessian_products
    assert spatial.manifold().cg_floor == 0.5
    _, floored = synchronize(g)
    with_floor, products[0] = products[0], 0
    monkeypatch.setattr(spatial, "_CG_FLOOR", 0.0)
    _, plain = synchronize(g)
    assert floored.certified and plain.certified
    assert with_floor < 0.75 * products[0]
    assert floored.estimate_cost == pytest.approx(plain.estimate_cost, rel=1e-8)
    assert floored.suboptimality_bound <= 1e-4 * floored.tolerance * 3 * g.num_poses


def test_the_newton_retraction_is_the_svd_polar_factor():
    """At rank 3 from 250 poses the retraction runs Newton's polar iteration: the SVD's polar
    factor to round-off along small and large tangent steps, orthonormal rows; a singular
    block falls back to the SVD."""

    rng = np.random.default_rng(5)
    stiefel = spatial.manifold()
    n = spatial._NEWTON_FROM
    x = spatial._stack(_rotations(rng, n))
    for size in (0.01, 1.0, 5.0):
        step = stiefel.project(x, size * rng.normal(size=x.shape))
        moved = x + step
        moved[3:6] = np.outer([1.0, 2.0, 3.0], [1.0, 1.0, 1.0])  # rank one
        polar = stiefel.retract(moved)
        assert np.allclose(polar, polar_svd(moved), rtol=0, atol=1e-12)
        blocks = polar.reshape(n, 3, 3)
        assert np.allclose(blocks @ blocks.transpose(0, 2, 1), np.eye(3), atol=1e-12)


def test_the_closed_form_trial_point_is_the_svd_polar_factor():
    """From ``_CLOSED_FROM`` to ``_NEWTON_FROM`` poses the trust region's rank-3 trial point
    ``X + V`` is retracted in closed form (``Exp(atan|w| / |w| w) X_i``): the SVD's polar
    factor to 1e-13 along tangent steps from 1e-6 to 5, orthonormal rows; a zero step keeps
    X; other sizes and ranks take the retraction."""

    rng = np.random.default_rng(6)
    stiefel = spatial.manifold()
    for n in (spatial._CLOSED_FROM, spatial._NEWTON_FROM - 1):
        x = spatial._stack(_rotations(rng, n))
        for size in (1e-6, 0.3, 5.0):
            step = stiefel.project(x, size * rng.normal(size=x.shape))
            moved = stiefel.move(x, step)
            assert np.allclose(moved, polar_svd(x + step), rtol=0, atol=1e-13)
            blocks = moved.reshape(n, 3, 3)
            assert np.allclose(blocks @ blocks.transpose(0, 2, 1), np.eye(3), atol=1e-13)
        assert np.allclose(stiefel.move(x, np.zeros_like(x)), x, rtol=0, atol=1e-15)
    x = spatial._stack(_rotations(rng, spatial._CLOSED_FROM - 1))
    step = stiefel.project(x, rng.normal(size=x.shape))
    assert np.array_equal(stiefel.move(x, step), stiefel.retract(x + step))


def test_the_isotropic_translation_step_is_the_direct_solve():
    """Isotropic translation informations (a generated graph, held poses included): the
    translation step's CG with the scalar Laplacian gives the direct 3n solve's positions
    and chi2; anisotropic ones (5, 6, 7 on the axes) are left to the direct solve."""
    import rlpgo_gtsam.linear as linear
    from rlpgo_gtsam.synthetic import generate

    sample = generate(300, 0.05, 0.1, 1.0, 0.5, np.random.default_rng(2),
                      noisy_measurements=True, group=SE3)
    g = PoseGraph3D.from_gtsam(sample.graph, sample.initial)
    rotations = chordal_rotations(g)
    step = TranslationStep(g)
    a_j, b = step.whitened(rotations)
    held = np.array([g.anchor, 17, 150])
    held_t = np.random.default_rng(3).normal(size=(3, 3))
    fast = linear.solve_isotropic(g.num_poses, g.edges, a_j, b, held, held_t)
    assert fast is not None
    direct = linear.solve_block_pairwise(g.num_poses, g.edges, -a_j, a_j, b, held,
                                                 held_t)
    assert np.allclose(fast, direct, rtol=0, atol=1e-9 * np.abs(direct).max())
    assert np.array_equal(fast[held], held_t)
    assert edge_chi2(g, pose_matrices(rotations, fast)).sum() == pytest.approx(
        edge_chi2(g, pose_matrices(rotations, direct)).sum(), rel=1e-12)
    graph, values, _, _ = _exact_graph(np.random.default_rng(6), noise=0.05)
    g = PoseGraph3D.from_gtsam(graph, values)
    a_j, b = TranslationStep(g).whitened(chordal_rotations(g))
    held, held_poses = g.held
    held_t = held_poses[:, :, 3]
    assert linear.solve_isotropic(g.num_poses, g.edges, a_j, b, held, held_t) is None
