// Least-squares fit of the interpolated force-polytope model with Ceres.
//
// Residuals: for every training foot position p (exact Jacobian J, limits tau) and every vertex v_s
// of the approximate polytope (s in {+-1}^3 picks one facet per joint), the exact torque ratios
// x = diag(1/tau) J^T v_s should equal s: the vertex of the approximation should load each joint
// exactly to its limit, with the sign of the facets that meet there. The 24 residuals
// s_i x_i - 1 vanish for all vertices iff the approximation is exact, and they are expressed in the
// quality measure itself (rho_out is the largest |x_i|). Positive residuals (a vertex beyond a
// torque limit) are weighted `overshoot_weight` times more than negative ones (a vertex short of
// it), which biases the fit towards polytopes inside the exact one. A final uniform scaling of all
// offsets (the polytope scales with them, so rho_out does too) caps the training set's worst
// rho_out.
#include "terrastride/planner/polytope_fit.hpp"

#include <ceres/ceres.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <thread>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <stdexcept>

#include "terrastride/planner/polytope_core.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {
namespace core = polytope_core;
using Eigen::Matrix3d;
using Eigen::Vector3d;

std::string describe_fit(const PolytopeFitOptions& o) {
  char summary[200];
  std::snprintf(summary, sizeof summary,
                "samples %d per leg, seed %llu, box scale %g, %dx%d references, smoothness %g",
                o.samples, static_cast<unsigned long long>(o.seed), o.box_scale, o.l_refs,
                o.alpha_refs, o.smoothness);
  return summary;
}

std::vector<Vector3d> sample_leg_workspace(const robot::LegModel& leg, int count, uint64_t seed,
                                           double box_scale) {
  if (count < 1)
    throw std::invalid_argument("sample count must be positive, got " + std::to_string(count));
  if (!(box_scale > 0)) throw std::invalid_argument("box scale must be positive");
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::vector<Vector3d> feet;
  feet.reserve(count);
  const long max_attempts = 200L * count;
  for (long attempt = 0; attempt < max_attempts && static_cast<int>(feet.size()) < count;
       ++attempt) {
    const Vector3d u(unit(rng), unit(rng), unit(rng));
    const Vector3d p = leg.nominal_foot + box_scale * leg.range_of_motion.cwiseProduct(u);
    if (robot::inverse_kinematics(leg, p).ok()) feet.push_back(p);
  }
  if (static_cast<int>(feet.size()) < count)
    throw std::runtime_error("leg " + leg.name + ": only " + std::to_string(feet.size()) + " of " +
                             std::to_string(count) +
                             " sampled foot positions are within the joint limits");
  return feet;
}

