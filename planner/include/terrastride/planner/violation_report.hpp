// What a failed or stalled solve leaves violated, in words a user can act on: the constraint
// families whose rows stay outside their bounds, the feet they concern and the time span.
#pragma once

#include <string>
#include <vector>

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

struct FamilyViolation {
  std::string kind;                // the constraint family (Piece::kind)
  double violation = 0.0;          // its largest row violation, in the family's units
  std::vector<std::string> feet;   // feet of the pieces violated by at least half that
  double t_begin = 0.0, t_end = 0.0;  // s: the span of those pieces' times in the solution
};

// The families violated by more than `tolerance` at x, largest violation first. A piece's feet are
// those whose variables (foothold, swing knot, force) it reads; its time is the span of the knots
// of its base, force and swing-foot variables (a stance foothold alone: the stance).
std::vector<FamilyViolation> violated_families(const SrbdProblem& problem,
                                               const std::vector<double>& x, double tolerance);

// "shin_ik by 0.012 on RF, LH at t = 7.20-7.50 s; thigh by 0.004 on LH at t = 7.30 s" (the first
// `max_families`), or "" when none is violated.
std::string describe_violations(const std::vector<FamilyViolation>& families, int max_families = 3);

}  // namespace terrastride::planner
