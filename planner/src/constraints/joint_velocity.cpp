// "joints" (in "all"), velocity rows: the legs' joint velocities within the robot file's velocity
// limits, for robots whose every leg has them (an imported robot always does; HyQ's file gives
// none, and its problems are unchanged). The joint velocity is the one the post-hoc check measures
// (collision/src/kinematics.cpp): the foot's velocity relative to the base in the base frame,
// R^T (v_foot - v_base - w x (p_foot - p_base)), through the inverse of the leg's Jacobian at the
// joint angles of inverse kinematics. Rows at every knot (stance: the base moves over the
// standing foot) and at the quarter points of every swing segment, where the swing foot is
// fastest; the bounds keep kVelocityMargin of the limit in hand for the motion between the points.
#include <cmath>
#include <vector>

#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/robot/geometry.hpp"

namespace terrastride::planner {

namespace {

// The share of each velocity limit the rows leave unused: the post-hoc check samples every 10 ms,
// the rows hold 3 points per swing segment.
constexpr double kVelocityMargin = 0.05;

}  // namespace

template <class T>
Vec3<T> joint_velocity_rows(const robot::LegModel& leg, const Vec3<T>& base,
                            const Vec3<T>& base_vel, const Vec3<T>& euler,
                            const Vec3<T>& euler_rate, const Vec3<T>& foot,
                            const Vec3<T>& foot_vel) {
  const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(euler);
  const Vec3<T> rel = foot - base;
  Vec3<T> w;
  euler_to_angular<T>(euler, euler_rate, euler_rate, &w, nullptr);
  const Vec3<T> v_rel = R.transpose() * (foot_vel - base_vel - w.cross(rel));
  const Vec3<T> q = robot::leg_joint_angles<T>(leg, Vec3<T>(R.transpose() * rel));
  // The foot's Jacobian at q: column i is joint i's axis (turned by the joints before it) crossed
  // with the lever from the joint to the foot.
  const Eigen::Matrix<T, 3, 3> R0 = robot::axis_rotation<T>(leg.joint_axis[0], q[0]);
  const Eigen::Matrix<T, 3, 3> R01 = R0 * robot::axis_rotation<T>(leg.joint_axis[1], q[1]);
  const robot::LegPoints<T> pts = robot::general_leg_points<T>(leg, q);
  const Vec3<T> a0 = leg.joint_axis[0].cast<T>();
  const Vec3<T> a1 = R0 * leg.joint_axis[1].cast<T>();
  const Vec3<T> a2 = R01 * leg.joint_axis[2].cast<T>();
  const Vec3<T> c0 = a0.cross(Vec3<T>(pts.foot - leg.haa_origin.cast<T>()));
  const Vec3<T> c1 = a1.cross(Vec3<T>(pts.foot - pts.hfe));
  const Vec3<T> c2 = a2.cross(Vec3<T>(pts.foot - pts.knee));
  // J^-1 v by the adjugate, written out: the same operations for values and dual numbers (Eigen's
  // inverse takes another path for double, and the rows must agree to the last bit).
  const Vec3<T> r0 = c1.cross(c2), r1 = c2.cross(c0), r2 = c0.cross(c1);
  const T det = c0.dot(r0);
  return Vec3<T>(r0.dot(v_rel) / det, r1.dot(v_rel) / det, r2.dot(v_rel) / det);
}

template Vec3<double> joint_velocity_rows<double>(const robot::LegModel&, const Vec3<double>&,
                                                  const Vec3<double>&, const Vec3<double>&,
                                                  const Vec3<double>&, const Vec3<double>&,
                                                  const Vec3<double>&);

namespace {

// One piece at fraction sigma of segment s for foot f: the leg's three joint velocities within
// [lo, hi], from the base's and the foot's Hermite values and rates there (a stance foot's rate
// is zero).
void add_point_velocity_rows(SrbdProblem& problem, int f, int s, double sigma,
                             const std::vector<double>& lo, const std::vector<double>& hi) {
  const Layout& L = problem.layout();
  const robot::LegModel leg = problem.robot().legs[f];
  LocalVars lv;
  const LegSplinePoint lp = add_leg_spline_point(lv, L, f, s, sigma, false);
  problem.add_piece(make_piece("joint_velocity", lv, lo, hi, [=](const auto* x, auto* g) {
    using T = std::decay_t<decltype(*g)>;
    Vec3<T> base, base_vel, euler, euler_rate, foot, foot_vel;
    lp.eval<T>(x, &base, &base_vel, &euler, &euler_rate, &foot, &foot_vel);
    const Vec3<T> qd =
        joint_velocity_rows<T>(leg, base, base_vel, euler, euler_rate, foot, foot_vel);
    for (int j = 0; j < 3; ++j) g[j] = qd[j];
  }));
}

// Foot f's rows' bounds: the limits less kVelocityMargin.
void velocity_bounds(const robot::LegModel& leg, std::vector<double>* lo, std::vector<double>* hi) {
  const Eigen::Vector3d lim = (1.0 - kVelocityMargin) * leg.velocity_limit;
  *lo = {-lim[0], -lim[1], -lim[2]};
  *hi = {lim[0], lim[1], lim[2]};
}

}  // namespace

bool has_velocity_limits(const robot::RobotModel& robot) {
  for (const auto& leg : robot.legs)
    if (!(leg.velocity_limit.minCoeff() > 0)) return false;
  return !robot.legs.empty();
}

void build_joint_velocity_rows(SrbdProblem& problem) {
  const robot::RobotModel& robot = problem.robot();
  if (!has_velocity_limits(robot)) return;
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot.legs.size());
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = robot.legs[f];
    std::vector<double> lo, hi;
    velocity_bounds(leg, &lo, &hi);
    for (int k = 0; k <= S; ++k) {
      LocalVars lv;
      const auto p = lv.add3(L.foot_pos[f][k]);
      const auto pv = lv.add3(L.foot_vel[f][k]);  // -1 (zero) where the foot stands
      const auto r = lv.add3(L.base[k]);
      const auto rv = lv.add3(L.base[k] + 3);
      const auto e = lv.add3(L.base[k] + 6);
      const auto ev = lv.add3(L.base[k] + 9);
      problem.add_piece(make_piece("joint_velocity", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        const Vec3<T> qd = joint_velocity_rows<T>(leg, gather3(x, r), gather3(x, rv), gather3(x, e),
                                                  gather3(x, ev), gather3(x, p), gather3(x, pv));
        for (int j = 0; j < 3; ++j) g[j] = qd[j];
      }));
    }
    for (int s = 0; s < S; ++s) {
      if (L.contact[f][s]) continue;
      for (const double sigma : {0.25, 0.5, 0.75})
        add_point_velocity_rows(problem, f, s, sigma, lo, hi);
    }
  }
}

void add_joint_velocity_points(SrbdProblem& problem, const std::vector<JointPoint>& points) {
  const robot::RobotModel& robot = problem.robot();
  if (!has_velocity_limits(robot)) return;
  for (const JointPoint& point : points) {
    if (!point.velocity) continue;
    require_joint_point_in(problem, point);
    std::vector<double> lo, hi;
    velocity_bounds(robot.legs[point.foot], &lo, &hi);
    add_point_velocity_rows(problem, point.foot, point.segment, point.sigma, lo, hi);
  }
}

}  // namespace terrastride::planner