namespace {

robot::ForcePolytope exact_at(const robot::LegModel& leg, const Vector3d& foot) {
  const robot::IkResult ik = robot::inverse_kinematics(leg, foot);
  if (ik.status == robot::IkStatus::unreachable) throw std::runtime_error(ik.message);
  return robot::exact_force_polytope(leg, ik.q);
}

double median_of(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double quantile_of(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(std::ceil(q * v.size())) - 1);
  return v[i];
}

// Normal of the base frame expressed in the leg's local (un-rolled, un-tilted) frame:
// n_loc = Ry(alpha) Rx(-gamma) n, the inverse of core::rotate.
Vector3d to_local(const LegCoordinates& c, const Vector3d& n) {
  const double cg = std::cos(c.gamma), sg = std::sin(c.gamma);
  const double ca = std::cos(c.alpha), sa = std::sin(c.alpha);
  const Vector3d w(n[0], cg * n[1] + sg * n[2], -sg * n[1] + cg * n[2]);
  return Vector3d(ca * w[0] + sa * w[2], w[1], -sa * w[0] + ca * w[2]);
}

// Angles of a local normal about a pole; theta unwrapped to lie within pi of `theta_near`.
void angles_of(int pole, const Vector3d& n, double theta_near, double* theta, double* phi) {
  *phi = std::asin(std::clamp(n[pole], -1.0, 1.0));
  double t = std::atan2(n[(pole + 2) % 3], n[(pole + 1) % 3]);
  while (t - theta_near > M_PI) t -= 2 * M_PI;
  while (t - theta_near < -M_PI) t += 2 * M_PI;
  *theta = t;
}

// Pole of each facet: the local axis least aligned with the facet's normal, so phi stays far
// from +-pi/2 where theta is undefined.
std::array<int, kPolytopeFacets> choose_poles(const LegCoordinates& c,
                                              const robot::ForcePolytope& exact) {
  std::array<int, kPolytopeFacets> poles{};
  for (int j = 0; j < kPolytopeFacets; ++j) {
    const Vector3d n = to_local(c, exact.normals[j]);
    n.cwiseAbs().minCoeff(&poles[j]);
  }
  return poles;
}

// Sets node (i, m) of `model` from an exact polytope seen at leg coordinates `c`.
void set_node_from_exact(LegPolytopeModel* model, int i, int m, const LegCoordinates& c,
                         const robot::ForcePolytope& exact, const double* theta_near) {
  double* node = model->node(i, m);
  for (int j = 0; j < kPolytopeFacets; ++j) {
    angles_of(model->poles[j], to_local(c, exact.normals[j]), theta_near ? theta_near[3 * j] : 0.0,
              &node[3 * j], &node[3 * j + 1]);
    node[3 * j + 2] = exact.offsets[j];
  }
}

constexpr int kNodeSize = 3 * kPolytopeFacets;
constexpr int kResiduals = 3 * kPolytopeVertices;

// Residuals of one training sample; NC = 2 (interpolation in l only) or 4 (bilinear in l, alpha)
// grid nodes, ordered (i, m), (i+1, m), (i, m+1), (i+1, m+1).
//
// The residuals depend on the NC corner nodes only through their interpolation v = sum_c w_c
// corner_c (weights w_c from the hip through l and alpha), so the Jacobian is taken with respect
// to the hip (4) and v (18) alone, 22 dual numbers instead of 4 + 18 NC = 76, and chained by hand:
// dr/dcorner_c = w_c dr/dv, dr/dhip = the total derivative (v moves with the hip through the
// weights). The same values and derivatives as automatic differentiation of the whole, for a
// fifth of the work (the fit's time is almost all Jacobian evaluations).
template <int NC>
class SampleCost : public ceres::CostFunction {
 public:
  SampleCost(const LegPolytopeModel* layout, const Vector3d& foot, const Matrix3d& scaled_jt,
             int cell_l, int cell_alpha, double overshoot_weight)
      : layout_(layout),
        foot_(foot),
        scaled_jt_(scaled_jt),
        cell_l_(cell_l),
        cell_alpha_(cell_alpha),
        overshoot_weight_(overshoot_weight) {
    set_num_residuals(kResiduals);
    mutable_parameter_block_sizes()->push_back(4);
    for (int c = 0; c < NC; ++c) mutable_parameter_block_sizes()->push_back(kNodeSize);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    if (!jacobians) {
      double w[NC], v[kNodeSize];
      interpolate(parameters, w, v);
      residuals_at(parameters[0], v, residuals);
      return true;
    }
    using J = ceres::Jet<double, 4 + kNodeSize>;
    J hip[4];
    for (int i = 0; i < 4; ++i) hip[i] = J(parameters[0][i], i);
    J w[NC], v[kNodeSize];
    interpolate(parameters, hip, w, v);
    for (int k = 0; k < kNodeSize; ++k) v[k].v[4 + k] = 1.0;
    J r[kResiduals];
    residuals_at(hip, v, r);
    for (int i = 0; i < kResiduals; ++i) {
      residuals[i] = r[i].a;
      if (jacobians[0])
        for (int k = 0; k < 4; ++k) jacobians[0][4 * i + k] = r[i].v[k];
      for (int c = 0; c < NC; ++c)
        if (jacobians[1 + c])
          for (int k = 0; k < kNodeSize; ++k)
            jacobians[1 + c][kNodeSize * i + k] = w[c].a * r[i].v[4 + k];
    }
    return true;
  }

 private:
  // Interpolation weights at the sample's leg coordinates and the interpolated node values.
  template <typename T>
  void weights(const T* hip, T* w) const {
    T gamma, l, alpha;
    core::leg_coordinates(layout_->use_roll, hip, foot_, &gamma, &l, &alpha);
    const T t = core::fraction(layout_->l_knots, cell_l_, l);
    if constexpr (NC == 2) {
      w[0] = T(1.0) - t;
      w[1] = t;
    } else {
      const T s = core::fraction(layout_->alpha_knots, cell_alpha_, alpha);
      w[0] = (T(1.0) - t) * (T(1.0) - s);
      w[1] = t * (T(1.0) - s);
      w[2] = (T(1.0) - t) * s;
      w[3] = t * s;
    }
  }
  template <typename T>
  void interpolate(double const* const* parameters, const T* hip, T* w, T* v) const {
    weights(hip, w);
    for (int k = 0; k < kNodeSize; ++k) {
      v[k] = T(0.0);
      for (int c = 0; c < NC; ++c) v[k] += w[c] * parameters[1 + c][k];
    }
  }
  void interpolate(double const* const* parameters, double* w, double* v) const {
    interpolate<double>(parameters, parameters[0], w, v);
  }

