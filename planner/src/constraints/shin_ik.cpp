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
// so the fixed-beta rows hold while the real shin hits the edge (see the issue #5 report).
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
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_shin_ik_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(2, options.shin_points);
  if (2 * nk - 1 > feasibility::kMaxShinValues)
    throw std::invalid_argument("shin_ik: too many shin points");
  const int nf = static_cast<int>(problem.robot().legs.size());
  for (int f = 0; f < nf; ++f) {
    const robot::LegModel leg = problem.robot().legs[f];
    const double exclusion = options.shin_exclusion >= 0.0
                                 ? options.shin_exclusion
                                 : robot::shin_exclusion(problem.robot(), leg);
    const double radius = options.shin_clearance >= 0.0 ? -1.0 : leg.shin_radius;
    const double fixed_clearance = options.shin_clearance;
    // shin_softmin > 0: the 2 nk - 1 values folded into one row (their soft minimum).
    const double t_soft = options.shin_softmin;
    const int rows = t_soft > 0.0 ? 1 : 2 * nk - 1;
    std::vector<double> lo(rows, (radius >= 0.0 ? 0.0 : fixed_clearance) + options.shin_ik_margin),
        hi(rows, kInf);
    for (int k = 0; k <= L.num_segments; ++k) {
      LocalVars lv;
      const auto p = lv.add3(L.foot_pos[f][k]);
      const auto r = lv.add3(L.base[k]);
      const auto e = lv.add3(L.base[k] + 6);
      problem.add_piece(make_piece("shin_ik", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        using std::sqrt;
        const Vec3<T> foot = gather3(x, p), base = gather3(x, r);
        const Eigen::Matrix<T, 3, 3> R = rotation_zyx<T>(gather3(x, e));
        const Vec3<T> knee =
            base + R * robot::knee_in_base<T>(
                           leg, robot::leg_joint_angles<T>(leg, R.transpose() * (foot - base)));
        const Vec3<T> d = knee - foot;
        const T len = sqrt(d.squaredNorm());
        const T horiz = sqrt(d[0] * d[0] + d[1] * d[1] + 1e-12);
        // Vertical gap for one capsule radius of perpendicular distance to an edge below the
        // axis: r / cos(inclination), capped at 2 r (inclination 60 deg): steeper, the lowest
        // points (just past the excluded foot end) could not clear flat ground by r / cos.
        T gap = T(0.0);
        if (radius >= 0.0) {
          T cosi = horiz / len;
          if (value_of(cosi) < 0.5) cosi = T(0.5);
          gap = radius / cosi;
        }
        // Rows 0..nk-1: each point above the terrain under it. Rows nk..2nk-2: each point above
        // the terrain under the NEXT point: the shin rises from foot to knee, so a step edge
        // between two points is held by the lower one too (measured on pallet_10 without these
        // rows: the edge slipped between points, capsule 2 cm into it).
        const T t0 = exclusion / len;
        Vec3<T> prev;
        T values[feasibility::kMaxShinValues] = {};
        T* out = t_soft > 0.0 ? values : g;
        for (int j = 0; j < nk; ++j) {
          const T t = t0 + (1.0 - t0) * (static_cast<double>(j) / (nk - 1));
          const Vec3<T> q = foot + t * d;
          const T h = terrain_height(*field, q[0], q[1]);
          out[j] = q[2] - h - gap;
          if (j > 0) out[nk + j - 1] = prev[2] - h - gap;
          prev = q;
        }
        if (t_soft > 0.0) g[0] = feasibility::soft_min(values, 2 * nk - 1, t_soft);
      }));
    }
  }
}

}  // namespace terrastride::planner
