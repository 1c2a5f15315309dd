"""How the certified relaxation ends: every status of its certificate reached on a generated
graph (by the graph itself or by a forced limit), said in one line; the sparse verification
agrees with the dense one; the chordal estimate is the rank-1 optimum of an exact graph."""

import json
import math
import time

import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.init import main as init_main

import rlpgo_gtsam.relaxation.circles as circles
import rlpgo_gtsam.relaxation.staircase as staircase
from rlpgo_gtsam import PoseGraph2D, generate, write_g2o
from rlpgo_gtsam.chordal import chordal_rotations
from rlpgo_gtsam.relaxation import Status, certify, descend, relaxation_cost, synchronize
from rlpgo_gtsam.relaxation.trust_region import trust_region
from rlpgo_gtsam.relaxation.verification import verify
from rlpgo_gtsam.se2 import wrap


def _graph(n, sigma_r, seed, noisy=True) -> PoseGraph2D:
    sample = generate(n, sigma_r, 0.05, 3.0, 0.5, np.random.default_rng(seed),
                      noisy_measurements=noisy)
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial)


@pytest.fixture(scope="module")
def heavy_sample():
    """100 poses, sigma_R 0.5, noisy measurements: rank 1 is a saddle, rank 2 solves the
    relaxation, which is not exact."""
    return generate(100, 0.5, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)


@pytest.fixture(scope="module")
def heavy(heavy_sample) -> PoseGraph2D:
    return PoseGraph2D.from_gtsam(heavy_sample.graph, heavy_sample.initial)


def _ended(certificate, status: Status) -> None:
    """The certificate has ``status``, its ``certified`` agrees, and its line names it."""
    assert certificate.status == status and certificate.status is status
    assert certificate.certified is (status == "certified")
    record = certificate.record()
    assert record["status"] == status.value and type(record["status"]) is str
    assert record["certified"] is certificate.certified
    line = certificate.describe()
    assert "\n" not in line and f"rank {certificate.rank}" in line
    assert line.startswith("certified optimal" if certificate.certified else "NOT certified: ")
    assert line.endswith(f"{certificate.seconds:.2f} s)")


def test_an_exact_graph_ends_certified():
    theta, certificate = synchronize(_graph(100, 0.3, 21, noisy=False))
    _ended(certificate, Status.CERTIFIED)
    assert certificate.rank == 1 and certificate.suboptimality_bound < 1e-6


@pytest.mark.parametrize("iterations", [2, 300])
def test_descend_is_the_staircase_first_rank_without_its_verification(heavy, iterations):
    # the same trust region from the same chordal start: rank 1 held, capped alike
    theta, certificate = synchronize(heavy, max_rank=1, max_iterations=iterations)
    assert np.abs(wrap(descend(heavy, max_iterations=iterations) - theta)).max() < 1e-12
    assert certificate.rank == 1 and not certificate.certified  # a saddle there: no proof


def test_a_solved_relaxation_that_is_not_exact_ends_not_tight(heavy):
    _, certificate = synchronize(heavy)
    _ended(certificate, Status.NOT_TIGHT)
    assert certificate.min_eigenvalue >= -certificate.tolerance  # the relaxation is solved ...
    assert certificate.suboptimality_bound > 1.0  # ... but the rounded estimate misses it
    assert "not exact" in certificate.describe()


def test_max_rank_one_on_a_hard_graph_ends_at_the_rank_limit(heavy):
    _, certificate = synchronize(heavy, max_rank=1)
    _ended(certificate, Status.RANK_LIMIT)
    assert certificate.rank == 1 and certificate.min_eigenvalue < -certificate.tolerance
    assert "rank limit" in certificate.describe()


def test_too_few_trust_region_iterations_end_at_the_iteration_limit(heavy):
    _, certificate = synchronize(heavy, max_iterations=1, max_rank=3)
    _ended(certificate, Status.ITERATION_LIMIT)
    assert certificate.rank == 3 and "iteration limit" in certificate.describe()


