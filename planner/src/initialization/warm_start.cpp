// The initial guess of a re-plan: the previous plan, shifted in time, at the new problem's knots
// (its free variables only; the start state and the goal stay as the new problem fixed them).
#include <algorithm>
#include <cmath>
#include <vector>

#include "../plan_interpolation.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

namespace {

// A measured start off the previous plan (after a push: the base 0.1-0.5 m/s and 0.5-2 rad/s
// away from the plan's rates, a lifted foot moving) against the previous plan's knot 1,
// 0.01-0.05 s later (a cropped first segment), asks the first segment's cubic for the whole
// difference at once: the guess's first-segment dynamics rows were 15-1000 body weights off, its
// swing rows 5-90 times the bound, and the steps after a push stalled there (20 iterations, still
// 1-700 off). So knot 1's guess is the measured start carried along the previous plan: its offset
// from the plan at the start, the position moved on by the velocity offset over the first
// segment, the velocity offset kept. The offset then moves at a constant velocity within the
// first segment, whose accelerations, and with them its dynamics and swing rows, are the previous
// plan's; the next segment (0.05-0.1 s) takes the offset back to the plan. Only knot 1 moves: a
// blend over the following knots moved their band rows too and took more iterations. A start on
// the plan (offset 0) leaves the guess as it was.
struct FirstKnotCarry {
  Variables* variables;
  double h;  // the first segment's nominal duration
  // The variable pairs (value, rate) at knot 0 (fixed by the start) and knot 1, dimension d, and
  // the previous plan's value and rate at the start; `angle`: an Euler angle (offset wrapped).
  void operator()(int value0, int rate0, int value1, int rate1, double planned_value,
                  double planned_rate, bool angle) const {
    std::vector<double>& x = variables->initial;
    auto is_fixed = [&](int i) { return !(variables->lower[i] < variables->upper[i]); };
    auto set = [&](int i, double v) {
      if (!is_fixed(i)) x[i] = std::clamp(v, variables->lower[i], variables->upper[i]);
    };
    if (value0 < 0 || rate0 < 0 || value1 < 0 || rate1 < 0) return;
    if (!is_fixed(value0) || !is_fixed(rate0)) return;  // not a measured start
    double offset = x[value0] - planned_value;
    if (angle) offset = std::remainder(offset, 2.0 * M_PI);
    const double rate_offset = x[rate0] - planned_rate;
    if (offset == 0.0 && rate_offset == 0.0) return;
    set(value1, x[value1] + offset + rate_offset * h);
    set(rate1, x[rate1] + rate_offset);
  }
};

void carry_start_offset_to_knot_1(const Layout& L, const TrajectorySample& planned_start,
                                  Variables* variables) {
  if (L.num_segments < 2) return;  // knot 1 is the end
  const FirstKnotCarry carry{variables, L.nominal_knot_time[1] - L.nominal_knot_time[0]};
  const int b0 = L.base[0], b1 = L.base[1];
  const Eigen::Vector3d rates = interpolation::euler_rates(planned_start);
  for (int d = 0; d < 3; ++d) {
    // A base knot's 12 values: position, velocity, Euler angles, Euler rates.
    carry(b0 + d, b0 + 3 + d, b1 + d, b1 + 3 + d, planned_start.base.position[d],
          planned_start.base.linear_velocity[d], false);
    carry(b0 + 6 + d, b0 + 9 + d, b1 + 6 + d, b1 + 9 + d, planned_start.base.euler_zyx[d],
          rates[d], true);
  }
  // A foot swinging through the first segment (position and velocity variables at both knots).
  for (std::size_t f = 0; f < L.foot_vel.size(); ++f) {
    const auto &p = L.foot_pos[f], &v = L.foot_vel[f];
    const auto& planned = planned_start.feet[f];
    for (int d = 0; d < 3; ++d)
      carry(p[0] < 0 ? -1 : p[0] + d, v[0] < 0 ? -1 : v[0] + d, p[1] < 0 ? -1 : p[1] + d,
            v[1] < 0 ? -1 : v[1] + d, planned.position[d], planned.velocity[d], false);
  }
}

}  // namespace

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
  if (!starts_at_rest_) carry_start_offset_to_knot_1(L, knot[0], &variables_);
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
