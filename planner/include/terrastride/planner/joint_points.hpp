// Joint rows at chosen instants of a problem (the refinement of plan_motion, planner.cpp): where
// a dense check of a solution (dense_joint_check) finds a joint beyond its range, velocity or
// torque limit between the constraint points, the same rows as "joints" (constraints/joints.cpp,
// joint_velocity.cpp) or "polytope" (constraints/polytope.cpp) at that instant, with the same
// bounds (the range less joint_margin, widened near a measured start or a pinned end; the
// velocity limit less its margin; the contact force inside the leg's fitted force polytope).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "terrastride/planner/dense_checks.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// A piece of kind "joints" (three rows, the leg's angles) at every point with `range`.
void add_joint_range_points(SrbdProblem& problem, const std::vector<JointPoint>& points);
// A piece of kind "joint_velocity" (three rows) at every point with `velocity`, for a robot with
// velocity limits (has_velocity_limits; none otherwise).
void add_joint_velocity_points(SrbdProblem& problem, const std::vector<JointPoint>& points);
// A piece of kind "polytope" (six rows, the facets of the foot's force polytope at the instant's
// foot position in the base frame, divided by m g; the separate rows build_polytope_set makes
// with polytope_softmax = 0) at every point with `torque`. Throws std::invalid_argument for such
// a point in a swing segment (no contact force to bound).
void add_polytope_points(SrbdProblem& problem, const std::vector<JointPoint>& points);

// One clause for a message about a plan the refinement could not bring within its limits: how the
// refinement of plan.json's "joint_refinement" record ended ("rounds", "time", "rows_hold",
// "failed") and what the dense check still finds, e.g. "refinement of the joint rows stopped
// after 3 rounds with joints still past their limits between the constraint points (torque
// 1.04x its limit)". Empty when the record is null or the refinement ran to the end.
std::string joint_refinement_stop_clause(const nlohmann::json& refinement);

// Throws std::invalid_argument naming the point when it lies outside `problem`.
inline void require_joint_point_in(const SrbdProblem& problem, const JointPoint& point) {
  const int nf = static_cast<int>(problem.robot().legs.size());
  if (point.foot < 0 || point.foot >= nf || point.segment < 0 ||
      point.segment >= problem.layout().num_segments || !(point.sigma >= 0.0 && point.sigma <= 1.0))
    throw std::invalid_argument(
        "joint point outside the problem: foot " + std::to_string(point.foot) + ", segment " +
        std::to_string(point.segment) + ", sigma " + std::to_string(point.sigma));
}

}  // namespace terrastride::planner