def test_a_spent_time_limit_rounds_what_it_has_and_verifies_nothing(heavy):
    theta, certificate = synchronize(heavy, time_limit_s=0.0)
    _ended(certificate, Status.TIME_LIMIT)
    assert theta.shape == (heavy.num_poses,) and np.all(np.isfinite(theta))
    assert certificate.rank == 1 and certificate.seconds < 1.0
    assert math.isnan(certificate.min_eigenvalue) and math.isnan(certificate.lower_bound)
    assert certificate.record()["lower_bound"] is None  # strict JSON: no NaN
    assert math.isfinite(certificate.estimate_cost)
    assert "time limit" in certificate.describe() and "not verified" in certificate.describe()
    # A limit the call does not reach changes nothing.
    assert np.array_equal(synchronize(heavy, max_rank=1, time_limit_s=600.0)[0],
                          synchronize(heavy, max_rank=1)[0])


def test_progress_says_one_line_per_rank_and_changes_nothing(heavy):
    lines: list[str] = []
    theta, certificate = synchronize(heavy, progress=lines.append)
    ranks = [line for line in lines if "iterations," in line]
    assert [line.split(":")[0] for line in ranks] == \
        [f"rank {r}" for r in range(1, certificate.rank + 1)] + ["rounded estimate polished"]
    assert all("cost" in line and "gradient" in line and line.endswith(" s") for line in ranks)
    assert all("\n" not in line and len(line) < 120 for line in lines)
    again, same = synchronize(heavy)
    assert np.array_equal(theta, again) and same.estimate_cost == certificate.estimate_cost


def test_a_stalled_rank_is_verified_where_it_stands_and_its_bound_holds(heavy, monkeypatch):
    """A trust region that stops lowering the cost by 1% of n eta per 10 iterations ends its
    rank; the bound tr(Lambda) + n min(lambda_min, 0) computed there is a bound at any Y:
    it stays below the optimum the unstalled staircase reaches, and both verdicts agree."""
    import rlpgo_gtsam.relaxation.trust_region as trust_region

    _, fully = synchronize(heavy)
    ranks: list[str] = []
    monkeypatch.setattr(trust_region, "STALL_FRACTION", 1e4)  # any slow rank stalls
    _, stalled = synchronize(heavy, progress=ranks.append)
    assert any(line.startswith("rank 2: 10 iterations") for line in ranks)  # stalled there
    assert stalled.status == fully.status == Status.NOT_TIGHT
    assert stalled.lower_bound <= fully.lower_bound + heavy.num_poses * fully.tolerance


def test_the_rounded_estimate_is_polished_downhill_at_rank_one(heavy, monkeypatch):
    """Above rank 1 the rounded orientations are moved downhill at rank 1: the estimate's
    relaxation cost is at most the plain rounding's (here 175 against 206, the relaxation's
    174), and it is a rank-1 critical point."""
    theta, polished = synchronize(heavy)
    monkeypatch.setattr(staircase, "polish", lambda problem, manifold, y, *args: y)
    plain_theta, plain = synchronize(heavy)
    assert polished.rank == plain.rank > 1
    assert polished.estimate_cost < 0.9 * plain.estimate_cost
    assert polished.lower_bound == plain.lower_bound  # the staircase itself is unchanged
    assert relaxation_cost(heavy, theta) == pytest.approx(polished.estimate_cost)
    at_rank_one = certify(heavy, theta)  # Lambda at the polished z: a critical point
    assert at_rank_one.estimate_cost == pytest.approx(polished.estimate_cost)


def test_the_initializer_passes_its_time_limit_and_progress_on(heavy):
    from rlpgo_gtsam.initializers import make_initializer

    lines: list[str] = []
    initializer = make_initializer("certified", time_limit_s=0.0, progress=lines.append)
    estimate = initializer.estimate(heavy, None)
    _ended(estimate.certificate, Status.TIME_LIMIT)
    assert lines and lines[-1].startswith("rank 1: 0 iterations")


def test_the_block_factor_solves_and_counts_the_shifted_schur_complement():
    graph = _graph(60, 0.5, 3)
    problem = circles.PlanarProblem(graph)
    q = problem.apply(np.eye(problem.n, dtype=complex))
    shift = np.linspace(-2.0, 1.0, problem.n) * problem.scale * 1e-2
    dense = q + np.diag(shift)
    factor = problem.factor(shift)
    v = np.random.default_rng(0).standard_normal((problem.n, 2)) + 0j
    assert np.allclose(factor.solve(v), np.linalg.solve(dense, v), rtol=1e-8, atol=1e-12)
    assert factor.negative_pivots() == int(np.sum(np.linalg.eigvalsh(dense) <= 0))


