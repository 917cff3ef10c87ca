// The initial guess of a re-plan: the previous plan, shifted in time, at the new problem's knots
// (its free variables only; the start state and the goal stay as the new problem fixed them).
#include <algorithm>
#include <vector>

#include "../plan_interpolation.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

void SrbdProblem::warm_start_from(const Trajectory& prev, double shift) {
  const Layout& L = layout_;
  const int S = L.num_segments;
  // The previous plan at knot k, from its samples in the segment to the left of the knot (to the
  // right for the first): with aligned knots (PhaseTimeline::first_interval_elapsed) that
  // reproduces the previous splines exactly.
  const auto& kt = L.nominal_knot_time;
  std::vector<TrajectorySample> knot(S + 1);
  for (int k = 0; k <= S; ++k) {
    const int seg = k > 0 ? k - 1 : 0;
    knot[k] =
        interpolation::segment_state(prev, kt[k] + shift, kt[seg] + shift, kt[seg + 1] + shift);
  }
  for (int k = 0; k <= S; ++k) {
    const auto& s = knot[k];
    const int b = L.base[k];
    const Eigen::Vector3d rates = interpolation::euler_rates(s);
    for (int d = 0; d < 3; ++d) {
      auto set = [&](int i, double v) {
        if (variables_.lower[i] < variables_.upper[i])
          variables_.initial[i] = std::clamp(v, variables_.lower[i], variables_.upper[i]);
      };
      set(b + d, s.base.position[d]);
      set(b + 3 + d, s.base.linear_velocity[d]);
      set(b + 6 + d, s.base.euler_zyx[d]);
      set(b + 9 + d, rates[d]);
    }
  }
  const int nf = static_cast<int>(robot_.legs.size());
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k <= S; ++k) {
      const int pv = L.foot_pos[f][k], vv = L.foot_vel[f][k];
      if (pv >= 0 && variables_.lower[pv] < variables_.upper[pv])
        for (int d = 0; d < 3; ++d) variables_.initial[pv + d] = knot[k].feet[f].position[d];
      if (vv >= 0 && variables_.lower[vv] < variables_.upper[vv])
        for (int d = 0; d < 3; ++d) variables_.initial[vv + d] = knot[k].feet[f].velocity[d];
    }
  for (int f = 0; f < nf; ++f)
    for (int s = 0; s < S; ++s)
      for (int side = 0; side < 2; ++side) {
        const int fv = L.force[f][s][side];
        if (fv < 0) continue;
        const auto smp = interpolation::segment_state(prev, kt[s + side] + shift, kt[s] + shift,
                                                      kt[s + 1] + shift);
        if (!smp.feet[f].contact) continue;
        for (int d = 0; d < 3; ++d) variables_.initial[fv + d] = smp.feet[f].force[d];
      }
}
}  // namespace terrastride::planner
