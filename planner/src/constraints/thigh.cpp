// "thigh" (beyond the paper; in "all"): the thigh, a capsule from the HFE joint to the knee (the
// robot file's thigh radius), kept clear of the terrain by the same model as the shin
// (leg_capsule_clearance.hpp), with the HFE joint and the knee from the leg's inverse kinematics
// at the base pose. Measured on stairs --goal 1,0.3,0.5 with shin_ik alone: 147 samples of a thigh
// inside a riser (post-hoc capsule check); the thigh is a wider capsule (45 mm) whose knee end
// swings close to a riser's edge when the base climbs past a planted foot.
// Where: only where the terrain near the leg is tall (leg_clearance_points), at
// leg_clearance_points per segment there; elsewhere the thigh is a leg length above the ground.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "feasibility_common.hpp"
#include "leg_capsule_clearance.hpp"
#include "spline_variables.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_thigh_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(2, options.thigh_points);
  const double t_soft = options.shin_softmin;
  const int nf = static_cast<int>(problem.robot().legs.size());
  const double foot_radius = problem.robot().foot_radius;
  const std::vector<std::vector<int>> points = feasibility::leg_clearance_points(problem, options);
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    if (!(leg.thigh_radius > 0.0)) continue;
    const feasibility::CapsuleRows rows =
        feasibility::capsule_rows("thigh", leg.thigh_radius, false, options.shin_ik_margin, nk,
                                  options);
    for (int s = 0; s < S; ++s) {
      if (points[f][s] <= 0) continue;
      for (const double sigma : L.segment_points(s, points[f][s], s == S - 1 || points[f][s + 1] <= 0)) {
        LocalVars lv;
        const feasibility::LegPoint at = feasibility::add_leg_point(lv, L, f, s, sigma, foot_radius);
        const auto thigh_rows = [=](const auto& foot, const auto& base, const auto& euler,
                                    const auto& R, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          using std::cos;
          using std::sin;
          const Vec3<T> q = robot::leg_joint_angles<T>(leg, R.transpose() * (foot - base));
          const Vec3<T> hfe = base + R * robot::hfe_in_base<T>(leg, q);
          const Vec3<T> knee = base + R * robot::knee_in_base<T>(leg, q);
          const T t_start(0.0), across_x = -sin(euler[0]), across_y = cos(euler[0]);
          feasibility::link_capsule_rows<T>(*field, hfe, knee, rows, t_start, nk, across_x,
                                            across_y, t_soft, g);
        };
        const int n_rows = static_cast<int>(rows.lo.size());
        problem.add_piece(make_piece("thigh", lv, rows.lo, rows.hi, [=](const auto* x, auto* g) {
          feasibility::leg_point_rows(at, leg, x, n_rows, g, thigh_rows);
        }));
      }
    }
  }
}

}  // namespace terrastride::planner
