// "joints" (beyond the paper; in "all"): the legs' joint ranges. The range-of-motion box of the
// baseline (TOWR's kinematic model) is a box around the nominal foot, and HyQ's joint ranges do not
// contain all of it: a foot high and forward under the hip needs HFE beyond its range (measured on
// the pallet plans: 100-300 samples up to 8 deg past HFE's limit). This set keeps the joint angles
// from inverse kinematics of the foot in the base frame (docs/design.md §4.2) within
// [q_min + margin, q_max - margin] at every knot of the base spline: during stances (the foot
// stands, the base moves) and at the knots inside swings. Between knots the angles move little
// (stance); swing segments get a row at their middle too. The post-hoc check measures the result
// densely.
// Each knot row depends on the knot's base position and orientation and the foot position only.
// joints_softmax > 0 folds each knot's rows, and each swing segment's three points, into one soft-
// maximum row (fewer KKT rows; off by default: more iterations, see FeasibilityOptions).
// In "all" since the balanced initial guess (initialization/force_guess.cpp): pallet_15 "all" 10 ->
// 13 iterations, the demo 23 -> 18, and no plan sample outside a joint range (44-67 before on the
// pallets).
#include <algorithm>
#include <cmath>

#include "feasibility_common.hpp"
#include "spline_variables.hpp"
#include "start_return.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

namespace {

// The rows: the IK joint angles of the foot at `foot` (world) for the base at `base` with ZYX
// Euler angles `euler`.
template <class T>
void joint_angle_rows(const robot::LegModel& leg, const Vec3<T>& base, const Vec3<T>& euler,
                      const Vec3<T>& foot, T* g) {
  const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(euler);
  const Vec3<T> q = robot::leg_joint_angles<T>(leg, R.transpose() * (foot - base));
  for (int j = 0; j < 3; ++j) g[j] = q[j];
}

// The merged form: the six distances past the bounds, q_j - hi_j and lo_j - q_j (<= 0 inside),
// appended to `values` at `n`.
template <class T>
void joint_excess_values(const robot::LegModel& leg, const Vec3<T>& base, const Vec3<T>& euler,
                         const Vec3<T>& foot, const std::vector<double>& lo,
                         const std::vector<double>& hi, T* values, int* n) {
  T q[3];
  joint_angle_rows(leg, base, euler, foot, q);
  for (int j = 0; j < 3; ++j) {
    values[(*n)++] = q[j] - hi[j];
    values[(*n)++] = lo[j] - q[j];
  }
}

}  // namespace

namespace {

// The joints' bounds: each range shrunk by the margin, then widened near a measured start or a
// pinned end that lies outside it.
struct JointBounds {
  std::vector<std::vector<double>> lo, hi;
  // A measured start outside a joint's range (knot 0 fixed, !starts_at_rest): its excess below /
  // above each bound, the room the rows after it get (start_return.hpp); likewise a session
  // step's pinned end (the last knot fixed, !ends_at_rest), the room the rows before it get.
  std::vector<std::vector<double>> below, above, below_end, above_end;
  double span = 0.0, t_end = 0.0;

