// The "baseline" set: the SRBD formulation of nlp.hpp, its families in one place.
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_baseline_set(SrbdProblem& problem) {
  // Segment by segment, each segment's dynamics and range of motion together: the order of the
  // rows is the order of Ipopt's KKT matrix, so it is kept as it has always been (another order
  // is an equivalent problem whose iterates differ in their last bits).
  for (int s = 0; s < problem.layout().num_segments; ++s) {
    add_dynamics_linear(problem, s);
    add_dynamics_angular(problem, s);
    add_range_of_motion(problem, s);
  }
  add_stance_height(problem);
  add_foothold_planarity(problem);
  add_friction(problem);
  add_swing_clearance(problem);
  add_total_duration(problem);
  if (problem.options().rest_boundaries) add_rest_boundary(problem);
}

}  // namespace terrastride::planner
