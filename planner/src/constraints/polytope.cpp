// "polytope": force polytopes (Bratta et al. 2020, III-A; docs/design.md §7). The fitted
// model gives, per leg, g_j(p_b, f_b) = n^j(p_b)^T f_b - d^j(p_b) <= 0 (6 facets, two per joint)
// for the foot position p_b and the contact force f_b in the BASE frame:
//   R = rotation_zyx(euler), p_b = R^T (p - r), f_b = R^T f.
// The model's analytic dg/dp_b and dg/df_b are chained through p_b and f_b, which depend on the
// piece's variables (base position and Euler splines, foothold, force knots) by forward-mode AD.
// Rows are divided by m g, like the friction rows, so they read in body weights.
//
// Where. Forces are linear in time inside a stance segment and g is linear in f_b for a FIXED
// p_b and base orientation, so if the base stood still the force knots alone would make g <= 0
// hold along the whole segment. The base does not stand still: p_b and R change along the segment
// (r moves about 4 cm per 0.1 s segment in the 2.4 s crawl), and g depends nonlinearly on p_b
// (the facets turn and scale with the leg's length and tilt). So the rows are imposed at every
// force knot AND at `polytope_inner_points` points inside each stance segment (default: its
// midpoint), where the force is the knots' linear interpolation and the base comes from its
// Hermite splines. The post-hoc torque check (every sample of the plan) measures what is left.
//
// Rows. By default (polytope_softmax > 0) the 6 facets at both knots and the inner points of one
// stance segment become ONE row, their soft maximum (feasibility::soft_max >= every one of them,
// so nothing the separate rows forbid is admitted): the segment's piece needs the whole base
// Hermite segment anyway, so its clique does not grow, and the KKT system loses ~4,300 rows on an
// 11 s crawl. The separate rows (polytope_softmax = 0) are kept for tests and comparisons.
#include <algorithm>
#include <memory>
#include <stdexcept>
#include <vector>

#include "feasibility_common.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/polytope_model.hpp"