  // The 24 residuals from the hip and the interpolated (theta, phi, d) of the six facets.
  template <typename T>
  void residuals_at(const T* hip, const T* v, T* residuals) const {
    T gamma, l, alpha;
    core::leg_coordinates(layout_->use_roll, hip, foot_, &gamma, &l, &alpha);
    core::Vec3<T> n[kPolytopeFacets];
    T d[kPolytopeFacets];
    for (int j = 0; j < kPolytopeFacets; ++j) {
      n[j] = core::rotate(gamma, alpha, core::local_normal(layout_->poles[j], v[3 * j], v[3 * j + 1]));
      d[j] = v[3 * j + 2];
    }
    for (int k = 0; k < kPolytopeVertices; ++k) {
      const int r0 = core::vertex_facet(k, 0), r1 = core::vertex_facet(k, 1),
                r2 = core::vertex_facet(k, 2);
      const core::Vec3<T> vertex = core::meet(n[r0], n[r1], n[r2], d[r0], d[r1], d[r2]);
      const core::Vec3<T> x = scaled_jt_.cast<T>() * vertex;
      for (int i = 0; i < 3; ++i) {
        const double sign = ((k >> i) & 1) ? 1.0 : -1.0;
        T e = sign * x[i] - T(1.0);
        if (e > T(0.0)) e *= T(overshoot_weight_);
        residuals[3 * k + i] = e;
      }
    }
  }

  const LegPolytopeModel* layout_;
  Vector3d foot_;
  Matrix3d scaled_jt_;  // row i: J_i^T / tau_i
  int cell_l_, cell_alpha_;
  double overshoot_weight_;
};


// Smoothness prior on the reference grid: the second divided difference of every node value along
// one grid direction, made dimensionless by the mean knot spacing and the value's scale (radians
// for the angles, the central offset for the offsets). Cells that few samples visit (corners of
// the workspace) would otherwise be fitted to a handful of points and generalise badly.
struct SmoothnessResidual {
  double c_prev, c_mid, c_next;  // divided-difference weights times the mean spacing
  std::array<double, kNodeSize> inv_scale;
  double weight;
  template <typename T>
  bool operator()(const T* prev, const T* mid, const T* next, T* r) const {
    for (int k = 0; k < kNodeSize; ++k)
      r[k] = T(weight * inv_scale[k]) *
             (T(c_prev) * prev[k] + T(c_mid) * mid[k] + T(c_next) * next[k]);
    return true;
  }
};

void add_smoothness(ceres::Problem* problem, const std::vector<double>& knots, double weight,
                    const std::array<double, kNodeSize>& inv_scale,
                    const std::function<double*(int)>& node) {
  const int n = static_cast<int>(knots.size());
  if (n < 3 || weight <= 0) return;
  const double mean_h = (knots.back() - knots.front()) / (n - 1);
  for (int i = 1; i + 1 < n; ++i) {
    const double h0 = knots[i] - knots[i - 1], h1 = knots[i + 1] - knots[i];
    // (V+ - V)/h1 - (V - V-)/h0, times the mean spacing.
    auto* f = new SmoothnessResidual{mean_h / h0, -mean_h / h0 - mean_h / h1, mean_h / h1,
                                     inv_scale, weight};
    problem->AddResidualBlock(new ceres::AutoDiffCostFunction<SmoothnessResidual, kNodeSize,
                                                              kNodeSize, kNodeSize, kNodeSize>(f),
                              nullptr, node(i - 1), node(i), node(i + 1));
  }
}

}  // namespace

double polytope_rho_out(const LegPolytopeModel& model, const robot::LegModel& leg,
                        const Vector3d& foot) {
  const robot::ForcePolytope exact = exact_at(leg, foot);
  double worst = 0;
  for (const Vector3d& v : model.vertices(foot)) {
    const double r = exact.torque_ratio(v);
    worst = std::max(worst, std::isfinite(r) ? r : HUGE_VAL);
  }
  return worst;
}

double polytope_rho_in(const LegPolytopeModel& model, const robot::LegModel& leg,
                       const Vector3d& foot) {
  const robot::ForcePolytope exact = exact_at(leg, foot);
  const PolytopeFacets f = model.facets(foot);
  double worst = 0;
  for (const Vector3d& w : exact.vertices) {
    for (int j = 0; j < kPolytopeFacets; ++j) {
      if (!(f.offsets[j] > 0)) return 0.0;  // the approximation does not even hold f = 0
      worst = std::max(worst, f.normals[j].dot(w) / f.offsets[j]);
    }
  }
  return worst > 0 ? 1.0 / worst : 0.0;
}

PolytopeQuality evaluate_polytope_quality(const LegPolytopeModel& model, const robot::LegModel& leg,
                                          const std::vector<Vector3d>& feet) {
  PolytopeQuality q;
  q.samples = static_cast<int>(feet.size());
  if (feet.empty()) return q;
  std::vector<double> out, in;
  out.reserve(feet.size());
  in.reserve(feet.size());
  for (const Vector3d& p : feet) {
    out.push_back(polytope_rho_out(model, leg, p));
    in.push_back(polytope_rho_in(model, leg, p));
  }
  q.rho_out_median = median_of(out);
  q.rho_out_p95 = quantile_of(out, 0.95);
  q.rho_out_max = *std::max_element(out.begin(), out.end());
  q.rho_in_median = median_of(in);
  q.rho_in_min = *std::min_element(in.begin(), in.end());
  return q;
}

