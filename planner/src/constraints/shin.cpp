// "shin": shin collision (Bratta et al. 2020, III-B, (19)-(20); docs/design.md §6.4). The lower
// leg is modelled as a straight segment of length s from the foot p at a fixed angle beta to the
// ground, in the vertical plane through the base's heading psi (yaw):
//   point k in (0, 1]:  q_k = p + k s (cos(beta) cos(psi), cos(beta) sin(psi), sin(beta)),
// k = 1 the knee. Each point must stay above the terrain under it:
//   p_z + k s sin(beta) - h(q_k,x, q_k,y) >= clearance,
// at `shin_points` points from k_min (the part of the shin next to the foot, which stands on the
// ground by design, is left out, as in the post-hoc capsule check) to the knee; the clearance
// defaults to the shin capsule's radius / |cos(beta)| (see FeasibilityOptions).
// The sign of the horizontal direction is carried by beta: 37 deg on HyQ's hind legs (knee ahead
// of the foot), 127 deg on the front legs (cos < 0: knee behind the foot), as in the paper.
//
// Where: over every stance. A stance foot does not move, but psi does (the base turns while the
// foot stands), so the rows are imposed at every segment end of the stance and at
// `shin_yaw_points - 1` points inside each segment, with psi from the base's yaw spline there.
// Initial (fixed) stances are included: their footholds are given but the yaw is not.
//
// Rows: by default (shin_softmin > 0) all values of one stance segment (shin_points per yaw point)
// are folded into ONE row, their soft minimum (feasibility::soft_min <= every value, so the row
// holds each point's inequality); its variables are those of the segment's inner yaw point
// (foothold, yaw Hermite segment, duration), so cliques do not grow while the rows drop ~20x.
//
// Not in swing (a choice): in swing the real leg folds (the knee rises and the shin angle is far
// from beta), so the fixed-beta model would mostly constrain a configuration the leg is not in;
// a swinging foot is kept clear of the terrain (probed around it) by the baseline's swing
// clearance, and its lift-off and touch-down footholds are stance footholds covered here.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "feasibility_common.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"

namespace terrastride::planner {

void build_shin_set(SrbdProblem& problem, const FeasibilityOptions& options) {
  const Layout& L = problem.layout();
  const terrain::HeightField* field = &problem.terrain();
  const int nk = std::max(1, options.shin_points);
  const int ny = std::max(1, options.shin_yaw_points);
  const double t_soft = options.shin_softmin;
  for (const auto& st : L.stances) {
    const auto& leg = problem.robot().legs[st.foot];
    const double s = leg.shin_length, cb = std::cos(leg.shin_angle), sb = std::sin(leg.shin_angle);
    if (!(s > 0.0)) continue;
    const double clearance =
        options.shin_clearance >= 0.0
            ? options.shin_clearance
            : leg.shin_radius / std::max(0.2, std::abs(cb));  // beta near 90 deg: no blow-up
    const double exclusion = options.shin_exclusion >= 0.0
                                 ? options.shin_exclusion
                                 : robot::shin_exclusion(problem.robot(), leg);
    const double k_min = std::clamp(exclusion / s, 0.0, 1.0);
    // One piece over the points at fractions `sigmas` of segment seg: nk rows per fraction, or
    // (shin_softmin > 0) one row, their soft minimum.
    auto add = [&](int seg, std::vector<double> sigmas) {
      const int n_values = static_cast<int>(sigmas.size()) * nk;
      if (n_values > feasibility::kMaxShinValues)
        throw std::invalid_argument("shin: too many points per piece (shin_points x yaw points)");
      const bool merged = t_soft > 0.0;
      const int rows = merged ? 1 : n_values;
      std::vector<double> lo(rows, clearance), hi(rows, kInf);
      LocalVars lv;
      const auto p = lv.add3(st.pos_var);
      // Yaw: only its own knot at a lone segment end, the whole yaw Hermite otherwise.
      int y0 = -1, v0 = -1, y1 = -1, v1 = -1, dur = -1;
      const bool only_start = sigmas.size() == 1 && sigmas[0] == 0.0;
      const bool only_end = sigmas.size() == 1 && sigmas[0] == 1.0;
      if (only_start) {
        y0 = lv.add(L.base[seg] + 6);
      } else if (only_end) {
        y1 = lv.add(L.base[seg + 1] + 6);
      } else {
        y0 = lv.add(L.base[seg] + 6);
        v0 = lv.add(L.base[seg] + 9);
        y1 = lv.add(L.base[seg + 1] + 6);
        v1 = lv.add(L.base[seg + 1] + 9);
        dur = lv.add(L.interval_var[L.seg_interval[seg]]);
      }
      const double frac = L.seg_fraction[seg];
      problem.add_piece(make_piece("shin", lv, lo, hi, [=](const auto* x, auto* g) {
        using T = std::decay_t<decltype(*g)>;
        using std::cos;
        using std::sin;
        T values[feasibility::kMaxShinValues] = {};
        T* out = merged ? values : g;
        int n = 0;
        for (const double sigma : sigmas) {
          T psi;
          if (dur < 0) {
            psi = y0 >= 0 ? x[y0] : x[y1];
          } else {
            const T h = x[dur] * frac;
            psi = hermite_value<T>(sigma, h, x[y0], x[v0], x[y1], x[v1]);
          }
          const T c = cos(psi), sn = sin(psi);
          for (int k = 1; k <= nk; ++k) {
            const double a = (nk == 1 ? 1.0 : k_min + (1.0 - k_min) * (k - 1) / (nk - 1)) * s;
            const T qx = x[p[0]] + a * cb * c, qy = x[p[1]] + a * cb * sn;
            out[n++] = x[p[2]] + a * sb - terrain_height(*field, qx, qy);
          }
        }
        if (merged) g[0] = feasibility::soft_min(values, n, t_soft);
      }));
    };
    for (int seg = st.first_seg; seg <= st.last_seg; ++seg) {
      std::vector<double> sigmas;
      for (int q = 0; q <= ny; ++q) {
        if (q == ny && seg != st.last_seg) continue;  // the next segment's start covers this end
        sigmas.push_back(static_cast<double>(q) / ny);
      }
      if (t_soft > 0.0) {
        add(seg, sigmas);  // one row for the whole segment
      } else {
        for (const double sigma : sigmas) add(seg, {sigma});
      }
    }
  }
}

}  // namespace terrastride::planner
