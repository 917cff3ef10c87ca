// The push benchmark's physical references (bench_push_recovery, benchmarks.md §12.2): how hard a
// push a rigid body can stop over a support of feet, without a step or with one. Not a bound
// proved for the simulator (rolling, vertical motion and the swing's own dynamics are neglected):
// a yardstick for what a push target asks of the body, in a header so that tests can check it.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <vector>

#include "convex_hull.hpp"  // planner/src: the support polygon the planner measures against
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::bench {

// How far from `c` along the unit direction `d` the convex hull of `points` ends (0 when c is
// outside it or the hull is a segment or a point): the ray leaves through the nearest of the
// counter-clockwise hull's edges it points out of (d to the edge's right).
inline double support_reach(const std::vector<Eigen::Vector2d>& points, const Eigen::Vector2d& c,
                            const Eigen::Vector2d& d) {
  const std::vector<Eigen::Vector2d> hull = planner::convex_hull_2d(points);
  if (hull.size() < 3) return 0.0;
  double reach = INFINITY;
  for (std::size_t i = 0; i < hull.size(); ++i) {
    const Eigen::Vector2d& a = hull[i];
    const Eigen::Vector2d e = hull[(i + 1) % hull.size()] - a;
    const double inside = planner::cross_2d(Eigen::Vector2d::Zero(), e, c - a);
    if (inside < 0) return 0.0;
    const double towards = planner::cross_2d(Eigen::Vector2d::Zero(), e, d);
    if (towards < 0) reach = std::min(reach, inside / -towards);
  }
  return std::isfinite(reach) ? reach : 0.0;
}

// A step outward during a push: a foot lands `reach` m past the base along the push, `time` s after
// the push began (infinite: no step). A foot that stood at the push leaves the support at `lift`
// (infinite: it was already swinging), and until it lands the support's edge is
// `edge_while_lifted`.
struct OutwardStep {
  double time = INFINITY;
  double reach = 0.0;
  double lift = INFINITY;
  double edge_while_lifted = 0.0;
};

// The largest push (as the acceleration it gives the body, m/s2; times the mass: N) of `duration`
// s a rigid body at height h over a support that reaches `reach` m in the push's direction can
// stop: its feet's ground force can slow it by at
// most min(mu g, g (reach - y) / h) (friction, and the force's line of action within the support,
// the linear inverted pendulum's limit), with y the base's travel since the push began. Without a
// step it is lost when y reaches the support's edge; with one, past the edge it falls away from it
// as the pendulum does until the step lands, which moves the edge to the foot, and it is lost when
// y reaches that. Rolling, vertical motion and the stepping foot's own support are neglected, so
// this is a physical reference, not the simulator's verdict.
inline double push_limit(double reach, double h, double mu, double duration,
                         OutwardStep step = {}) {
  constexpr double g = 9.81;
  auto stopped = [&](double accel_push) {
    double y = 0.0, v = 0.0, edge = reach;
    bool stepped = !std::isfinite(step.time);
    const double dt = 1e-4;
    for (double t = 0.0; t < 10.0; t += dt) {
      if (!stepped && t >= step.lift && t < step.time) edge = step.edge_while_lifted;
      if (!stepped && t >= step.time) {
        edge = std::max(edge, y + step.reach);
        stepped = true;
      }
      const double lever = edge - y;
      const double brake = lever >= 0 ? std::min(mu * g, g * lever / h) : g * lever / h;
      const double a = (t < duration ? accel_push : 0.0) - brake;
      v = std::max(v + a * dt, 0.0);
      y += v * dt;
      if (stepped && y >= edge) return false;
      if (t >= duration && v <= 0.0) return true;
    }
    return true;
  };
  double lo = 0.0, hi = 200.0;  // m/s^2 of push
  for (int i = 0; i < 40; ++i) (stopped(0.5 * (lo + hi)) ? lo : hi) = 0.5 * (lo + hi);
  return lo;
}

// Where, along the unit direction `d` from `c`, the ground force's line of action can act on the
// support of `points`: the ray's exit from their convex hull (support_reach), or with two feet the
// point where it crosses the line between them (negative behind c; 0 when it misses the segment,
// as with one foot: the body has no support along the push then).
inline double support_edge(const std::vector<Eigen::Vector2d>& points, const Eigen::Vector2d& c,
                           const Eigen::Vector2d& d) {
  const std::vector<Eigen::Vector2d> hull = planner::convex_hull_2d(points);
  if (hull.size() >= 3) return support_reach(points, c, d);
  if (hull.size() < 2) return 0.0;
  const Eigen::Vector2d e = hull[1] - hull[0];
  const double across = planner::cross_2d(Eigen::Vector2d::Zero(), e, d);
  if (std::abs(across) < 1e-9) return 0.0;
  const double along = planner::cross_2d(Eigen::Vector2d::Zero(), e, hull[0] - c) / across;
  const double at = (c + along * d - hull[0]).dot(e) / e.squaredNorm();
  return at >= 0.0 && at <= 1.0 ? along : 0.0;
}

// How far past the base along `dir` (world, horizontal) leg `leg`'s foot can land: the farthest
// corner of its range-of-motion box around its nominal foot, with the base turned by yaw.
inline double leg_step_reach(const robot::LegModel& leg, double yaw, const Eigen::Vector3d& dir) {
  const Eigen::Vector2d d(std::cos(yaw) * dir.x() + std::sin(yaw) * dir.y(),
                          -std::sin(yaw) * dir.x() + std::cos(yaw) * dir.y());
  return leg.nominal_foot.head<2>().dot(d) + std::abs(leg.range_of_motion.x() * d.x()) +
         std::abs(leg.range_of_motion.y() * d.y());
}

// The farthest any leg's foot can land past the base along `dir` (leg_step_reach over the legs).
inline double outward_step_reach(const robot::RobotModel& robot, double yaw,
                                 const Eigen::Vector3d& dir) {
  double best = 0.0;
  for (const auto& leg : robot.legs) best = std::max(best, leg_step_reach(leg, yaw, dir));
  return best;
}

}  // namespace terrastride::bench