LegPolytopeModel paper_polytope_model(const robot::LegModel& leg, const std::vector<Vector3d>& feet,
                                      bool with_roll) {
  if (feet.empty()) throw std::invalid_argument("leg " + leg.name + ": no sample foot positions");
  const robot::IkResult nominal = robot::inverse_kinematics(leg, leg.nominal_foot);
  if (nominal.status == robot::IkStatus::unreachable) throw std::runtime_error(nominal.message);
  LegPolytopeModel m;
  m.leg_name = leg.name;
  m.use_roll = with_roll;
  if (with_roll) {
    m.hip = leg.haa_origin;
    m.hip_offset = leg.l0;
  } else {
    m.hip = robot::hfe_position(leg, nominal.q);
    m.hip_offset = 0.0;
  }
  double l_min = HUGE_VAL, l_max = -HUGE_VAL;
  for (const Vector3d& p : feet) {
    const double l = m.coordinates(p).l;
    l_min = std::min(l_min, l);
    l_max = std::max(l_max, l);
  }
  const LegCoordinates c_nom = m.coordinates(leg.nominal_foot);
  double l_mid = c_nom.l;
  if (!(l_mid > l_min && l_mid < l_max)) l_mid = 0.5 * (l_min + l_max);
  m.l_knots = {l_min, l_mid, l_max};
  m.alpha_knots = {c_nom.alpha};
  m.nodes.assign(3 * kNodeSize, 0.0);
  m.poles = choose_poles(c_nom, robot::exact_force_polytope(leg, nominal.q));
  // The paper's three default configurations: the foot along the nominal direction from the hip
  // (nominal tilt, and roll), at the three reference leg lengths.
  for (int k : {1, 0, 2}) {
    const double l = m.l_knots[k];
    const double a = l * std::sin(c_nom.alpha), b = l * std::cos(c_nom.alpha) + m.hip_offset;
    Vector3d p =
        with_roll
            ? Vector3d(m.hip + Vector3d(a, b * std::sin(c_nom.gamma), -b * std::cos(c_nom.gamma)))
            : Vector3d(m.hip.x() + a, leg.nominal_foot.y(), m.hip.z() - b);
    robot::IkResult ik = robot::inverse_kinematics(leg, p);
    if (ik.status == robot::IkStatus::unreachable) {
      // Out of reach along the nominal line: take the sample of closest leg length instead.
      const auto best =
          std::min_element(feet.begin(), feet.end(), [&](const auto& x, const auto& y) {
            return std::abs(m.coordinates(x).l - l) < std::abs(m.coordinates(y).l - l);
          });
      p = *best;
      ik = robot::inverse_kinematics(leg, p);
    }
    set_node_from_exact(&m, k, 0, m.coordinates(p), robot::exact_force_polytope(leg, ik.q),
                        k == 1 ? nullptr : m.node(1, 0));
  }
  m.validate();
  return m;
}

