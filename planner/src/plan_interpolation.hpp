// Reading a plan between its samples: shared by interpolate_plan, the start state of a re-plan
// (replanning.cpp) and the warm start, which reproduces the previous plan's splines at the new
// problem's knots (initialization/warm_start.cpp).
#pragma once

#include <Eigen/Core>

#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner::interpolation {

// The Euler-angle rates of a sample (from its angular velocity).
Eigen::Vector3d euler_rates(const TrajectorySample& s);

// The state at t of the plan's spline segment [lo, hi], from the two samples inside it nearest t
// (exact even at the segment's ends, where interpolating across the knot would mix two cubics).
TrajectorySample segment_state(const Trajectory& plan, double t, double lo, double hi);

}  // namespace terrastride::planner::interpolation
