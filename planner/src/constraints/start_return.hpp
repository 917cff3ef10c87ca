// A re-plan from a measured state that already lies outside a row's bound (measured after a push:
// a joint 0.08-0.38 rad past its range, a foot 8 cm outside its range-of-motion box). Its knot 0
// is pinned to the measurement, so the rows there are constants; SrbdProblem::add_piece leaves the
// violated ones out and reports them. The same family's rows at the next knots would still ask for
// an instant recovery (a joint back within its range 0.03-0.1 s later), so they get room: the
// start's excess e over the bound, shrinking linearly to nothing over the start-return span,
// bound + e max(0, 1 - t / span) at nominal time t (as lateral_corridor.cpp's return into its
// corridor). A start within the bounds has e = 0: rows as before, so do cold plans.
// A start moving out of a foot's box goes further out before any force can stop it: after a
// right 450 N push (the pallet_15 closed loop at 4.2 s) LF stood 4 mm below its box with the base
// rising and rolling, its offset leaving the box at 0.4 m/s, and the first row after the start,
// 0.017 s on (the cropped first segment's end), with room shrinking from 4 mm, needed 47 m/s2 to
// stop it: the steps were infeasible by construction and failed at force_ramp and range_of_motion
// in the first segment. So a stance foot's range_of_motion rows get what the measured motion makes
// unavoidable instead, the offset's excess at its stop when it decelerates at friction * g
// (unavoidable_excess), returning over the same span. friction * g is the most a stance's friction
// gives sideways with the weight on the feet; a rise the base sheds at g, so there the room is at
// most twice what is unavoidable. A start moving back into its box, or within it and stopping
// before its edge, gets what it had.
// A session step's pinned horizon end is the same at the other side: its base is held at the
// reference's, and a stance foothold the measured start fixes lasts to it after a slip, so the
// end's rows can be constants outside their bounds (SrbdProblem::end_excess, left out), and the
// rows just before it, whose base must arrive at the pinned pose and velocity, cannot be within
// them either (the closed loop's left 300 N push on pallet_15: LH slipped 7 cm, the pinned end
// 5.7 cm outside LH's box, its last segment's rows 2.5 cm, nine steps in a row failed). They get
// the end's excess as room, growing over the same span up to the end: bound + e max(0, 1 -
// (t_end - t) / span). A plan that ends at rest (every cold plan, plan --init) has none.
#pragma once

#include <Eigen/Core>
#include <algorithm>

#include "base_line.hpp"  // all_fixed
#include "terrastride/planner/piece_math.hpp"  // rotation_zyx
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// The weight of the start's excess at nominal time t of a re-plan: 1 at the start, 0 from `span`.
inline double start_return_weight(double t, double span) {
  if (!(span > 0.0)) return 0.0;
  return std::max(0.0, 1.0 - t / span);
}

// The weight of a pinned end's excess at nominal time t of a step ending at t_end: 0 up to `span`
// before the end, rising to 1 towards it; 0 at the end itself, whose rows are constants (a
// violated one is left out by add_piece; one within its bound keeps it), and 0 at knot 0, a
// measured start's constants, which a horizon shorter than `span` would otherwise widen (and
// so hide part of the start's own excess from start_excess).
inline double end_return_weight(double t, double t_end, double span) {
  if (!(span > 0.0) || !(t > 0.0) || !(t < t_end - 1e-9)) return 0.0;
  return std::max(0.0, 1.0 - (t_end - t) / span);
}

// A re-plan's measured start (or a session step's pinned end) as the rows after (before) it see
// it: the base position and Euler angles at knot 0 (the last knot) and foot f's position there.
struct MeasuredFootPose {
  Eigen::Vector3d base, euler, foot;
};

// Foot f's pose at knot k when the problem fixes all of it; false otherwise.
inline bool fixed_foot_pose(const SrbdProblem& problem, int k, int f, MeasuredFootPose* pose) {
  const Layout& L = problem.layout();
  const int b = L.base[k], p = L.foot_pos[f][k];
  if (p < 0) return false;
  const auto& x = problem.lower();
  if (!all_fixed({b, b + 1, b + 2, b + 6, b + 7, b + 8, p, p + 1, p + 2}, x, problem.upper()))
    return false;
  pose->base = Eigen::Vector3d(x[b], x[b + 1], x[b + 2]);
  pose->euler = Eigen::Vector3d(x[b + 6], x[b + 7], x[b + 8]);
  pose->foot = Eigen::Vector3d(x[p], x[p + 1], x[p + 2]);
  return true;
}

// Foot f's measured start pose, when the problem starts from a given state (only a re-plan from a
// measured state gets room) and pins all of it; false otherwise (a cold plan, a foot whose
// position at knot 0 is free).
inline bool measured_foot_pose(const SrbdProblem& problem, int f, MeasuredFootPose* pose) {
  return !problem.starts_at_rest() && fixed_foot_pose(problem, 0, f, pose);
}

// The rate of stance foot f's measured offset from the base, in the base frame (d/dt R(e)^T (p -
// r) at knot 0, the foot at rest), when the start pins the base's velocity and Euler rates and f
// stands at knot 0; false otherwise (a swing foot accelerates much faster than its base can).
inline bool measured_stance_offset_rate(const SrbdProblem& problem, int f,
                                        const MeasuredFootPose& m, Eigen::Vector3d* rate) {
  const Layout& L = problem.layout();
  const int b = L.base[0];
  if (L.foot_vel[f][0] >= 0) return false;
  const auto& x = problem.lower();
  if (!all_fixed({b + 3, b + 4, b + 5, b + 9, b + 10, b + 11}, x, problem.upper())) return false;
  const Eigen::Vector3d v(x[b + 3], x[b + 4], x[b + 5]), er(x[b + 9], x[b + 10], x[b + 11]);
  // R(e)^T (p - r) along the start's motion, differentiated centrally (a constant of the
  // problem, not a row: no derivative of it is needed).
  auto offset = [&](double t) -> Eigen::Vector3d {
    return rotation_zyx<double>(m.euler + er * t).transpose() * (m.foot - m.base - v * t);
  };
  const double h = 1e-6;
  *rate = (offset(h) - offset(-h)) / (2 * h);
  return true;
}

// How far past `bound` a value at `value`, moving towards it at `rate`, is unavoidably at time
// t >= 0 when it can decelerate at most at `decel`: value + rate tau - decel tau^2 / 2 - bound at
// tau = min(t, rate / decel) (it stops at rate / decel), at least the start's own excess; 0 for a
// value within the bound that moves away from it or stops before reaching it.
inline double unavoidable_excess(double value, double rate, double bound, double t, double decel) {
  if (!(rate > 0.0) || !(decel > 0.0)) return std::max(0.0, value - bound);
  const double tau = std::min(t, rate / decel);
  return std::max(0.0, value + rate * tau - 0.5 * decel * tau * tau - bound);
}

// Foot f's pose at a session step's pinned end, when the problem pins its end (not at rest) and
// fixes the foot there (a foothold pinned to the reference's, or a stance the start fixes); false
// otherwise (a plan that ends at rest, a foot free at the end).
inline bool pinned_end_foot_pose(const SrbdProblem& problem, int f, MeasuredFootPose* pose) {
  return !problem.ends_at_rest() &&
         fixed_foot_pose(problem, problem.layout().num_segments, f, pose);
}

// The nominal time of the point at fraction sigma of segment s.
inline double nominal_point_time(const Layout& L, int s, double sigma) {
  return L.nominal_knot_time[s] + sigma * (L.nominal_knot_time[s + 1] - L.nominal_knot_time[s]);
}

}  // namespace terrastride::planner