namespace {

void check_fit_request(const robot::LegModel& leg, std::size_t samples,
                       const PolytopeFitOptions& opt) {
  if (opt.l_refs < 2) throw std::invalid_argument("l_refs must be at least 2");
  if (opt.alpha_refs < 1) throw std::invalid_argument("alpha_refs must be at least 1");
  const int min_samples = 4 * opt.l_refs * opt.alpha_refs;
  if (static_cast<int>(samples) < min_samples)
    throw std::invalid_argument("leg " + leg.name + ": " + std::to_string(samples) +
                                " samples are too few to fit " + std::to_string(opt.l_refs) + "x" +
                                std::to_string(opt.alpha_refs) + " reference polytopes (need " +
                                std::to_string(min_samples) + ")");
}

// The model before the fit: the grid of references over the sampled range and each node the
// exact polytope of the sample nearest to it; `centre_node` is the centre sample's node (the
// offsets' scale and the poles come from it).
LegPolytopeModel initial_model(const robot::LegModel& leg, const std::vector<Vector3d>& feet,
                               const std::vector<robot::ForcePolytope>& exact,
                               const PolytopeFitOptions& opt, std::vector<double>* centre_node) {
  LegPolytopeModel m;
  m.leg_name = leg.name;
  m.use_roll = true;
  // Start from the HAA axis and the HAA->HFE offset; the fit moves them if that helps.
  m.hip = leg.haa_origin;
  m.hip_offset = leg.l0;
  // Grid of references over the sampled range: leg lengths Chebyshev-spaced (denser at the ends,
  // where the knee's facets turn fastest near full extension), tilts evenly spaced.
  std::vector<LegCoordinates> coords;
  double l_min = HUGE_VAL, l_max = -HUGE_VAL, a_min = HUGE_VAL, a_max = -HUGE_VAL;
  for (const Vector3d& p : feet) {
    coords.push_back(m.coordinates(p));
    l_min = std::min(l_min, coords.back().l);
    l_max = std::max(l_max, coords.back().l);
    a_min = std::min(a_min, coords.back().alpha);
    a_max = std::max(a_max, coords.back().alpha);
  }
  for (int k = 0; k < opt.l_refs; ++k) {
    const double u = 0.5 * (1 - std::cos(M_PI * k / (opt.l_refs - 1)));
    m.l_knots.push_back(l_min + (l_max - l_min) * u);
  }
  if (opt.alpha_refs == 1) {
    m.alpha_knots = {0.5 * (a_min + a_max)};
  } else {
    for (int k = 0; k < opt.alpha_refs; ++k)
      m.alpha_knots.push_back(a_min + (a_max - a_min) * k / (opt.alpha_refs - 1));
  }
  m.nodes.assign(opt.l_refs * opt.alpha_refs * kNodeSize, 0.0);

  // Initial references: the exact polytope of the sample nearest to each node.
  const double l_span = l_max - l_min, a_span = std::max(a_max - a_min, 1e-6);
  auto nearest = [&](double l, double a) {
    size_t best = 0;
    double best_d = HUGE_VAL;
    for (size_t s = 0; s < coords.size(); ++s) {
      const double d =
          std::pow((coords[s].l - l) / l_span, 2) + std::pow((coords[s].alpha - a) / a_span, 2);
      if (d < best_d) best_d = d, best = s;
    }
    return best;
  };
  const size_t centre = nearest(m.l_knots[opt.l_refs / 2], m.alpha_knots[opt.alpha_refs / 2]);
  m.poles = choose_poles(coords[centre], exact[centre]);
  centre_node->assign(kNodeSize, 0.0);
  {
    LegPolytopeModel tmp = m;
    set_node_from_exact(&tmp, 0, 0, coords[centre], exact[centre], nullptr);
    std::copy(tmp.node(0, 0), tmp.node(0, 0) + kNodeSize, centre_node->begin());
  }
  for (int i = 0; i < opt.l_refs; ++i) {
    for (int a = 0; a < opt.alpha_refs; ++a) {
      const size_t s = nearest(m.l_knots[i], m.alpha_knots[a]);
      set_node_from_exact(&m, i, a, coords[s], exact[s], centre_node->data());
    }
  }
  return m;
}

// One round of the least-squares fit of `m`'s nodes (and the hip point, unless held) to the
// samples. The grid cell of each sample depends on the hip point, so the problem is rebuilt per
// round.
ceres::Solver::Summary fit_round(const std::vector<Vector3d>& feet,
                                 const std::vector<robot::ForcePolytope>& exact,
                                 const std::vector<double>& centre_node,
                                 const PolytopeFitOptions& opt, double* hip,
                                 LegPolytopeModel* model) {
  LegPolytopeModel& m = *model;
  ceres::Problem::Options popts;
  ceres::Problem problem(popts);
  problem.AddParameterBlock(hip, 4);
  for (int i = 0; i < opt.l_refs; ++i)
    for (int a = 0; a < opt.alpha_refs; ++a) problem.AddParameterBlock(m.node(i, a), kNodeSize);
  m.hip = Vector3d(hip[0], hip[1], hip[2]);
  m.hip_offset = hip[3];
  for (size_t s = 0; s < feet.size(); ++s) {
    const LegCoordinates c = m.coordinates(feet[s]);
    const int cl = core::locate(m.l_knots, c.l);
    const int ca = core::locate(m.alpha_knots, c.alpha);
    Matrix3d scaled_jt = exact[s].jacobian.transpose();
    for (int i = 0; i < 3; ++i) scaled_jt.row(i) /= exact[s].torque_limit[i];
    if (opt.alpha_refs == 1) {
      problem.AddResidualBlock(
          new SampleCost<2>(&m, feet[s], scaled_jt, cl, 0, opt.overshoot_weight), nullptr, hip,
          m.node(cl, 0), m.node(cl + 1, 0));
    } else {
      problem.AddResidualBlock(
          new SampleCost<4>(&m, feet[s], scaled_jt, cl, ca, opt.overshoot_weight), nullptr, hip,
          m.node(cl, ca), m.node(cl + 1, ca), m.node(cl, ca + 1), m.node(cl + 1, ca + 1));
    }
  }
  std::array<double, kNodeSize> inv_scale;
  for (int k = 0; k < kNodeSize; ++k)
    inv_scale[k] = (k % 3 == 2) ? 1.0 / std::abs(centre_node[k]) : 1.0;
  const double reg = opt.smoothness * std::sqrt(static_cast<double>(feet.size()));
  for (int a = 0; a < opt.alpha_refs; ++a)
    add_smoothness(&problem, m.l_knots, reg, inv_scale, [&](int i) { return m.node(i, a); });
  for (int i = 0; i < opt.l_refs; ++i)
    add_smoothness(&problem, m.alpha_knots, reg, inv_scale, [&](int a) { return m.node(i, a); });
  if (!opt.fit_hip) problem.SetParameterBlockConstant(hip);
  // A node that no residual touches (no sample nearby and no smoothness prior) would make the
  // normal equations singular: hold it at its initial exact polytope.
  for (int i = 0; i < opt.l_refs; ++i) {
    for (int a = 0; a < opt.alpha_refs; ++a) {
      std::vector<ceres::ResidualBlockId> blocks;
      problem.GetResidualBlocksForParameterBlock(m.node(i, a), &blocks);
      if (blocks.empty()) problem.SetParameterBlockConstant(m.node(i, a));
    }
  }
  ceres::Solver::Options sopts;
  sopts.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  // Most of a solve is forming J^T J (Ceres' sparse inner products), not factoring it: Powell's
  // dogleg keeps its Gauss-Newton step across a rejected step and only shrinks the region, where
  // Levenberg-Marquardt forms and factors the damped system again. Same fits (Go2 held-out
  // figures equal to 1e-5), some 12 % less CPU for more, cheaper iterations.
  sopts.trust_region_strategy_type = ceres::DOGLEG;
  sopts.max_num_iterations = opt.max_iterations;
  sopts.num_threads = std::max(1, opt.num_threads);
  sopts.logging_type = ceres::SILENT;
  sopts.minimizer_progress_to_stdout = false;
  sopts.function_tolerance = 1e-7;
  ceres::Solver::Summary summary;
  ceres::Solve(sopts, &problem, &summary);
  return summary;
}

// Conservative scaling: the polytope scales with its offsets, and so does rho_out. Returns the
// scale applied to `m`'s offsets (1 when the training feet's worst rho_out is within the cap).
double cap_training_rho_out(const robot::LegModel& leg, const std::vector<Vector3d>& feet,
                            const PolytopeFitOptions& opt, LegPolytopeModel* m) {
  if (!(opt.max_training_rho_out > 0)) return 1.0;
  double worst = 0;
  for (const Vector3d& p : feet) worst = std::max(worst, polytope_rho_out(*m, leg, p));
  if (!(worst > opt.max_training_rho_out)) return 1.0;
  const double scale = opt.max_training_rho_out / worst;
  for (size_t k = 2; k < m->nodes.size(); k += 3) m->nodes[k] *= scale;
  return scale;
}

}  // namespace

