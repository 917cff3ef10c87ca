// Joint rows at chosen instants of a problem (the refinement of plan_motion, planner.cpp): where
// a dense check of a solution (dense_joint_check) finds a joint beyond its range or velocity limit
// between the constraint points, the same rows as "joints" (constraints/joints.cpp,
// joint_velocity.cpp) at that instant, with the same bounds (the range less joint_margin, widened
// near a measured start or a pinned end; the velocity limit less its margin).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/planner/dense_checks.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

// A piece of kind "joints" (three rows, the leg's angles) at every point with `range`.
void add_joint_range_points(SrbdProblem& problem, const std::vector<JointPoint>& points);
// A piece of kind "joint_velocity" (three rows) at every point with `velocity`, for a robot with
// velocity limits (has_velocity_limits; none otherwise).
void add_joint_velocity_points(SrbdProblem& problem, const std::vector<JointPoint>& points);

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
