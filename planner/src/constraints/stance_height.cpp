// "stance_height" (baseline): every free stance foothold on the terrain, p_z = h(p_x, p_y). A
// stance has one position variable, so one row holds the foot there for the whole stance; the
// initial stances are given, not optimised, and get no row. Rows in m.
#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

void add_stance_height(SrbdProblem& problem) {
  const terrain::HeightField* field = &problem.terrain();
  for (const auto& st : problem.layout().stances) {
    if (st.fixed) continue;
    LocalVars lv;
    const auto p = lv.add3(st.pos_var);
    problem.add_piece(make_piece("stance_height", lv, {0.0}, {0.0}, [=](const auto* x, auto* g) {
      g[0] = x[p[2]] - terrain_height(*field, x[p[0]], x[p[1]]);
    }));
  }
}

}  // namespace terrastride::planner
