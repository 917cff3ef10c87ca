// A problem's state at a time as the start (or end) state a re-plan pins: the planner tests build
// pinned states from a cold problem's guess this way.
#pragma once

#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner::testing {

// `s` (SrbdProblem::evaluate) as a StartState: base pose and rates, feet and their velocities
// (no forces: a start state has none).
inline SrbdProblem::StartState start_state_of(const SrbdProblem::State& s) {
  SrbdProblem::StartState st;
  st.position = s.pos;
  st.euler_zyx = s.euler;
  st.linear_velocity = s.vel;
  st.euler_rates = s.euler_rate;
  st.foot_position = s.foot_pos;
  st.foot_velocity = s.foot_vel;
  return st;
}

}  // namespace terrastride::planner::testing