LegPolytopeModel fit_leg_polytope(const robot::LegModel& leg, const std::vector<Vector3d>& feet,
                                  const PolytopeFitOptions& opt, LegFitReport* report,
                                  const LegPolytopeModel* start) {
  const auto t0 = std::chrono::steady_clock::now();
  check_fit_request(leg, feet.size(), opt);
  if (start && (start->num_l() != opt.l_refs || start->num_alpha() != opt.alpha_refs ||
                !start->use_roll))
    throw std::invalid_argument("leg " + leg.name + ": the start model's grid (" +
                                std::to_string(start->num_l()) + "x" +
                                std::to_string(start->num_alpha()) +
                                ") is not the fit's, or it has no roll");
  std::vector<robot::ForcePolytope> exact;
  exact.reserve(feet.size());
  for (const Vector3d& p : feet) exact.push_back(exact_at(leg, p));
  std::vector<double> centre_node;
  LegPolytopeModel m;
  if (start) {
    m = *start;
    m.leg_name = leg.name;
    const double* centre = m.node(opt.l_refs / 2, opt.alpha_refs / 2);
    centre_node.assign(centre, centre + kNodeSize);
  } else {
    m = initial_model(leg, feet, exact, opt, &centre_node);
  }
  double hip[4] = {m.hip.x(), m.hip.y(), m.hip.z(), m.hip_offset};
  LegFitReport rep;
  rep.leg = leg.name;
  rep.samples = static_cast<int>(feet.size());
  for (int round = 0; round < std::max(1, opt.rounds); ++round) {
    const ceres::Solver::Summary summary = fit_round(feet, exact, centre_node, opt, hip, &m);
    if (round == 0) rep.initial_cost = summary.initial_cost;
    rep.final_cost = summary.final_cost;
    rep.iterations += static_cast<int>(summary.iterations.size()) - 1;
    if (summary.termination_type == ceres::FAILURE)
      throw std::runtime_error("leg " + leg.name + ": polytope fit failed: " + summary.message);
  }
  m.hip = Vector3d(hip[0], hip[1], hip[2]);
  m.hip_offset = hip[3];

  rep.offset_scale = cap_training_rho_out(leg, feet, opt, &m);
  m.validate();
  rep.training = evaluate_polytope_quality(m, leg, feet);
  rep.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (report) *report = rep;
  return m;
}

std::string LegCopy::describe(const std::string& source_name) const {
  if (mirror_x > 0 && mirror_y > 0) return source_name + " translated";
  return source_name + " mirrored in " +
         (mirror_x < 0 && mirror_y < 0 ? "x and y" : mirror_x < 0 ? "x" : "y");
}

