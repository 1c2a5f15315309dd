// sesync_rounded: run SE-Sync (Rosen, Carlone, Bandeira, Leonard; IJRR 2019) on a
// planar (EDGE_SE2) or 3D (EDGE_SE3:QUAT) g2o pose graph and write its rounded
// estimate plus its certificate data.
//
//   usage: sesync_rounded INPUT.g2o OUTPUT.json
//
// SE-Sync runs with its default options (SESyncOpts{}: chordal initialization,
// simplified formulation, default tolerances, one thread, not verbose).
//
// OUTPUT is one JSON object:
//   seconds                 wall time (std::chrono::steady_clock) of the whole
//                           SESync::SESync(measurements, options) call: problem
//                           construction, Riemannian staircase, verification,
//                           rounding.  File reading is excluded.
//   sesync_reported_seconds SE-Sync's own total_computation_time (it excludes the
//                           problem construction)
//   status                  SE-Sync's termination status (GlobalOpt, SaddlePoint,
//                           EigImprecision, MaxRank, ElapsedTime)
//   verification_passed     status == GlobalOpt: the certificate matrix S at the
//                           final rank passed SE-Sync's test (S + eta*I admits a
//                           Cholesky factorization, eta = min_eig_num_tol), i.e.
//                           Yopt solves the semidefinite relaxation
//   certified               verification_passed and suboptimality_bound <=
//                           certified_bound_tol (= 1e-6 * max(1, |lower_bound|)):
//                           the rounded estimate is then a certified global
//                           optimum of SE-Sync's cost (the relaxation is tight).
//                           When the test passes but the bound is large, the
//                           relaxation is exact but not tight (rank > 2 optimum).
//   eta                     that tolerance
//   sesync_theta            SE-Sync's curvature x'Sx along its last escape
//                           direction; SE-Sync sets it to 0 when the test passes
//                           (it then computes no eigenvalue)
//   min_eigenvalue          lambda_min of the certificate matrix S = M - Lambda
//                           (the translation-explicit one SE-Sync tests) at the
//                           final Yopt, computed here after the timed call by
//                           shift-invert subspace iteration
//   min_eigenvalue_residual ||S x - lambda x|| for the returned Ritz pair (unit x)
//   min_eigenvalue_iterations, min_eigenvalue_shift
//   objective               SE-Sync's cost F(xhat) of the rounded estimate
//   sdp_value               F(Yopt' Yopt), the rank-restricted relaxation's value
//   lower_bound             tr(Lambda), the dual value (a lower bound on the
//                           global optimum of SE-Sync's cost when S is PSD)
//   duality_gap             sdp_value - lower_bound
//   suboptimality_bound     objective - lower_bound (SE-Sync's definition)
//   rank                    rows of Yopt (final staircase level)
//   num_poses, num_measurements
//   dim                     2 or 3
//   ids                     the file's vertex ids, sorted ascending
//   poses                   in that order, SE-Sync's rounded estimate exactly as
//                           returned, i.e. in SE-Sync's arbitrary gauge (NOT
//                           anchored to the file's vertices): [x, y, theta] per
//                           pose in 2D; [x, y, z, r11, r12, r13, r21, ..., r33]
//                           (the rotation matrix row by row) in 3D
//
// The g2o file is parsed here (EDGE_SE2 or EDGE_SE3:QUAT, not both; VERTEX_SE2 /
// VERTEX_SE3:QUAT lines only contribute ids; FIX lines, comments and blank lines
// are ignored; anything else is an error) into SE-Sync's RelativePoseMeasurement
// with exactly the precisions that SE-Sync's own read_g2o_file assigns: in 2D
// tau = 2 / tr(inverse translational information), kappa = rotational information
// I33; in 3D tau = 3 / tr(inverse of the 3x3 translational information block),
// kappa = 3 / (2 tr(inverse of the 3x3 rotational block)).  Unlike read_g2o_file
// (which uses the raw ids as indices and silently re-uses the previous line on
// unknown tokens or blank lines), ids are mapped to 0..n-1 in sorted order and
// malformed input is rejected.
//
// Errors: one line on stderr, exit status 1.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/CholmodSupport>
#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <Eigen/Sparse>

#include "SESync/SESync.h"
#include "SESync/SESyncProblem.h"
#include "SESync/SESync_utils.h"

