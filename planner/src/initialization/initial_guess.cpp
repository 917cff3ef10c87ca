#include "initial_guess.hpp"

namespace terrastride::planner::initialization {

void build_initial_guess(const GuessInputs& in, Variables* variables) {
  const Layout& L = in.layout;
  variables->initial.assign(variables->lower.size(), 0.0);
  for (std::size_t j = 0; j < L.interval_var.size(); ++j)
    variables->initial[L.interval_var[j]] = L.interval_nominal[j];
  const BaseBoundary boundary = guess_base_motion(in, variables);
  fix_base_boundary(in, boundary, variables);
  guess_footholds(in, boundary, variables);
  guess_swing_feet(in, boundary, variables);
  guess_forces(in, variables);
}

}  // namespace terrastride::planner::initialization
