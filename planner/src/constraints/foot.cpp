// "foot": the foot radius (Bratta et al. 2020, III-B). The paper keeps a stance foothold where the
// terrain is constant within the foot radius r; the terrain gives that as a signed margin (m to the
// nearest unsafe cell for radius r, negative inside, with a gradient; see docs/design.md §5.4), so
// every free stance foothold gets one row  margin(p_x, p_y; r) >= foot_margin. A stance foot does
// not move (one position variable per stance), so one row holds it for the whole stance. The
// initial stances are given, not optimised, and get no row.
#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_foot_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  const double r = problem.robot().foot_radius;
  for (const auto& st : L.stances) {
    if (st.fixed) continue;
    LocalVars lv;
    const int ix = lv.add(st.pos_var), iy = lv.add(st.pos_var + 1);  // z does not enter
    problem.add_piece(
        make_piece("foot", lv, {options.foot_margin}, {kInf}, [=](const auto* x, auto* g) {
          g[0] = feasibility::safety_margin(*field, x[ix], x[iy], r);
        }));
  }
}

}  // namespace terrastride::planner
