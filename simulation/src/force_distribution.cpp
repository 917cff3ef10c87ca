// Stance forces within friction pyramids for the trunk wrench (force_distribution.hpp).
#include "force_distribution.hpp"

#include <libalglib/optimization.h>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <utility>

namespace terrastride::simulation::internal {

namespace {

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Vector3d;
using Eigen::VectorXd;

Matrix3d skew(const Vector3d& v) {
  Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

// The map from the feet's forces (3 per foot, stacked) to the trunk wrench they make: their sum
// and the sum of their moments lever x f about the base.
MatrixXd wrench_map(const std::vector<Vector3d>& lever) {
  const int n = static_cast<int>(lever.size());
  MatrixXd g(6, 3 * n);
  for (int i = 0; i < n; ++i) {
    g.block<3, 3>(0, 3 * i) = Matrix3d::Identity();
    g.block<3, 3>(3, 3 * i) = skew(lever[i]);
  }
  return g;
}

// The tangent directions of the pyramid about n: t1 along the world's x projected onto the
// terrain (y where n is along x), t2 = n x t1.
std::pair<Vector3d, Vector3d> tangents(const Vector3d& n) {
  Vector3d t1 = Vector3d::UnitX() - n.x() * n;
  if (t1.norm() < 1e-6) t1 = Vector3d::UnitY() - n.y() * n;
  t1.normalize();
  return {t1, n.cross(t1)};
}

// The pyramid's edges: kEdges unit directions around the normal, n + mu (cos a t1 + sin a t2)
// at a = 2 pi k / kEdges. Eight make an octagon within 8 % of the cone (cos(pi/8) = 0.924 of its
// radius at the facets' middles); four, a diamond, gave up to 29 % of it along the diagonals,
// which cost the flat crawl's lateral push margin 619 -> 506 N.
constexpr int kEdges = 8;

Vector3d edge(const Vector3d& n, const Vector3d& t1, const Vector3d& t2, double mu, int k) {
  const double a = 2.0 * M_PI * k / kEdges;
  return n + mu * (std::cos(a) * t1 + std::sin(a) * t2);
}

// min 0.5 x' Q x + c' x over x >= 0 with ALGLIB's QuickQP, from `start`, its stopping tests in
// units of `scale` per variable; false (x untouched) when the data are not finite or the solver
// reports a failure or throws (ALGLIB signals bad input with alglib::ap_error).
bool solve_nonnegative_qp(const MatrixXd& q, const VectorXd& c, const VectorXd& start, double scale,
                          VectorXd* x) {
  if (!q.allFinite() || !c.allFinite() || !start.allFinite() || !std::isfinite(scale)) return false;
  const int m = static_cast<int>(c.size());
  try {
    alglib::real_2d_array q_alglib;
    q_alglib.setlength(m, m);
    alglib::real_1d_array c_alglib, lower, upper, scales, x0;
    for (auto* v : {&c_alglib, &lower, &upper, &scales, &x0}) v->setlength(m);
    for (int i = 0; i < m; ++i) {
      for (int k = 0; k < m; ++k) q_alglib[i][k] = q(i, k);
      c_alglib[i] = c[i];
      lower[i] = 0.0;
      upper[i] = alglib::fp_posinf;
      scales[i] = scale;
      x0[i] = start[i];
    }
    alglib::minqpstate state;
    alglib::minqpcreate(m, state);
    alglib::minqpsetquadraticterm(state, q_alglib, true);
    alglib::minqpsetlinearterm(state, c_alglib);
    alglib::minqpsetbc(state, lower, upper);
    alglib::minqpsetscale(state, scales);
    alglib::minqpsetstartingpoint(state, x0);
    alglib::minqpsetalgoquickqp(state, 0.0, 0.0, 1e-9, 0, true);
    alglib::minqpoptimize(state);
    alglib::real_1d_array solution;
    alglib::minqpreport report;
    alglib::minqpresults(state, solution, report);
    if (report.terminationtype <= 0) return false;
    x->resize(m);
    for (int i = 0; i < m; ++i) (*x)[i] = solution[i];
    return x->allFinite();
  } catch (const alglib::ap_error&) {
    return false;
  }
}

}  // namespace

std::vector<Vector3d> spread_wrench(const Eigen::Matrix<double, 6, 1>& w,
                                    const std::vector<Vector3d>& lever) {
  const int n = static_cast<int>(lever.size());
  std::vector<Vector3d> out(n, Vector3d::Zero());
  if (n == 0) return out;
  const MatrixXd g = wrench_map(lever);
  const MatrixXd ggt = g * g.transpose() + 1e-6 * MatrixXd::Identity(6, 6);
  const VectorXd f = g.transpose() * ggt.ldlt().solve(w);
  for (int i = 0; i < n; ++i) out[i] = f.segment<3>(3 * i);
  return out;
}

Vector3d into_cone(const Vector3d& f, const Vector3d& n, double mu) {
  double fn = f.dot(n);
  if (fn <= 0) return Vector3d::Zero();
  Vector3d ft = f - fn * n;
  const double t = ft.norm();
  if (t > mu * fn) ft *= mu * fn / t;
  return fn * n + ft;
}

bool within_friction_pyramid(const Vector3d& f, const Vector3d& n, double mu) {
  const auto [t1, t2] = tangents(n);
  const double fn = f.dot(n);
  if (fn < 0.0) return false;
  // Each facet lies between two edges: its outward direction in the tangent plane is at the
  // middle angle, at distance mu cos(pi / kEdges) per unit of normal force.
  const double a = f.dot(t1), b = f.dot(t2);
  for (int k = 0; k < kEdges; ++k) {
    const double mid = 2.0 * M_PI * (k + 0.5) / kEdges;
    if (a * std::cos(mid) + b * std::sin(mid) > mu * std::cos(M_PI / kEdges) * fn * (1 + 1e-12))
      return false;
  }
  return true;
}

std::vector<Vector3d> constrained_stance_forces(const std::vector<StanceFoot>& feet, double mu,
                                                const ForceDistributionWeights& w) {
  const int n = static_cast<int>(feet.size());
  std::vector<Vector3d> out;
  for (const auto& f : feet) out.push_back(f.desired);
  if (std::all_of(feet.begin(), feet.end(), [&](const StanceFoot& f) {
        return within_friction_pyramid(f.desired, f.normal, mu);
      }))
    return out;
  // f = E lambda, lambda >= 0: foot i's force is a non-negative sum of its pyramid's edges.
  MatrixXd e = MatrixXd::Zero(3 * n, kEdges * n);
  std::vector<Vector3d> lever;
  VectorXd desired(3 * n);
  for (int i = 0; i < n; ++i) {
    const Vector3d& nn = feet[i].normal;
    const auto [t1, t2] = tangents(nn);
    for (int k = 0; k < kEdges; ++k)
      e.col(kEdges * i + k).segment<3>(3 * i) = edge(nn, t1, t2, mu, k);
    lever.push_back(feet[i].lever);
    desired.segment<3>(3 * i) = feet[i].desired;
  }
  MatrixXd g = wrench_map(lever);
  g.bottomRows<3>() *= w.angular;
  g.row(2) *= w.vertical;
  // |A lambda - b|^2 as the quadratic program 0.5 lambda' Q lambda + c' lambda, Q = 2 A'A, c =
  // -2 A'b. A foot's edges have null combinations (opposite edges sum to 2n), so Q is only
  // semidefinite: a weight of 1e-9 on |lambda|^2 makes it definite without moving the solution.
  MatrixXd a(6 + 3 * n, kEdges * n);
  a.topRows<6>() = g * e;
  a.bottomRows(3 * n) = std::sqrt(w.regularisation) * e;
  VectorXd b(6 + 3 * n);
  b.head<6>() = g * desired;
  b.tail(3 * n) = std::sqrt(w.regularisation) * desired;
  MatrixXd q = 2.0 * a.transpose() * a;
  q.diagonal().array() += 1e-9 * q.diagonal().maxCoeff();
  const VectorXd c = -2.0 * a.transpose() * b;
  VectorXd start(kEdges * n);
  double load = 0.0;
  for (int i = 0; i < n; ++i) {
    const double fn = std::max(feet[i].desired.dot(feet[i].normal), 0.0);
    start.segment(kEdges * i, kEdges).setConstant(fn / kEdges);
    load += fn;
  }
  VectorXd lambda;
  // A failed solve keeps the desired forces, which leg_torque then clips into their cones as the
  // clipped distribution does.
  if (!solve_nonnegative_qp(q, c, start, std::max(load / (kEdges * n), 1.0), &lambda)) return out;
  for (int i = 0; i < n; ++i) {
    out[i].setZero();
    for (int k = 0; k < kEdges; ++k)
      out[i] += lambda[kEdges * i + k] * e.col(kEdges * i + k).segment<3>(3 * i);
  }
  return out;
}

}  // namespace terrastride::simulation::internal