def test_a_rejected_step_is_cut_from_the_recorded_cg_path_exactly(heavy):
    """After a rejected step the trust region takes the smaller radius's step from the last
    CG run's recorded path: bitwise what a new run would return, without Hessian products."""
    from rlpgo_gtsam.relaxation.trust_region import _shortened, truncated_cg

    problem, manifold = circles.PlanarProblem(heavy), circles.manifold()
    y = np.exp(1j * chordal_rotations(heavy))[:, None]
    qy = problem.apply(y)
    lam = manifold.multipliers(y, qy)
    grad = 2.0 * (qy - manifold.times(lam, y))
    precon = problem.preconditioner(manifold)

    def hess(v):
        return manifold.hessian(y, lam, v, problem.apply(v))

    def pre(v):
        return 0.5 * manifold.project(y, problem.solve_shifted(precon, v))

    radius = 50.0 * np.sqrt(manifold.inner(grad, pre(grad)))
    path: list = []
    *_, length = truncated_cg(grad, hess, pre, radius, path)
    assert path
    for smaller in (0.25 * min(radius, length), 1e-3 * length):
        again = truncated_cg(grad, hess, pre, smaller)
        cut = _shortened(path, smaller)
        assert cut is not None and cut[2:] == again[2:] == (True, smaller)
        assert np.array_equal(cut[0], again[0]) and np.array_equal(cut[1], again[1])


def test_the_same_graph_gets_the_same_certificate_twice_in_one_process():
    """ARPACK starts from Y or a fixed sample, never its own seed carried between calls (320
    poses: above the dense verification's size; with ARPACK's seed the two calls differed)."""
    sample = generate(320, 1.0, 0.05, 3.0, 1.0, np.random.default_rng(2),
                      noisy_measurements=True)
    graph = PoseGraph2D.from_gtsam(sample.graph, sample.initial)
    first = synchronize(graph, max_rank=3)
    second = synchronize(graph, max_rank=3)
    assert np.array_equal(first[0], second[0])
    assert first[1].lower_bound == second[1].lower_bound
    assert first[1].min_eigenvalue == second[1].min_eigenvalue


def test_the_hessian_preconditioners_invert_the_hessian_and_refuse_a_saddle(heavy):
    """At rank 1 of an easy graph's optimum the tangent Hessian's factor inverts the
    Hessian (up to its shift); above rank 1 the factor of S + delta I is applied. Where the
    relaxation is not exact, rank 1's minimum is a saddle of the staircase: the tangent
    Hessian there is positive definite, S (lambda_min -1.7) is not."""
    manifold = circles.manifold()

    def at_rank_one(graph):
        problem = circles.PlanarProblem(graph)
        theta, _ = synchronize(graph, max_rank=1)
        y = np.exp(1j * theta)[:, None]
        lam = manifold.multipliers(y, problem.apply(y))
        s = problem.apply(np.eye(problem.n, dtype=complex)) - np.diag(lam)
        return problem, y, lam, s

    problem, y, lam, s = at_rank_one(heavy)
    assert np.linalg.eigvalsh(s)[0] < -1.0
    assert problem.hessian_preconditioner(manifold, y, lam) is not None
    assert problem.hessian_preconditioner(manifold, np.hstack([y, 0 * y]), lam) is None
    problem, y, lam, s = at_rank_one(_graph(100, 0.05, 4))
    rng = np.random.default_rng(0)
    a = rng.standard_normal(problem.n)
    v = (1j * (a - a.mean()) * y[:, 0])[:, None]  # tangent, no gauge part
    hv = manifold.hessian(y, lam, v, problem.apply(v))
    pre = problem.hessian_preconditioner(manifold, y, lam)
    assert np.allclose(pre(hv), v, rtol=1e-5, atol=1e-6 * np.abs(v).max())
    y2 = np.hstack([y, np.zeros_like(y)])  # the same point at rank 2: S + delta I
    pre2 = problem.hessian_preconditioner(manifold, y2, lam)
    w = rng.standard_normal((problem.n, 2)) + 1j * rng.standard_normal((problem.n, 2))
    delta = problem.preconditioner_delta(manifold)
    expected = 0.5 * manifold.project(y2, np.linalg.solve(s + delta * np.eye(problem.n), w))
    assert np.allclose(pre2(w), expected, rtol=1e-6)


