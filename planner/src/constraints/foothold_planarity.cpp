// "foothold_planarity" (baseline): every free stance foothold on locally planar terrain,
// |h(p + o) - h(p) - grad h(p) . o| <= foothold_planarity at the four offsets o of length
// clearance_probe (foothold_planarity.hpp). Keeps feet off step edges, where the smoothed surface
// differs from the real one and a lifting or landing foot would sweep through the edge. Rows in m.
#include <vector>

#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/foothold_planarity.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

void add_foothold_planarity(SrbdProblem& problem) {
  const ProblemOptions& options = problem.options();
  const terrain::HeightField* field = &problem.terrain();
  const double probe = options.clearance_probe;
  if (!(options.foothold_planarity > 0.0 && probe > 0.0)) return;
  const double tol = options.foothold_planarity;
  for (const auto& st : problem.layout().stances) {
    if (st.fixed) continue;
    LocalVars lv;
    const auto p = lv.add3(st.pos_var);
    std::vector<double> lo(4, -tol), hi(4, tol);
    problem.add_piece(make_piece("foothold_planarity", lv, lo, hi, [=](const auto* x, auto* g) {
      foothold_planarity_residuals(*field, x[p[0]], x[p[1]], probe, g);
    }));
  }
}

}  // namespace terrastride::planner