namespace {

// Relative tolerance on the suboptimality bound for calling the rounded
// estimate certified (the bound is ~1e-10 on tight instances).
constexpr double kCertifiedRelTol = 1e-6;

using SESync::Matrix;
using SESync::Scalar;
using SESync::SparseMatrix;
using SESync::Vector;

struct Graph {
  size_t dim = 2;
  SESync::measurements_t measurements;
  std::vector<long long> ids; // sorted file ids; index = SE-Sync pose index
};

Graph read_g2o(const std::string &path) {
  std::ifstream in(path);
  if (!in)
    throw std::runtime_error("cannot open " + path);

  struct RawEdge {
    long long i, j;
    SESync::RelativePoseMeasurement m; // i, j filled in once ids are indexed
  };
  std::vector<RawEdge> edges;
  std::vector<long long> ids;
  size_t dim = 0;

  std::string line;
  size_t lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    std::istringstream ss(line);
    std::string tok;
    if (!(ss >> tok) || tok[0] == '#')
      continue;
    auto where = [&]() { return path + ":" + std::to_string(lineno); };
    auto set_dim = [&](size_t d) {
      if (dim != 0 && dim != d)
        throw std::runtime_error("2D and 3D lines mixed at " + where());
      dim = d;
    };
    if (tok == "EDGE_SE2") {
      set_dim(2);
      RawEdge e;
      double dx, dy, dth, I11, I12, I13, I22, I23, I33;
      if (!(ss >> e.i >> e.j >> dx >> dy >> dth >> I11 >> I12 >> I13 >> I22 >>
            I23 >> I33))
        throw std::runtime_error("malformed EDGE_SE2 at " + where());
      if (e.i == e.j)
        throw std::runtime_error("self-loop edge at " + where());
      e.m.t = Eigen::Matrix<Scalar, 2, 1>(dx, dy);
      e.m.R = Eigen::Rotation2D<Scalar>(dth).toRotationMatrix();
      Eigen::Matrix<Scalar, 2, 2> tran_info;
      tran_info << I11, I12, I12, I22;
      Eigen::LLT<Eigen::Matrix<Scalar, 2, 2>> llt(tran_info);
      if (llt.info() != Eigen::Success || !(I33 > 0))
        throw std::runtime_error("non-positive-definite information at " +
                                 where());
      e.m.tau = 2 / tran_info.inverse().trace(); // as SESync::read_g2o_file
      e.m.kappa = I33;                           // as SESync::read_g2o_file
      edges.push_back(e);
      ids.push_back(e.i);
      ids.push_back(e.j);
    } else if (tok == "EDGE_SE3:QUAT") {
      set_dim(3);
      RawEdge e;
      double t[3], q[4], I[21];
      if (!(ss >> e.i >> e.j >> t[0] >> t[1] >> t[2] >> q[0] >> q[1] >> q[2] >>
            q[3]))
        throw std::runtime_error("malformed EDGE_SE3:QUAT at " + where());
      for (double &v : I)
        if (!(ss >> v))
          throw std::runtime_error("malformed EDGE_SE3:QUAT at " + where());
      if (e.i == e.j)
        throw std::runtime_error("self-loop edge at " + where());
      // g2o's order: x y z qx qy qz qw; information upper triangle row by row,
      // translation block first.
      Eigen::Matrix<Scalar, 6, 6> info;
      for (int r = 0, k = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c, ++k)
          info(r, c) = info(c, r) = I[k];
      const Eigen::Quaternion<Scalar> quat(q[3], q[0], q[1], q[2]);
      e.m.t = Eigen::Matrix<Scalar, 3, 1>(t[0], t[1], t[2]);
      e.m.R = quat.normalized().toRotationMatrix();
      const Eigen::Matrix<Scalar, 3, 3> tran_info = info.topLeftCorner<3, 3>();
      const Eigen::Matrix<Scalar, 3, 3> rot_info = info.bottomRightCorner<3, 3>();
      // as SESync::read_g2o_file
      e.m.tau = 3 / tran_info.inverse().trace();
      e.m.kappa = 3 / (2 * rot_info.inverse().trace());
      if (!(e.m.tau > 0) || !(e.m.kappa > 0) || !std::isfinite(e.m.tau) ||
          !std::isfinite(e.m.kappa))
        throw std::runtime_error("non-positive precision at " + where());
      edges.push_back(e);
      ids.push_back(e.i);
      ids.push_back(e.j);
    } else if (tok == "VERTEX_SE2" || tok == "VERTEX_SE3:QUAT") {
      set_dim(tok == "VERTEX_SE2" ? 2 : 3);
      long long id;
      if (!(ss >> id))
        throw std::runtime_error("malformed " + tok + " at " + where());
      ids.push_back(id);
    } else if (tok == "FIX") {
      continue;
    } else {
      throw std::runtime_error("unsupported g2o token '" + tok + "' at " +
                               where());
    }
  }
  if (edges.empty())
    throw std::runtime_error("no edge in " + path);

  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  std::map<long long, size_t> index;
  for (size_t k = 0; k < ids.size(); ++k)
    index[ids[k]] = k;

  // Connectivity (SE-Sync needs a connected graph).
  std::vector<size_t> parent(ids.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](size_t a) {
    while (parent[a] != a)
      a = parent[a] = parent[parent[a]];
    return a;
  };
  size_t components = ids.size();

