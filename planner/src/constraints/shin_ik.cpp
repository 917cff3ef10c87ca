// "shin_ik" (beyond the paper): the same inequality on the leg's REAL shin, from the foot to the
// knee that the leg's inverse kinematics puts there for the current base pose (design.md §4.2):
//   p_b = R^T (p - r), v = p_b - p_HAA, gamma = atan2(v_y, -v_z), rho = hypot(v_y, v_z),
//   X = v_x, Z = -(rho - l0), q_K = kappa acos((X^2 + Z^2 - l1^2 - l2^2) / (2 l1 l2)),
//   q_H = atan2(-X, -Z) - atan2(l2 sin q_K, l1 + l2 cos q_K),
//   knee_b = p_HAA + Rx(gamma) (-l1 sin q_H, 0, -l0 - l1 cos q_H),   knee = r + R knee_b.
// Points q_j = p + t_j (knee - p), t_j from the excluded foot end to 1, must stand above the
// terrain by the capsule radius over the cosine of the shin's actual inclination. The paper's
// fixed beta is a heuristic: measured on our pallet plans, a hind shin flattens to ~30 deg when
// the base moves on over a foot planted before the step, and the knee is ~0.33 m from the foot,
// so the fixed-beta rows hold while the real shin hits the edge (docs/design.md §6.4).
// Imposed at every knot of the base spline (value-only, few columns), in stance and in swing: a
// foot lifting off beside an edge keeps its shin there for a few hundredths of a second (measured
// on pallet_15 with stance knots only: the RH shin 0.04 s after lift-off touched the edge). With
// shin_softmin > 0 (the default) the 2 nk - 1 rows of one knot are folded into one, their soft
// minimum (as for "shin").
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

void build_shin_ik_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(2, options.shin_points);
  const double t_soft = options.shin_softmin;
  const int nf = static_cast<int>(problem.robot().legs.size());
  const double foot_radius = problem.robot().foot_radius;
  const std::vector<std::vector<int>> points = feasibility::leg_clearance_points(problem, options);
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    const double exclusion = options.shin_exclusion >= 0.0
                                 ? options.shin_exclusion
                                 : robot::shin_exclusion(problem.robot(), leg);
    // A fixed shin_clearance replaces the capsule's gap r / cos(inclination).
    const feasibility::CapsuleRows rows = feasibility::capsule_rows(
        "shin_ik", leg.shin_radius, options.shin_clearance >= 0.0,
        std::max(0.0, options.shin_clearance) + options.shin_ik_margin, nk, options);
    for (int s = 0; s < S; ++s) {
      // Every knot (the segment's start; its end only in the last segment, the next segment's
      // start covers it), and leg_clearance_points per segment where the terrain is tall.
      for (const double sigma : L.segment_points(s, std::max(1, points[f][s]), s == S - 1)) {
        LocalVars lv;
        const feasibility::LegPoint at = feasibility::add_leg_point(lv, L, f, s, sigma, foot_radius);
        const auto shin_rows = [=](const auto& foot, const auto& base, const auto& euler,
                                   const auto& R, auto* g) {
          using T = std::decay_t<decltype(*g)>;
          using std::cos;
          using std::sin;
          using std::sqrt;
          const Vec3<T> knee =
              base + R * robot::knee_in_base<T>(
                             leg, robot::leg_joint_angles<T>(leg, R.transpose() * (foot - base)));
          const T len = sqrt((knee - foot).squaredNorm());
          const T t_start = exclusion / len, across_x = -sin(euler[0]), across_y = cos(euler[0]);
          feasibility::link_capsule_rows<T>(*field, foot, knee, rows, t_start, nk, across_x,
                                            across_y, t_soft, g);
        };
        const int n_rows = static_cast<int>(rows.lo.size());
        problem.add_piece(make_piece("shin_ik", lv, rows.lo, rows.hi, [=](const auto* x, auto* g) {
          feasibility::leg_point_rows(at, leg, x, n_rows, g, shin_rows);
        }));
      }
    }
  }
}

}  // namespace terrastride::planner
