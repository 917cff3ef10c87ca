// The initial guess of a re-plan: the previous plan, shifted in time, at the new problem's knots
// (its free variables only; the start state and the goal stay as the new problem fixed them).
// A measured start off the previous plan (a push) is blended into the guess's first knots and
// the forces there re-balanced (blend_to_measured_start), so that the solve starts near
// feasibility instead of with a jump at knot 0.
#include <algorithm>
#include <cmath>
#include <vector>

#include "../plan_interpolation.hpp"
#include "initial_guess.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

namespace {

// A start this far from the previous plan's state there is blended in: a push's offset (0.2 s
// of 200 N on HyQ is 0.45 m/s). The tracking errors of an undisturbed closed loop (a few mm,
// cm/s) are not: a small offset the solve repairs in the first segment alone (a 2 cm offset on
// the flat crawl: 2 iterations), while a blended guess moves every row of the blended knots
// (6 iterations).
constexpr double kBlendVelocity = 0.15;  // m/s
constexpr double kBlendPosition = 0.03;  // m
constexpr double kBlendEuler = 0.08;     // rad
constexpr double kBlendEulerRate = 0.8;  // rad/s
// The correction returns to the previous plan over at least this long, and over as long as a
// decelerating at half of friction * g takes for the velocity offset, but ends before the last
// knot (a session step's end is pinned) at most this fraction into the plan.
constexpr double kBlendMin = 0.3;
constexpr double kBlendMaxFraction = 0.8;

// The cubic Hermite correction from (d, dd) at u = 0 to (0, 0) at u = 1 over `span` s: its value
// and rate at u.
void hermite_correction(double u, double span, const Eigen::Vector3d& d, const Eigen::Vector3d& dd,
                        Eigen::Vector3d* value, Eigen::Vector3d* rate) {
  const double h00 = 2 * u * u * u - 3 * u * u + 1, h10 = u * u * u - 2 * u * u + u;
  const double g00 = 6 * u * u - 6 * u, g10 = 3 * u * u - 4 * u + 1;
  *value = h00 * d + h10 * span * dd;
  *rate = (g00 * d + g10 * span * dd) / span;
}

// The measured start (knot 0's fixed values) against the warm start's state there (the guess_*
// arguments): the difference blended out over the first knots (base, and a foot swinging from
// the start until its touch-down) and the forces there re-balanced for the moved base.
void blend_to_measured_start(SrbdProblem& problem, const Eigen::Vector3d& guess_position,
                             const Eigen::Vector3d& guess_velocity,
                             const Eigen::Vector3d& guess_euler, const Eigen::Vector3d& guess_rates,
                             const std::vector<Eigen::Vector3d>& guess_foot_position,
                             const std::vector<Eigen::Vector3d>& guess_foot_velocity) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const auto& kt = L.nominal_knot_time;
  const auto& lo = problem.lower();
  const auto& hi = problem.upper();
  std::vector<double>& x = problem.initial_guess();
  const int b0 = L.base[0];
  auto at = [&](int i) { return Eigen::Vector3d(lo[i], lo[i + 1], lo[i + 2]); };
  Eigen::Vector3d dp = at(b0) - guess_position, dv = at(b0 + 3) - guess_velocity,
                  de = at(b0 + 6) - guess_euler, dr = at(b0 + 9) - guess_rates;
  for (int d = 0; d < 3; ++d) de[d] = std::remainder(de[d], 2 * M_PI);
  const int nf = static_cast<int>(problem.robot().legs.size());
  auto free3 = [&](int i) { return i >= 0 && lo[i] < hi[i]; };
  if (!(dv.norm() > kBlendVelocity || dp.norm() > kBlendPosition || de.norm() > kBlendEuler ||
        dr.norm() > kBlendEulerRate))
    return;
  // The guess before the blend: the forces are re-balanced for the change from it.
  const std::vector<double> previous = x;
  const double decel = 0.5 * problem.options().friction * kGravity;
  const double span =
      std::min(std::max(kBlendMin, 4.0 * dv.norm() / decel), kBlendMaxFraction * kt[S]);
  auto set3 = [&](int i, const Eigen::Vector3d& add) {
    for (int d = 0; d < 3; ++d)
      if (lo[i + d] < hi[i + d]) x[i + d] += add[d];
  };
  int k_last = 0;  // the last knot the correction moves
  for (int k = 1; k < S && kt[k] < span; ++k) {
    Eigen::Vector3d c, cr;
    const int b = L.base[k];
    hermite_correction(kt[k] / span, span, dp, dv, &c, &cr);
    set3(b, c);
    set3(b + 3, cr);
    hermite_correction(kt[k] / span, span, de, dr, &c, &cr);
    set3(b + 6, c);
    set3(b + 9, cr);
    k_last = k;
  }
  // A foot swinging at the start (or a stance turned into a swing: a foot a push lifted) moves
  // from where it was measured to the previous plan's path by its touch-down.
  for (int f = 0; f < nf; ++f) {
    const int p0 = L.foot_pos[f][0], v0 = L.foot_vel[f][0];
    if (v0 < 0 || free3(p0)) continue;
    int s_end = 0;
    while (s_end < S && !L.contact[f][s_end]) ++s_end;
    const double land = kt[s_end];
    if (!(land > 0.0)) continue;
    const Eigen::Vector3d fp = at(p0) - guess_foot_position[f];
    Eigen::Vector3d fv = Eigen::Vector3d::Zero();
    if (!free3(v0)) fv = at(v0) - guess_foot_velocity[f];
    for (int k = 1; k < s_end; ++k) {
      Eigen::Vector3d c, cr;
      hermite_correction(kt[k] / land, land, fp, fv, &c, &cr);
      if (free3(L.foot_pos[f][k])) set3(L.foot_pos[f][k], c);
      if (free3(L.foot_vel[f][k])) set3(L.foot_vel[f][k], cr);
    }
  }
  // The forces over the blended knots (and the first one after them): the previous plan's plus
  // the least change that balances the change in the base's motion.
  initialization::balance_forces(problem.robot(), L, problem.options(), 0, std::min(S, k_last + 1),
                                 &previous, &x, &lo, &hi);
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
  if (starts_at_rest_) return;
  std::vector<Eigen::Vector3d> foot_position(nf), foot_velocity(nf);
  for (int f = 0; f < nf; ++f) {
    foot_position[f] = knot[0].feet[f].position;
    foot_velocity[f] = knot[0].feet[f].velocity;
  }
  blend_to_measured_start(*this, knot[0].base.position, knot[0].base.linear_velocity,
                          knot[0].base.euler_zyx, interpolation::euler_rates(knot[0]),
                          foot_position, foot_velocity);
}
}  // namespace terrastride::planner