def test_long_runs_switch_to_the_hessian_preconditioner_and_need_fewer_products(
        monkeypatch, hessian_products):
    """3000 poses in long rows: CG preconditioned by Q + delta I needs 202 Hessian products;
    switching to the Hessian's own after a run of 10 or more, far fewer; the same
    estimate."""
    sample = generate(3000, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(1),
                      noisy_measurements=True)
    graph = PoseGraph2D.from_gtsam(sample.graph, sample.initial)
    products = hessian_products
    _, switched = synchronize(graph)
    with_switch, products[0] = products[0], 0
    monkeypatch.setattr(circles, "_HESSIAN_PRECONDITIONER_AFTER", None)
    _, plain = synchronize(graph)
    assert switched.certified and plain.certified
    assert with_switch < 0.5 * products[0]
    assert switched.estimate_cost == pytest.approx(plain.estimate_cost, rel=1e-10)


def test_a_failed_saddle_escape_is_reported(monkeypatch):
    # This graph needs rank 3; with no step halvings the escape to rank 2 cannot descend.
    graph = _graph(30, 2.0, 2)
    monkeypatch.setattr(circles, "_ESCAPE_HALVINGS", 0)
    _, certificate = synchronize(graph, max_rank=2)
    _ended(certificate, Status.SADDLE_ESCAPE_FAILED)
    assert "saddle escape failed at rank 2" in certificate.describe()


def test_an_unconverged_eigenvalue_is_reported_and_its_bound_stays_a_bound(monkeypatch, heavy):
    _, exact = synchronize(heavy, max_rank=1)  # the dense verification's lambda_min
    monkeypatch.setattr(circles, "_DENSE_BELOW", 0)
    monkeypatch.setattr(circles, "_ARPACK_OPTIONS", {"maxiter": 1, "ncv": 5})
    _, certificate = synchronize(heavy, max_rank=1)
    _ended(certificate, Status.EIGENVALUE_IMPRECISE)
    assert certificate.estimate_cost == exact.estimate_cost  # the same Y, verified otherwise
    assert certificate.min_eigenvalue <= exact.min_eigenvalue  # a floor, not the value
    assert certificate.lower_bound <= exact.lower_bound
    assert "did not converge" in certificate.describe()


def test_certify_refuses_a_non_optimal_estimate(heavy):
    certificate = certify(heavy, heavy.poses[:, 2])  # the odometry guess
    _ended(certificate, Status.NOT_OPTIMAL)
    assert "not the relaxation's optimum" in certificate.describe()


@pytest.mark.parametrize("sigma_r, seed, point", [(0.4, 1, "optimum"), (0.5, 2, "saddle"),
                                                   (0.4, 1, "odometry")])
def test_sparse_and_dense_verification_agree(monkeypatch, sigma_r, seed, point):
    graph = _graph(200, sigma_r, seed)
    problem = circles.PlanarProblem(graph)
    eta = problem.tolerance(None)
    if point == "odometry":  # many negative eigenvalues
        y = np.exp(1j * graph.poses[:, 2])[:, None]
    else:  # a critical point at rank 1: the optimum, or a saddle with a few negative ones
        start = np.exp(1j * chordal_rotations(graph))[:, None]
        y, _ = trust_region(problem, circles.manifold(), start, 300,
                            1e-9 * np.sqrt(problem.n) * problem.scale)
    assert problem.n < circles._DENSE_BELOW
    dense = verify(problem, circles.manifold(), y, eta)
    monkeypatch.setattr(circles, "_DENSE_BELOW", 0)
    sparse = verify(problem, circles.manifold(), y, eta)
    assert dense.certified is sparse.certified is (point == "optimum")
    assert not sparse.imprecise and sparse.trace == dense.trace
    # At an optimum lambda_min is 0 up to round-off: compared on the problem's scale.
    scale = problem.scale if point == "optimum" else abs(dense.min_eigenvalue)
    assert abs(sparse.min_eigenvalue - dense.min_eigenvalue) <= 1e-6 * scale