  Graph g;
  g.ids = ids;
  g.measurements.reserve(edges.size());
  g.dim = dim;
  for (const RawEdge &e : edges) {
    SESync::RelativePoseMeasurement m = e.m;
    m.i = index.at(e.i);
    m.j = index.at(e.j);
    g.measurements.push_back(m);

    size_t a = find(m.i), b = find(m.j);
    if (a != b) {
      parent[a] = b;
      --components;
    }
  }
  if (components != 1)
    throw std::runtime_error("pose graph is not connected (" +
                             std::to_string(components) + " components)");
  return g;
}

const char *status_name(SESync::SESyncStatus s) {
  switch (s) {
  case SESync::GlobalOpt:
    return "GlobalOpt";
  case SESync::SaddlePoint:
    return "SaddlePoint";
  case SESync::EigImprecision:
    return "EigImprecision";
  case SESync::MaxRank:
    return "MaxRank";
  case SESync::ElapsedTime:
    return "ElapsedTime";
  }
  return "Unknown";
}

struct MinEig {
  double lambda = std::numeric_limits<double>::quiet_NaN();
  double residual = std::numeric_limits<double>::quiet_NaN();
  double shift = std::numeric_limits<double>::quiet_NaN();
  int iterations = 0;
};

Matrix orthonormal_columns(const Matrix &X) {
  Eigen::HouseholderQR<Matrix> qr(X);
  return qr.householderQ() * Matrix::Identity(X.rows(), X.cols());
}

// Smallest eigenvalue of the symmetric sparse S by subspace iteration on
// (S + sigma I)^{-1}, sigma > -lambda_min(S) found by doubling from sigma0.
MinEig minimum_eigenvalue(const SparseMatrix &S, double sigma0) {
  MinEig out;
  const Eigen::Index N = S.rows();
  SparseMatrix Id(N, N);
  Id.setIdentity();
  double scale = 0;
  for (Eigen::Index k = 0; k < S.outerSize(); ++k)
    for (SparseMatrix::InnerIterator it(S, k); it; ++it)
      scale = std::max(scale, std::abs(it.value()));

  Eigen::CholmodSupernodalLLT<SparseMatrix> llt;
  llt.cholmod().print = 0;
  llt.cholmod().quick_return_if_not_posdef = 1;
  double sigma = sigma0;
  bool ok = false;
  for (int k = 0; k < 80; ++k) {
    llt.compute(S + sigma * Id);
    if (llt.info() == Eigen::Success) {
      ok = true;
      break;
    }
    sigma *= 2;
  }
  if (!ok)
    return out;
  out.shift = sigma;

  const Eigen::Index b = std::min<Eigen::Index>(8, N);
  std::srand(12345);
  Matrix X = orthonormal_columns(Matrix::Random(N, b));
  double prev = std::numeric_limits<double>::infinity();
  for (int it = 1; it <= 1000; ++it) {
    X = orthonormal_columns(llt.solve(X));
    Matrix SX = S * X;
    Matrix H = X.transpose() * SX;
    H = 0.5 * (H + H.transpose()).eval();
    Eigen::SelfAdjointEigenSolver<Matrix> es(H);
    X = X * es.eigenvectors(); // Ritz vectors, ascending Ritz values
    Vector x = X.col(0);
    double lambda = es.eigenvalues()(0);
    out.lambda = lambda;
    out.residual = (S * x - lambda * x).norm();
    out.iterations = it;
    if (out.residual <= 1e-10 * std::max(1.0, scale) ||
        (it > 20 && std::abs(lambda - prev) <= 1e-14 * std::max(1.0, scale)))
      break;
    prev = lambda;
  }
  return out;
}

std::string num(double v) {
  if (!std::isfinite(v))
    return "null";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

} // namespace

