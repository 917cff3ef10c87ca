// "total_duration" (baseline, optimised timing only): the phase durations, variables then, sum to
// the plan's duration. Row in s.
#include <stdexcept>
#include <string>

#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

void add_total_duration(SrbdProblem& problem) {
  if (!problem.options().optimize_timing) return;
  const Layout& L = problem.layout();
  LocalVars lv;
  for (int v : L.interval_var) lv.add(v);
  const int n = static_cast<int>(L.interval_var.size());
  const double T = problem.timeline().duration();
  if (n <= kMaxPieceVars) {
    problem.add_piece(make_piece("total_duration", lv, {T}, {T}, [=](const auto* x, auto* g) {
      using T_ = std::decay_t<decltype(*g)>;
      T_ sum = x[0];
      for (int i = 1; i < n; ++i) sum += x[i];
      g[0] = sum;
    }));
  } else {
    throw std::invalid_argument("too many gait intervals (" + std::to_string(n) +
                                ") for timing optimisation; use fewer cycles");
  }
}

}  // namespace terrastride::planner