namespace terrastride::planner {

namespace {
constexpr int kMaxPolytopeValues = 64;  // facet values one merged piece may fold into its row
}  // namespace

namespace feasibility {

// g = constraint(p, f) * scale, with the model's analytic Jacobians chained for AD arguments.
inline void polytope_rows(const LegPolytopeModel& m, const Vec3<double>& p, const Vec3<double>& f,
                          double scale, double* g) {
  const auto v = m.constraint(p, f);
  for (int j = 0; j < kPolytopeFacets; ++j) g[j] = v[j] * scale;
}
inline void polytope_rows(const LegPolytopeModel& m, const Vec3<Ad>& p, const Vec3<Ad>& f,
                          double scale, Ad* g) {
  const Eigen::Vector3d pv(p[0].value(), p[1].value(), p[2].value());
  const Eigen::Vector3d fv(f[0].value(), f[1].value(), f[2].value());
  Eigen::Matrix<double, kPolytopeFacets, 3> dp, df;
  const auto v = m.constraint(pv, fv, &dp, &df);
  for (int j = 0; j < kPolytopeFacets; ++j) {
    AdVector d;
    for (int i = 0; i < 3; ++i) {
      accumulate(&d, dp(j, i) * scale, p[i].derivatives());
      accumulate(&d, df(j, i) * scale, f[i].derivatives());
    }
    g[j] = Ad(v[j] * scale, d);
  }
}

// The merged row: soft_max (at scale t) of the facet values at n points, point k's base-frame
// foot position pb[k] and force fb[k], times scale.
inline double polytope_soft_max(const LegPolytopeModel& m, const Vec3<double>* pb,
                                const Vec3<double>* fb, int n, double scale, double t) {
  double values[kMaxPolytopeValues];
  for (int k = 0; k < n; ++k) polytope_rows(m, pb[k], fb[k], scale, values + k * kPolytopeFacets);
  return soft_max(values, n * kPolytopeFacets, t);
}
// For AD arguments the soft maximum is differentiated in doubles: its derivative with respect to
// value j is w_j = exp((v_j - max) / t) / sum, so the row's derivative is the sum over the points
// of (sum_j w_j dg_j/dpb) pb' + (sum_j w_j dg_j/dfb) fb': six vector terms per point instead of
// every facet value's derivatives over the piece's variables and their soft maximum in AD (the
// same value; derivatives equal up to round-off).
inline Ad polytope_soft_max(const LegPolytopeModel& m, const Vec3<Ad>* pb, const Vec3<Ad>* fb,
                            int n, double scale, double t) {
  using std::exp;
  using std::log;
  double values[kMaxPolytopeValues];
  Eigen::Matrix<double, kPolytopeFacets, 3> dp[kMaxPolytopeValues / kPolytopeFacets],
      df[kMaxPolytopeValues / kPolytopeFacets];
  for (int k = 0; k < n; ++k) {
    const Eigen::Vector3d pv(pb[k][0].value(), pb[k][1].value(), pb[k][2].value());
    const Eigen::Vector3d fv(fb[k][0].value(), fb[k][1].value(), fb[k][2].value());
    const auto v = m.constraint(pv, fv, &dp[k], &df[k]);
    for (int j = 0; j < kPolytopeFacets; ++j) values[k * kPolytopeFacets + j] = v[j] * scale;
  }
  const int nv = n * kPolytopeFacets;
  double top = values[0];
  for (int k = 1; k < nv; ++k) top = std::max(top, values[k]);
  double weights[kMaxPolytopeValues];
  double sum = weights[0] = exp((values[0] - top) / t);
  for (int k = 1; k < nv; ++k) sum += weights[k] = exp((values[k] - top) / t);
  AdVector d;
  for (int k = 0; k < n; ++k) {
    const Eigen::Matrix<double, 1, kPolytopeFacets> w =
        Eigen::Map<const Eigen::Matrix<double, 1, kPolytopeFacets>>(weights + k * kPolytopeFacets) *
        (scale / sum);
    const Eigen::RowVector3d wp = w * dp[k], wf = w * df[k];
    for (int i = 0; i < 3; ++i) {
      accumulate(&d, wp[i], pb[k][i].derivatives());
      accumulate(&d, wf[i], fb[k][i].derivatives());
    }
  }
  return Ad(top + t * log(sum), d);
}

}  // namespace feasibility

namespace {

// One piece of the 6 facet rows at fraction sigma of segment s for foot f. At sigma = 0 or 1 only
// that knot's values enter (base pose, foothold, force knot); inside, the whole Hermite segment of
// the base, the segment's duration and both force knots.
void add_polytope_point(SrbdProblem& problem, const std::shared_ptr<const RobotPolytopeModel>& model,
                        int f, int s, double sigma) {
  const Layout& L = problem.layout();
  const double scale = 1.0 / (problem.robot().mass * kGravity);
  const std::vector<double> lo(kPolytopeFacets, -kInf), hi(kPolytopeFacets, 0.0);
  LocalVars lv;
  const HermiteLocal rp = add_base_position(lv, L, s, sigma, true);
  const HermiteLocal ep = add_base_euler(lv, L, s, sigma, true);
  const auto pf = lv.add3(L.foot_pos[f][s]);
  const auto f0 = sigma < 1.0 ? lv.add3(L.force[f][s][0]) : std::array<int, 3>{-1, -1, -1};
  const auto f1 = sigma > 0.0 ? lv.add3(L.force[f][s][1]) : std::array<int, 3>{-1, -1, -1};
  const int dur = rp.needs_duration || ep.needs_duration ? add_segment_duration(lv, L, s) : -1;
  const double frac = L.seg_fraction[s];
  const LegPolytopeModel* leg = &model->legs[f];
  problem.add_piece(make_piece("polytope", lv, lo, hi, [=, keep = model](const auto* x, auto* g) {
    using T = std::decay_t<decltype(*g)>;
    (void)keep;
    const T h = dur >= 0 ? T(x[dur] * frac) : T(1.0);
    Vec3<T> r, e;
    hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
    hermite<T>(sigma, h, x, ep, &e, nullptr, nullptr);
    const Eigen::Matrix<T, 3, 3> Rt = rotation_zyx<T>(e).transpose();
    const Vec3<T> force = (1.0 - sigma) * gather3(x, f0) + sigma * gather3(x, f1);
    const Vec3<T> pb = Rt * (gather3(x, pf) - r);
    const Vec3<T> fb = Rt * force;
    feasibility::polytope_rows(*leg, pb, fb, scale, g);
  }));
}

}  // namespace

void build_polytope_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const auto& robot = problem.robot();
  const auto model = shared_polytope_model(robot);
  if (model->legs.size() != robot.legs.size())
    throw std::invalid_argument("force polytopes of robot " + robot.name + " have " +
                                std::to_string(model->legs.size()) + " legs, the robot " +
                                std::to_string(robot.legs.size()));
  const double scale = 1.0 / (robot.mass * kGravity);
  const int nf = static_cast<int>(robot.legs.size());
  const int S = L.num_segments;
  const int ni = std::max(0, options.polytope_inner_points);

