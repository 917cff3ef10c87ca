// What plan_motion refuses before its solve, without solving: for callers that suggest requests
// (`terrastride regions`) and must not suggest one the planner refuses at once.
#pragma once

#include "terrastride/planner/options.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

// For a fresh plan (no warm start): the problem's construction (the trunk's fit under any
// overhang on the path, a start clear of one) and the end stance's reachability
// (require_reachable). Throws what plan_motion would (UnreachableRequest, RequestError,
// GaitError); tens of ms where a solve takes seconds.
void check_before_solve(const robot::RobotModel& robot, const terrain::HeightField& plan_terrain,
                        const PlannerOptions& options);

}  // namespace terrastride::planner