int main(int argc, char **argv) {
  if (argc != 3) {
    std::cerr << "usage: " << argv[0] << " INPUT.g2o OUTPUT.json" << std::endl;
    return 2;
  }
  try {
    const Graph g = read_g2o(argv[1]);
    const size_t n = g.ids.size();

    SESync::SESyncOpts opts; // defaults throughout
    opts.verbose = false;

    const auto t0 = std::chrono::steady_clock::now();
    SESync::SESyncResult res = SESync::SESync(g.measurements, opts);
    const auto t1 = std::chrono::steady_clock::now();
    const double seconds = std::chrono::duration<double>(t1 - t0).count();

    const size_t d = g.dim;
    if (static_cast<size_t>(res.xhat.rows()) != d ||
        static_cast<size_t>(res.xhat.cols()) != (d + 1) * n)
      throw std::runtime_error("unexpected shape of SE-Sync's rounded estimate");

    // Certificate matrix at the final rank, outside the timed region: the
    // translation-explicit S = M - diag(0_n, Lambda) that SE-Sync's
    // verify_solution factors.
    SESync::SESyncProblem problem(g.measurements, opts.formulation,
                                  opts.projection_factorization,
                                  opts.preconditioner,
                                  opts.reg_Cholesky_precon_max_condition_number);
    problem.set_relaxation_rank(res.Yopt.rows());
    const Matrix Lambda_blocks = problem.compute_Lambda_blocks(res.Yopt);
    std::vector<Eigen::Triplet<Scalar>> trip;
    trip.reserve(d * d * n);
    for (size_t i = 0; i < n; ++i)
      for (size_t r = 0; r < d; ++r)
        for (size_t c = 0; c < d; ++c)
          trip.emplace_back(n + i * d + r, n + i * d + c,
                            Lambda_blocks(r, i * d + c));
    SparseMatrix Lambda_full((d + 1) * n, (d + 1) * n);
    Lambda_full.setFromTriplets(trip.begin(), trip.end());
    const SparseMatrix M = SESync::construct_M_matrix(g.measurements);
    const SparseMatrix S = M - Lambda_full;
    const MinEig me = minimum_eigenvalue(S, opts.min_eig_num_tol);

    const double theta_last = res.escape_direction_curvatures.empty()
                                  ? std::numeric_limits<double>::quiet_NaN()
                                  : res.escape_direction_curvatures.back();

    // SE-Sync's test passed: Yopt solves the semidefinite relaxation.  Certified:
    // moreover the rounding is tight, i.e. xhat is a certified global optimum of
    // SE-Sync's cost (suboptimality bound zero up to round-off).
    const bool verified = res.status == SESync::GlobalOpt;
    const double bound_tol =
        kCertifiedRelTol * std::max(1.0, std::abs(res.trLambda));
    const bool certified = verified && res.suboptimality_bound <= bound_tol;

    std::ofstream out(argv[2]);
    if (!out)
      throw std::runtime_error(std::string("cannot write ") + argv[2]);
    out << "{\n";
    out << "  \"seconds\": " << num(seconds) << ",\n";
    out << "  \"sesync_reported_seconds\": " << num(res.total_computation_time)
        << ",\n";
    out << "  \"status\": \"" << status_name(res.status) << "\",\n";
    out << "  \"verification_passed\": " << (verified ? "true" : "false")
        << ",\n";
    out << "  \"certified\": " << (certified ? "true" : "false") << ",\n";
    out << "  \"certified_bound_tol\": " << num(bound_tol) << ",\n";
    out << "  \"eta\": " << num(opts.min_eig_num_tol) << ",\n";
    out << "  \"sesync_theta\": " << num(theta_last) << ",\n";
    out << "  \"min_eigenvalue\": " << num(me.lambda) << ",\n";
    out << "  \"min_eigenvalue_residual\": " << num(me.residual) << ",\n";
    out << "  \"min_eigenvalue_iterations\": " << me.iterations << ",\n";
    out << "  \"min_eigenvalue_shift\": " << num(me.shift) << ",\n";
    out << "  \"objective\": " << num(res.Fxhat) << ",\n";
    out << "  \"sdp_value\": " << num(res.SDPval) << ",\n";
    out << "  \"lower_bound\": " << num(res.trLambda) << ",\n";
    out << "  \"duality_gap\": " << num(res.duality_gap) << ",\n";
    out << "  \"suboptimality_bound\": " << num(res.suboptimality_bound)
        << ",\n";
    out << "  \"rank\": " << res.Yopt.rows() << ",\n";
    out << "  \"num_poses\": " << n << ",\n";
    out << "  \"num_measurements\": " << g.measurements.size() << ",\n";
    out << "  \"dim\": " << d << ",\n";
    out << "  \"ids\": [";
    for (size_t i = 0; i < n; ++i)
      out << (i ? ", " : "") << g.ids[i];
    out << "],\n";
    out << "  \"poses\": [\n";
    for (size_t i = 0; i < n; ++i) {
      out << "    [";
      for (size_t r = 0; r < d; ++r)
        out << (r ? ", " : "") << num(res.xhat(r, i));
      if (d == 2) {
        const Eigen::Matrix<Scalar, 2, 2> R = res.xhat.block(0, n + d * i, d, d);
        out << ", " << num(std::atan2(R(1, 0), R(0, 0)));
      } else {
        for (size_t r = 0; r < d; ++r)
          for (size_t c = 0; c < d; ++c)
            out << ", " << num(res.xhat(r, n + d * i + c));
      }
      out << "]" << (i + 1 < n ? ",\n" : "\n");
    }
    out << "  ]\n}\n";
    out.close();
    if (!out)
      throw std::runtime_error(std::string("error writing ") + argv[2]);
  } catch (const std::exception &e) {
    std::cerr << "sesync_rounded: " << e.what() << std::endl;
    return 1;
  }
  return 0;
}
