// The initial guess of a re-plan: the previous plan, shifted in time, at the new problem's knots
// (its free variables only; the start state and the goal stay as the new problem fixed them).
#include <algorithm>
#include <vector>

#include "../plan_interpolation.hpp"
#include "initial_guess.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

namespace {

// The cubic Hermite offset that starts at (d, dv) and is (0, 0) at fraction s = 1 of `span`:
// value and rate at fraction s.
struct BridgeOffset {
  Eigen::Vector3d value, rate;
};
BridgeOffset bridge_offset(double s, double span, const Eigen::Vector3d& d,
                           const Eigen::Vector3d& dv) {
  const double h00 = 2 * s * s * s - 3 * s * s + 1, h10 = s * s * s - 2 * s * s + s;
  const double dh00 = (6 * s * s - 6 * s) / span, dh10 = 3 * s * s - 4 * s + 1;
  return {h00 * d + h10 * span * dv, dh00 * d + dh10 * dv};
}

}  // namespace

void SrbdProblem::warm_start_from(const Trajectory& prev, double shift, double bridge_span) {
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
  if (bridge_span > 0.0 && !starts_at_rest_) bridge_guess_from_start(knot[0], bridge_span);
}

// The guess's first `span` seconds moved from the previous plan to a transition that leaves the
// measured start with its own velocity and rates and meets the previous plan at `span` (a cubic
// Hermite offset, its largest acceleration 4 |dv| / span + 6 |d| / span^2), swing feet likewise up
// to their touch-down; the forces over that span then balance the transition (guess_forces).
// The previous plan's own first knots leave the measured velocity within the first 0.01-0.02 s
// segment, an acceleration of |dv| / h (35-130 m/s2 for the 0.6-1.3 m/s offsets after a push)
// that the first iterates have to undo.
void SrbdProblem::bridge_guess_from_start(const TrajectorySample& guess_start, double span) {
  const Layout& L = layout_;
  const int S = L.num_segments;
  const auto& kt = L.nominal_knot_time;
  std::vector<double>& x = variables_.initial;
  auto set = [&](int i, double v) {
    if (variables_.lower[i] < variables_.upper[i])
      x[i] = std::clamp(v, variables_.lower[i], variables_.upper[i]);
  };
  auto v3 = [&](int i) { return Eigen::Vector3d(x[i], x[i + 1], x[i + 2]); };
  const int b0 = L.base[0];
  const Eigen::Vector3d dp = v3(b0) - guess_start.base.position;
  const Eigen::Vector3d dv = v3(b0 + 3) - guess_start.base.linear_velocity;
  const Eigen::Vector3d de = v3(b0 + 6) - guess_start.base.euler_zyx;
  const Eigen::Vector3d der = v3(b0 + 9) - interpolation::euler_rates(guess_start);
  int last_knot = 0;
  for (int k = 1; k <= S && kt[k] < span; ++k) {
    const double s = kt[k] / span;
    const BridgeOffset p = bridge_offset(s, span, dp, dv), e = bridge_offset(s, span, de, der);
    const int b = L.base[k];
    for (int d = 0; d < 3; ++d) {
      set(b + d, x[b + d] + p.value[d]);
      set(b + 3 + d, x[b + 3 + d] + p.rate[d]);
      set(b + 6 + d, x[b + 6 + d] + e.value[d]);
      set(b + 9 + d, x[b + 9 + d] + e.rate[d]);
    }
    last_knot = k;
  }
  // A swing foot measured off the previous plan's swing: its own offset, gone by its touch-down
  // (the first knot whose velocity is not a variable) or by `span`, whichever comes first.
  const int nf = static_cast<int>(robot_.legs.size());
  for (int f = 0; f < nf; ++f) {
    if (L.foot_vel[f][0] < 0 || L.foot_pos[f][0] < 0) continue;
    int touchdown = S;
    for (int k = 1; k <= S; ++k)
      if (L.foot_vel[f][k] < 0) {
        touchdown = k;
        break;
      }
    const double foot_span = std::min(span, kt[touchdown]);
    if (!(foot_span > 0.0)) continue;
    const FootState& g = guess_start.feet[f];
    const Eigen::Vector3d d = v3(L.foot_pos[f][0]) - g.position;
    const Eigen::Vector3d dfv = v3(L.foot_vel[f][0]) - g.velocity;
    for (int k = 1; k < touchdown && kt[k] < foot_span; ++k) {
      const BridgeOffset o = bridge_offset(kt[k] / foot_span, foot_span, d, dfv);
      for (int dd = 0; dd < 3; ++dd) {
        set(L.foot_pos[f][k] + dd, x[L.foot_pos[f][k] + dd] + o.value[dd]);
        set(L.foot_vel[f][k] + dd, x[L.foot_vel[f][k] + dd] + o.rate[dd]);
      }
    }
  }
  // The knot at `span` and the one after it keep the previous plan's base; their forces are
  // balanced again as well (their segments' accelerations changed with the bridge's last knot).
  initialization::guess_forces({robot_, terrain_, timeline_, options_, layout_, nullptr},
                               &variables_, 0, std::min(S, last_knot + 1));
}
}  // namespace terrastride::planner