  // The bounds of foot f's rows at nominal time t > 0 (knot 0's stay, and the end's: a violated
  // one is a constant, left out by add_piece). Returns the merged row's room: its largest value
  // is the largest excess.
  double widened(int f, double t, std::vector<double>* l, std::vector<double>* u) const {
    *l = lo[f];
    *u = hi[f];
    const double w = t > 0.0 ? start_return_weight(t, span) : 0.0;
    const double we = end_return_weight(t, t_end, span);
    double most = 0.0;
    for (int j = 0; j < 3; ++j) {
      const double b = std::max(below[f][j] * w, below_end[f][j] * we);
      const double a = std::max(above[f][j] * w, above_end[f][j] * we);
      (*l)[j] -= b;
      (*u)[j] += a;
      most = std::max({most, b, a});
    }
    return most;
  }
};

JointBounds joint_bounds(const SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const double margin = options.joint_margin;
  const int nf = static_cast<int>(problem.robot().legs.size());
  JointBounds jb;
  jb.lo.assign(nf, std::vector<double>(3));
  jb.hi = jb.lo;
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel& leg = problem.robot().legs[f];
    for (int j = 0; j < 3; ++j) {
      jb.lo[f][j] = leg.q_min[j] + margin;
      jb.hi[f][j] = leg.q_max[j] - margin;
      if (!(jb.lo[f][j] < jb.hi[f][j]))
        throw std::invalid_argument("joint margin " + std::to_string(margin) +
                                    " rad leaves no range for joint " + std::to_string(j) +
                                    " of leg " + leg.name);
    }
  }
  jb.span = options.start_return;
  jb.t_end = L.nominal_knot_time[L.num_segments];
  jb.below.assign(nf, std::vector<double>(3, 0.0));
  jb.above = jb.below_end = jb.above_end = jb.below;
  auto excess = [&](int f, const MeasuredFootPose& m, std::vector<double>* b,
                    std::vector<double>* a) {
    double q[3];
    joint_angle_rows(problem.robot().legs[f], m.base, m.euler, m.foot, q);
    for (int j = 0; j < 3; ++j) {
      (*b)[j] = std::max(0.0, jb.lo[f][j] - q[j]);
      (*a)[j] = std::max(0.0, q[j] - jb.hi[f][j]);
    }
  };
  for (int f = 0; f < nf; ++f) {
    MeasuredFootPose m;
    if (measured_foot_pose(problem, f, &m)) excess(f, m, &jb.below[f], &jb.above[f]);
    if (pinned_end_foot_pose(problem, f, &m)) excess(f, m, &jb.below_end[f], &jb.above_end[f]);
  }
  return jb;
}

// Every knot of every foot: one piece each (foot f's knots 0..S, then the next foot's).
void add_knot_joint_rows(SrbdProblem& problem, const JointBounds& jb, double t_soft) {
  const Layout& L = problem.layout();
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    const std::vector<double> lo = jb.lo[f], hi = jb.hi[f];
    for (int k = 0; k <= L.num_segments; ++k) {
      std::vector<double> lk, hk;
      const double room = jb.widened(f, L.nominal_knot_time[k], &lk, &hk);
      LocalVars lv;
      const auto p = lv.add3(L.foot_pos[f][k]);
      const auto r = lv.add3(L.base[k]);
      const auto e = lv.add3(L.base[k] + 6);
      if (t_soft > 0.0) {
        problem.add_piece(make_piece("joints", lv, {-kInf}, {room}, [=](const auto* x, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          T values[6];
          int n = 0;
          joint_excess_values(leg, gather3(x, r), gather3(x, e), gather3(x, p), lo, hi, values, &n);
          g[0] = feasibility::soft_max(values, n, t_soft);
        }));
        continue;
      }
      problem.add_piece(make_piece("joints", lv, lk, hk, [=](const auto* x, auto* g) {
        joint_angle_rows(leg, gather3(x, r), gather3(x, e), gather3(x, p), g);
      }));
    }
  }
}

// Swing feet move fast between knots (the flat crawl's 0.33 m steps take 0.16 s): points
// inside each swing segment as well, a quarter of it apart. Measured on pallet_15 baseline,joints
// without these rows: a swinging RF foot passed 0.17 deg beyond HFE's limit between two knots;
// with the middle only, the pallet_15 trot to 1.5,0,0 with `all` put a landing LH foot 0.9 deg
// beyond HFE's limit at 0.91-0.92 s, between the middle and the end of its last swing segment
// (off-path suite, exit 4).
constexpr double kSwingPoints[3] = {0.25, 0.5, 0.75};