def test_the_chordal_estimate_is_the_rank_one_optimum_of_an_exact_graph():
    sample = generate(150, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(5))
    graph = PoseGraph2D.from_gtsam(sample.graph, sample.initial)
    truth = PoseGraph2D.from_gtsam(sample.graph, sample.ground_truth).poses[:, 2]

    def gauge_free(theta):
        return wrap(theta - theta[graph.anchor])

    def error(a, b):
        return np.abs(wrap(gauge_free(a) - gauge_free(b))).max()

    chordal = chordal_rotations(graph)
    theta, certificate = synchronize(graph, max_rank=1)  # the staircase held at rank 1
    assert certificate.certified and certificate.rank == 1
    assert error(chordal, truth) < 1e-8 and error(theta, truth) < 1e-8
    assert error(theta, chordal) < 1e-8
    # From the odometry guess the trust region reaches the same optimum, as closely as the
    # round-off of the cost (about 1e-9 absolute here) resolves it.
    from_odometry, certificate = synchronize(graph, graph.poses[:, 2], max_rank=1)
    assert certificate.certified and error(from_odometry, truth) < 1e-6


def test_both_commands_print_the_status_and_json_records_the_certificate_once(tmp_path,
                                                                              heavy_sample):
    path, json_path = tmp_path / "in.g2o", tmp_path / "rows.json"
    write_g2o(path, heavy_sample.graph, heavy_sample.initial)
    line = "NOT certified: the relaxation is solved but not exact"
    result = CliRunner().invoke(compare_main, [str(path), "--methods", "chordal,certified",
                                               "--iters", "5", "--json", str(json_path)])
    assert result.exit_code == 0, result.output
    assert f"  certificate (certified): {line}" in result.stdout
    assert "certificate (chordal)" not in result.stdout
    record = {r["method"]: r for r in json.loads(json_path.read_text())}["certified"]
    assert record["certificate"]["status"] == "not_tight" and "details" not in record
    result = CliRunner().invoke(init_main, [str(path), "-o", str(tmp_path / "out.g2o"),
                                            "--method", "certified", "--refine", "none"])
    assert result.exit_code == 0, result.output
    assert f"certificate: {line}" in result.stdout


def test_truncated_cg_past_its_deadline_hands_over_one_descending_step():
    """The deadline bites between CG's iterations: one runs, and its step lowers the model
    (the trust region takes it if the cost agrees); without a deadline CG goes on."""
    from rlpgo_gtsam.relaxation.trust_region import truncated_cg

    rng = np.random.default_rng(0)
    a = rng.standard_normal((40, 40))
    hessian = a @ a.T + np.eye(40)
    grad = rng.standard_normal(40)
    products: list[int] = []

    def hess(v):
        products.append(1)
        return hessian @ v

    step, h_step, boundary, _ = truncated_cg(grad, hess, lambda v: v, 1e6,
                                             deadline=time.perf_counter() - 1.0)
    assert len(products) == 1 and not boundary
    assert np.allclose(h_step, hessian @ step)
    cut_model = grad @ step + 0.5 * step @ hessian @ step
    assert cut_model < 0
    products.clear()
    full, *_ = truncated_cg(grad, hess, lambda v: v, 1e6)
    assert len(products) > 1 and grad @ full + 0.5 * full @ hessian @ full < cut_model


def test_the_verification_asks_its_hook_before_each_long_step_and_ends_on_time_up():
    """Above the dense size, the hook is called before the factorization and before each of
    the eigen-solver's solves (with the solves so far), changes nothing, and raising
    TimeUp there ends the verification: the staircase's deadline inside its longest step
    (16 s of 34 on 200,000 poses)."""
    from rlpgo_gtsam.relaxation.verification import TimeUp

    graph = _graph(320, 0.4, 1)
    problem, manifold = circles.PlanarProblem(graph), circles.manifold()
    assert problem.n >= circles._DENSE_BELOW
    y = np.exp(1j * synchronize(graph, max_rank=1)[0])[:, None]
    eta = problem.tolerance(None)
    seen: list[int] = []
    hooked = verify(problem, manifold, y, eta, seen.append)
    assert len(seen) > 2 and seen == [0, *range(len(seen) - 1)]
    plain = verify(problem, manifold, y, eta)
    assert (hooked.certified, hooked.min_eigenvalue) == (plain.certified, plain.min_eigenvalue)

    def out_of_time(solves: int) -> None:
        if solves >= 2:
            raise TimeUp

    with pytest.raises(TimeUp):
        verify(problem, manifold, y, eta, out_of_time)