  auto add = [&](int f, int s, double sigma) { add_polytope_point(problem, model, f, s, sigma); };

  // Merged (polytope_softmax > 0): one piece and ONE row per stance segment, the soft maximum of
  // the 6 facet rows at its two force knots and its inner points (>= each of them, so the row
  // holds all of them). Its variables are those of the inner points' pieces above: the whole
  // base Hermite segment, the foothold, both force knots (a missing knot reads as zero force).
  auto add_segment = [&](int f, int s) {
    std::vector<double> sigmas{0.0};
    for (int q = 1; q <= ni; ++q) sigmas.push_back(static_cast<double>(q) / (ni + 1));
    sigmas.push_back(1.0);
    const int n_values = static_cast<int>(sigmas.size()) * kPolytopeFacets;
    if (n_values > kMaxPolytopeValues)
      throw std::invalid_argument("polytope: too many points per segment");
    LocalVars lv;
    const HermiteLocal rp = add_base_position(lv, L, s, 0.5, false);
    const HermiteLocal ep = add_base_euler(lv, L, s, 0.5, false);
    const auto pf = lv.add3(L.foot_pos[f][s]);
    const auto f0 = lv.add3(L.force[f][s][0]);
    const auto f1 = lv.add3(L.force[f][s][1]);
    const int dur = add_segment_duration(lv, L, s);
    const double frac = L.seg_fraction[s];
    const double t_soft = options.polytope_softmax;
    const LegPolytopeModel* leg = &model->legs[f];
    problem.add_piece(
        make_piece("polytope", lv, {-kInf}, {0.0}, [=, keep = model](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          (void)keep;
          const T h = x[dur] * frac;
          const Vec3<T> pf_w = gather3(x, pf), fk0 = gather3(x, f0), fk1 = gather3(x, f1);
          Vec3<T> pb[kMaxPolytopeValues / kPolytopeFacets], fb[kMaxPolytopeValues / kPolytopeFacets];
          int n = 0;
          for (const double sigma : sigmas) {
            Vec3<T> r, e;
            hermite<T>(sigma, h, x, rp, &r, nullptr, nullptr);
            hermite<T>(sigma, h, x, ep, &e, nullptr, nullptr);
            const Eigen::Matrix<T, 3, 3> Rt = rotation_zyx<T>(e).transpose();
            const Vec3<T> force = (1.0 - sigma) * fk0 + sigma * fk1;
            pb[n] = Rt * (pf_w - r);
            fb[n] = Rt * force;
            ++n;
          }
          g[0] = feasibility::polytope_soft_max(*leg, pb, fb, n, scale, t_soft);
        }));
  };

  for (int f = 0; f < nf; ++f) {
    int last = -1;
    for (int s = 0; s < S; ++s) {
      if (!L.contact[f][s]) continue;
      if (options.polytope_softmax > 0.0) {
        add_segment(f, s);
        continue;
      }
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0 || fv == last) continue;  // a knot shared by two segments: once
        last = fv;
        add(f, s, side);
      }
      for (int q = 1; q <= ni; ++q) add(f, s, static_cast<double>(q) / (ni + 1));
    }
  }
}

void add_polytope_points(SrbdProblem& problem, const std::vector<JointPoint>& points) {
  const auto model = shared_polytope_model(problem.robot());
  if (model->legs.size() != problem.robot().legs.size())
    throw std::invalid_argument("force polytopes of robot " + problem.robot().name + " have " +
                                std::to_string(model->legs.size()) + " legs, the robot " +
                                std::to_string(problem.robot().legs.size()));
  for (const JointPoint& point : points) {
    if (!point.torque) continue;
    require_joint_point_in(problem, point);
    if (!problem.layout().contact[point.foot][point.segment])
      throw std::invalid_argument("polytope point in a swing: foot " + std::to_string(point.foot) +
                                  ", segment " + std::to_string(point.segment));
    add_polytope_point(problem, model, point.foot, point.segment, point.sigma);
  }
}

}  // namespace terrastride::planner