// Merged: the three points of a swing segment share its Hermite variables, so one piece and one
// row hold them all (its clique is each point's).
void add_merged_swing_joint_row(SrbdProblem& problem, const JointBounds& jb, int f, int s,
                                double t_soft) {
  const Layout& L = problem.layout();
  const robot::LegModel leg = problem.robot().legs[f];
  const std::vector<double> lo = jb.lo[f], hi = jb.hi[f];
  LocalVars lv;
  const HermiteLocal rp = add_base_position(lv, L, s, 0.5, false);
  const HermiteLocal ep = add_base_euler(lv, L, s, 0.5, false);
  const HermiteLocal fp = add_foot_position(lv, L, f, s, 0.5, false);
  const int dur = add_segment_duration(lv, L, s);
  const double frac = L.seg_fraction[s];
  // The largest room of the three points: the start's shrinks (largest at the first), the
  // pinned end's grows (largest at the last).
  std::vector<double> lk, hk;
  double room = 0.0;
  for (const double sigma : kSwingPoints)
    room = std::max(room, jb.widened(f, nominal_point_time(L, s, sigma), &lk, &hk));
  problem.add_piece(make_piece("joints", lv, {-kInf}, {room}, [=](const auto* x, auto* g) {
    using T = std::decay_t<decltype(*g)>;
    const T h = x[dur] * frac;
    T values[18];
    int n = 0;
    for (const double sigma : kSwingPoints) {
      Vec3<T> base, euler, foot;
      hermite<T>(sigma, h, x, rp, &base, nullptr, nullptr);
      hermite<T>(sigma, h, x, ep, &euler, nullptr, nullptr);
      hermite<T>(sigma, h, x, fp, &foot, nullptr, nullptr);
      joint_excess_values(leg, base, euler, foot, lo, hi, values, &n);
    }
    g[0] = feasibility::soft_max(values, n, t_soft);
  }));
}

// One piece at fraction sigma of segment s for foot f, three rows (the joints' angles within
// their widened bounds). In a stance segment the foot's Hermite variables are its foothold's.
void add_point_joint_rows(SrbdProblem& problem, const JointBounds& jb, int f, int s, double sigma) {
  const Layout& L = problem.layout();
  const robot::LegModel leg = problem.robot().legs[f];
  LocalVars lv;
  const LegSplinePoint lp = add_leg_spline_point(lv, L, f, s, sigma, true);
  std::vector<double> lk, hk;
  jb.widened(f, nominal_point_time(L, s, sigma), &lk, &hk);
  problem.add_piece(make_piece("joints", lv, lk, hk, [=](const auto* x, auto* g) {
    using T = std::decay_t<decltype(*g)>;
    Vec3<T> base, euler, foot;
    lp.eval<T>(x, &base, nullptr, &euler, nullptr, &foot, nullptr);
    joint_angle_rows(leg, base, euler, foot, g);
  }));
}

// One piece per swing point.
void add_swing_point_joint_rows(SrbdProblem& problem, const JointBounds& jb, int f, int s) {
  for (const double sigma : kSwingPoints) add_point_joint_rows(problem, jb, f, s, sigma);
}

}  // namespace

void build_joints_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const JointBounds jb = joint_bounds(problem, options);
  const double t_soft = options.joints_softmax;
  add_knot_joint_rows(problem, jb, t_soft);
  const Layout& L = problem.layout();
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < L.num_segments; ++s) {
      if (L.contact[f][s]) continue;
      if (t_soft > 0.0)
        add_merged_swing_joint_row(problem, jb, f, s, t_soft);
      else
        add_swing_point_joint_rows(problem, jb, f, s);
    }
}

void add_joint_range_points(SrbdProblem& problem, const std::vector<JointPoint>& points) {
  const JointBounds jb = joint_bounds(
      problem, feasibility_options(problem.robot(), problem.options().feasibility_settings));
  for (const JointPoint& point : points) {
    if (!point.range) continue;
    require_joint_point_in(problem, point);
    add_point_joint_rows(problem, jb, point.foot, point.segment, point.sigma);
  }
}

}  // namespace terrastride::planner
