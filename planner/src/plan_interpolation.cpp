// A plan's state between its samples: positions and their rates by cubic Hermite interpolation
// (exact within one of the planner's cubic spline segments), accelerations and forces linear.
#include "plan_interpolation.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {

// The Euler-rate matrix is piece_math.hpp's, the one the optimiser's pieces use.
Eigen::Vector3d euler_rates_of(const Eigen::Vector3d& euler_zyx,
                               const Eigen::Vector3d& angular_velocity) {
  return euler_rate_matrix<double>(euler_zyx).fullPivLu().solve(angular_velocity);
}

namespace interpolation {

Eigen::Vector3d euler_rates(const TrajectorySample& s) {
  return euler_rates_of(s.base.euler_zyx, s.base.angular_velocity);
}

}  // namespace interpolation

namespace {

using interpolation::euler_rates;

// The state at t on the cubic through samples a and b (t may lie outside [a.t, b.t]): positions
// and their rates by cubic Hermite interpolation with the samples' velocities, exact when both
// samples lie on one cubic spline segment (the planner's splines are cubic); accelerations and
// forces linear (forces are linear within a segment).
TrajectorySample hermite_between(const TrajectorySample& a, const TrajectorySample& b, double t) {
  const double h = b.t - a.t;
  const double u = (t - a.t) / std::max(1e-12, h);
  TrajectorySample s = a;
  s.t = t;
  auto mix = [u](const Eigen::Vector3d& p, const Eigen::Vector3d& q) {
    return (1 - u) * p + u * q;
  };
  hermite<double>(u, h, a.base.position, a.base.linear_velocity, b.base.position,
                  b.base.linear_velocity, &s.base.position, &s.base.linear_velocity, nullptr);
  Eigen::Vector3d euler_rate;
  hermite<double>(u, h, a.base.euler_zyx, euler_rates(a), b.base.euler_zyx, euler_rates(b),
                  &s.base.euler_zyx, &euler_rate, nullptr);
  s.base.angular_velocity = euler_rate_matrix<double>(s.base.euler_zyx) * euler_rate;
  s.base.linear_acceleration = mix(a.base.linear_acceleration, b.base.linear_acceleration);
  s.base.angular_acceleration = mix(a.base.angular_acceleration, b.base.angular_acceleration);
  for (std::size_t f = 0; f < s.feet.size() && f < b.feet.size(); ++f) {
    hermite<double>(u, h, a.feet[f].position, a.feet[f].velocity, b.feet[f].position,
                    b.feet[f].velocity, &s.feet[f].position, &s.feet[f].velocity, nullptr);
    // Forces jump at contact switches: blend only inside one contact state.
    if (a.feet[f].contact == b.feet[f].contact)
      s.feet[f].force = mix(a.feet[f].force, b.feet[f].force);
  }
  return s;
}

}  // namespace

TrajectorySample interpolate_plan(const Trajectory& plan, double t) {
  const auto& S = plan.samples;
  if (S.empty()) throw std::invalid_argument("plan has no samples");
  if (t <= S.front().t) return S.front();
  if (t >= S.back().t) return S.back();
  const auto it = std::upper_bound(S.begin(), S.end(), t,
                                   [](double v, const TrajectorySample& s) { return v < s.t; });
  return hermite_between(*(it - 1), *it, t);
}

namespace interpolation {

TrajectorySample segment_state(const Trajectory& plan, double t, double lo, double hi) {
  const auto& S = plan.samples;
  if (S.empty()) throw std::invalid_argument("plan has no samples");
  const double tol = 1e-9;
  auto first = std::lower_bound(S.begin(), S.end(), lo - tol,
                                [](const TrajectorySample& s, double v) { return s.t < v; });
  auto last = std::upper_bound(S.begin(), S.end(), hi + tol,
                               [](double v, const TrajectorySample& s) { return v < s.t; });
  if (last - first < 2) return interpolate_plan(plan, t);
  // A sample at the segment's end belongs to the next segment (plans are sampled right-continuous):
  // its forces, contact flags and accelerations are the next segment's, and a foot that lifts off
  // there shows no force. Two samples inside the segment determine its cubics and linear forces,
  // so the end is extrapolated from them when there are two. (Missed before: on the flat 2.4 s
  // crawl, whose switch times fall on the 0.01 s sample grid, a re-plan started 0.1 m g and
  // 30 N m out of balance and ended infeasible; on pallet_15 no switch falls on a sample.)
  if (last - first >= 3 && std::abs((last - 1)->t - hi) <= tol) --last;
  // The pair of samples in [lo, hi] around t (or the end pair when t is at an end).
  auto b =
      std::lower_bound(first, last, t, [](const TrajectorySample& s, double v) { return s.t < v; });
  b = std::clamp(b, first + 1, last - 1);
  return hermite_between(*(b - 1), *b, t);
}

}  // namespace interpolation

}  // namespace terrastride::planner
