// The objective of the SRBD problem: small sums of squares that pick, among the feasible motions,
// one a robot engineer accepts. Each term is one file here, its pieces of kind
// "cost_TERM", added with SrbdProblem::add_cost; the objective is the sum of the squares of their
// rows (SrbdProblem::eval_objective). Every term is dimensionless and integrated over time, so its
// weight (ProblemOptions::objective, ObjectiveWeights) says how much it matters:
//   base_acceleration          integral of |r''/g|^2 and w_ang |e''|^2 (smooth, calm base);
//   force_rate                 integral of |f'/(m g)|^2 over stances (forces that ramp);
//   swing_acceleration         integral of |p''/g|^2 over swings (a swing as low and smooth as
//                              its clearance rows allow: no 17 cm arcs before a 10 cm step);
//   base_jerk                  integral of |jerk/g|^2 within segments, and the jumps of the
//                              acceleration at knots as if spread over the adjoining segments;
//   nominal_pose               mean over the plan of ((z - z_nom)/5 cm)^2, |(e - e_nom)/0.1 rad|^2
//                              and (lateral offset from the straight path / 5 cm)^2 and the
//                              offset along it from the nominal progress, with the
//                              nominal path the cold initial guess (height above the terrain
//                              under the nominal feet, heading interpolated, the straight line).
#pragma once

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// Adds every term whose weight is > 0. Called by the SrbdProblem constructor after the initial
// guess (the nominal path) and before a warm start overwrites it.
void build_objective(SrbdProblem& problem);

void add_base_acceleration_cost(SrbdProblem& problem, double linear_weight, double angular_weight);
void add_force_rate_cost(SrbdProblem& problem, double weight);
void add_swing_acceleration_cost(SrbdProblem& problem, double weight);
void add_nominal_pose_cost(SrbdProblem& problem, double height_weight, double heading_weight,
                           double lateral_weight, double progress_weight);
void add_base_jerk_cost(SrbdProblem& problem, double weight);

// The integral over [0, h] of |a(t)|^2 for a linear a from a0 to a1 is
// h/3 (a0^2 + a0 a1 + a1^2) = |sqrt(h/4)(a0 + a1)|^2 + |sqrt(h/12)(a1 - a0)|^2:
// the two residual vectors whose squares sum to it, each times sqrt(weight).
template <class T, class V>
void linear_integral_residuals(const V& a0, const V& a1, const T& h, double weight, T* out) {
  using std::sqrt;
  const T c1 = sqrt(weight * h / 4.0), c2 = sqrt(weight * h / 12.0);
  for (int i = 0; i < 3; ++i) {
    out[i] = c1 * (a0[i] + a1[i]);
    out[3 + i] = c2 * (a1[i] - a0[i]);
  }
}

}  // namespace terrastride::planner