namespace {

Vector3d mirror_of(const LegCopy& c, const Vector3d& v) {
  return Vector3d(c.mirror_x * v.x(), c.mirror_y * v.y(), v.z());
}

// The mirrored leg's facet map at one foot position, or false when the polytopes differ.
bool match_polytopes(const robot::LegModel& source, const robot::LegModel& target,
                     const Vector3d& foot, LegCopy* copy, bool first) {
  const Vector3d p_source = source.haa_origin + mirror_of(*copy, foot - target.haa_origin);
  const robot::IkResult ik_t = robot::inverse_kinematics(target, foot);
  const robot::IkResult ik_s = robot::inverse_kinematics(source, p_source);
  if (ik_t.status == robot::IkStatus::unreachable || ik_s.status == robot::IkStatus::unreachable)
    return false;
  const robot::ForcePolytope t = robot::exact_force_polytope(target, ik_t.q);
  const robot::ForcePolytope s = robot::exact_force_polytope(source, ik_s.q);
  constexpr double kTol = 1e-9;
  const auto same = [&](int jt, int js) {
    return (t.normals[jt] - mirror_of(*copy, s.normals[js])).norm() < kTol &&
           std::abs(t.offsets[jt] - s.offsets[js]) <= kTol * std::abs(s.offsets[js]);
  };
  for (int i = 0; i < 3; ++i) {
    if (first) {
      const bool swapped = !same(2 * i, 2 * i) && same(2 * i, 2 * i + 1);
      copy->source_facet[2 * i] = 2 * i + (swapped ? 1 : 0);
      copy->source_facet[2 * i + 1] = 2 * i + (swapped ? 0 : 1);
    }
    if (!same(2 * i, copy->source_facet[2 * i]) || !same(2 * i + 1, copy->source_facet[2 * i + 1]))
      return false;
  }
  return true;
}

// Node values (theta, phi) of a facet whose local normal has component `axis` negated: with the
// pole's own axis phi changes sign; otherwise theta turns (local_normal's convention).
void mirror_angles(int pole, int axis, double* theta, double* phi) {
  if (axis == pole)
    *phi = -*phi;
  else if (axis == (pole + 1) % 3)
    *theta = M_PI - *theta;
  else
    *theta = -*theta;
}

}  // namespace

std::optional<LegCopy> find_leg_copy(const robot::LegModel& source, const robot::LegModel& target,
                                     const std::vector<Vector3d>& check_feet) {
  for (const auto& [mx, my] : {std::pair{1, 1}, std::pair{1, -1}, std::pair{-1, 1},
                               std::pair{-1, -1}}) {
    LegCopy copy;
    copy.mirror_x = mx;
    copy.mirror_y = my;
    bool ok = match_polytopes(source, target, target.nominal_foot, &copy, true);
    for (size_t k = 0; ok && k < check_feet.size(); ++k)
      ok = match_polytopes(source, target, check_feet[k], &copy, false);
    if (ok) return copy;
  }
  return std::nullopt;
}

LegPolytopeModel copy_leg_polytope(const LegPolytopeModel& fitted_source,
                                   const robot::LegModel& source, const robot::LegModel& target,
                                   const LegCopy& copy) {
  // The leg coordinates of p and of its source point p_s: l equal, gamma negated by mirror_y,
  // alpha by mirror_x; a facet's local normal is the source's with those components negated.
  const LegPolytopeModel& src = fitted_source;
  LegPolytopeModel m = src;
  m.leg_name = target.name;
  m.hip = target.haa_origin + mirror_of(copy, src.hip - source.haa_origin);
  const int na = src.num_alpha();
  if (copy.mirror_x < 0)
    for (int a = 0; a < na; ++a) m.alpha_knots[a] = -src.alpha_knots[na - 1 - a];
  for (int j = 0; j < kPolytopeFacets; ++j) m.poles[j] = src.poles[copy.source_facet[j]];
  for (int i = 0; i < src.num_l(); ++i) {
    for (int a = 0; a < na; ++a) {
      const double* from = src.node(i, copy.mirror_x < 0 ? na - 1 - a : a);
      double* to = m.node(i, a);
      for (int j = 0; j < kPolytopeFacets; ++j) {
        const double* f = from + 3 * copy.source_facet[j];
        double theta = f[0], phi = f[1];
        if (copy.mirror_y < 0) mirror_angles(m.poles[j], 1, &theta, &phi);
        if (copy.mirror_x < 0) mirror_angles(m.poles[j], 0, &theta, &phi);
        to[3 * j] = theta;
        to[3 * j + 1] = phi;
        to[3 * j + 2] = f[2];
      }
    }
  }
  m.validate();
  return m;
}

