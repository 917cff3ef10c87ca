// The paper's hardware-feasibility constraint sets (Bratta et al. 2020, section III), appended to
// the SRBD problem on top of "baseline":
//  - "foot"     foot radius (III-B): every free stance foothold keeps the terrain's signed
//               foothold-safety margin for the robot's foot radius >= foot_margin;
//  - "shin"     shin collision (III-B, eq. 13-14): p_z + k s sin(beta) - h(p_knee,k) >= clearance
//               for points k along the modelled shin, over the whole stance;
//  - "polytope" force polytopes (III-A): n^j(p_b)^T f_b <= d^j(p_b) in the base frame, at every
//               force knot and at points inside each stance segment.
// "all" means all three. Each set is built by one function (its own source file); the registry in
// nlp.cpp gets them from builtin_constraint_sets(), so they are available whenever the planner
// library is linked (no static initialisers).
#pragma once

#include <map>
#include <string>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct FeasibilityOptions {
  // foot: required margin (m) beyond the foot radius. The planner sees the smoothed 2 cm
  // height-field's margin (a B-spline of a grid distance), the post-hoc check the exact scene's;
  // a few millimetres absorb the rasterisation difference.
  double foot_margin = 0.005;
  // shin: points k = 1/n, 2/n, ..., 1 (knee) along the shin; vertical clearance (m) of each
  // point above the terrain under it; negative = use the leg's shin capsule radius.
  int shin_points = 3;
  double shin_clearance = -1.0;
  // shin: points per stance segment at which the base yaw is taken (ends of segments always).
  int shin_yaw_points = 2;
  // polytope: points per stance segment besides its two force knots (see polytope_set.cpp).
  int polytope_inner_points = 1;
};

void build_foot_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_shin_set(SrbdProblem& problem, const FeasibilityOptions& options = {});
void build_polytope_set(SrbdProblem& problem, const FeasibilityOptions& options = {});

// {"foot", "shin", "polytope"} with their default options (the registry's initial content).
std::map<std::string, ConstraintSetBuilder> builtin_constraint_sets();

// What "all" expands to, in order.
inline const char* const kAllFeasibilitySets[] = {"foot", "shin", "polytope"};

}  // namespace terrastride::planner