namespace {

// Runs `task(i)` for every index in `todo` on `workers` threads, one index per thread at a time;
// rethrows the first leg's error.
void for_each_leg(const std::vector<size_t>& todo, int workers,
                  const std::function<void(size_t)>& task) {
  std::vector<std::exception_ptr> errors(todo.size());
  std::atomic<size_t> next{0};
  const auto work = [&] {
    for (size_t k = next++; k < todo.size(); k = next++) {
      try {
        task(todo[k]);
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> threads;
  const int n = static_cast<int>(std::min<size_t>(std::max(1, workers), todo.size()));
  for (int t = 1; t < n; ++t) threads.emplace_back(work);
  work();
  for (auto& t : threads) t.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
}

// Feet of the copy check: every 25th training sample (24 of 600), spread over the workspace.
std::vector<Vector3d> copy_check_feet(const std::vector<Vector3d>& feet) {
  std::vector<Vector3d> out;
  for (size_t k = 0; k < feet.size(); k += 25) out.push_back(feet[k]);
  return out;
}

}  // namespace

RobotPolytopeModel fit_robot_polytopes(const robot::RobotModel& model,
                                       const PolytopeFitOptions& options,
                                       std::vector<LegFitReport>* reports) {
  RobotPolytopeModel out;
  out.robot = model.name;
  out.variant = "roll";
  const size_t n = model.legs.size();
  out.legs.resize(n);
  std::vector<LegFitReport> reps(n);
  std::vector<std::vector<Vector3d>> feet(n);
  std::vector<size_t> all_legs(n);
  for (size_t i = 0; i < n; ++i) all_legs[i] = i;
  for_each_leg(all_legs, options.num_threads, [&](size_t i) {
    feet[i] = sample_leg_workspace(model.legs[i], options.samples, options.seed + 7919 * i,
                                   options.box_scale);
  });
  // Legs that copy an earlier leg (mirror twins, translated copies) wait for its fit; the rest
  // are independent problems fitted one leg per thread (Ceres' own threads would share only the
  // Jacobian evaluation, a third of a leg's time; its normal equations and linear algebra are
  // serial).
  std::vector<std::optional<LegCopy>> copies(n);
  std::vector<size_t> to_fit;
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; options.copy_legs && j < i && !copies[i]; ++j) {
      if (copies[j]) continue;
      copies[i] = find_leg_copy(model.legs[j], model.legs[i], copy_check_feet(feet[i]));
      if (copies[i]) copies[i]->source = static_cast<int>(j);
    }
    if (!copies[i]) to_fit.push_back(i);
  }
  PolytopeFitOptions per_leg = options;
  if (to_fit.size() > 1) per_leg.num_threads = 1;
  const auto fit = [&](size_t i) {
    out.legs[i] = fit_leg_polytope(model.legs[i], feet[i], per_leg, &reps[i]);
  };
  for_each_leg(to_fit, options.num_threads, fit);

  // The copies, each checked on its own training feet; a copy that fits worse there than its
  // source on its own (a different joint range reaching where the source's grid extrapolates)
  // is fitted after all.
  std::vector<size_t> copied, refit;
  for (size_t i = 0; i < n; ++i)
    if (copies[i]) copied.push_back(i);
  std::vector<LegPolytopeModel> mirrored(n);  // before the copy's own offset scaling
  for_each_leg(copied, options.num_threads, [&](size_t i) {
    const auto t0 = std::chrono::steady_clock::now();
    const size_t j = static_cast<size_t>(copies[i]->source);
    mirrored[i] = copy_leg_polytope(out.legs[j], model.legs[j], model.legs[i], *copies[i]);
    LegPolytopeModel m = mirrored[i];
    LegFitReport rep;
    rep.leg = model.legs[i].name;
    rep.samples = static_cast<int>(feet[i].size());
    rep.copied_from = copies[i]->describe(model.legs[j].name);
    rep.offset_scale = cap_training_rho_out(model.legs[i], feet[i], options, &m);
    rep.training = evaluate_polytope_quality(m, model.legs[i], feet[i]);
    rep.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    out.legs[i] = std::move(m);
    reps[i] = rep;
  });
  for (size_t i : copied) {
    const auto& source = reps[static_cast<size_t>(copies[i]->source)].training;
    if (reps[i].training.rho_in_median < source.rho_in_median - options.copy_rho_in_tolerance)
      refit.push_back(i);
  }
  // A rejected copy is still the best first guess of its leg's fit: the fit starts from it
  // (a few iterations instead of a fit from the exact polytopes nearest the grid nodes).
  per_leg.num_threads = refit.size() > 1 ? 1 : options.num_threads;
  for_each_leg(refit, options.num_threads, [&](size_t i) {
    const std::string from = reps[i].copied_from;
    out.legs[i] = fit_leg_polytope(model.legs[i], feet[i], per_leg, &reps[i], &mirrored[i]);
    reps[i].started_from = from;
  });
  if (reports) *reports = std::move(reps);
  return out;
}

}  // namespace terrastride::planner
