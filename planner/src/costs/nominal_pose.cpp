// "cost_nominal_pose": the base near its nominal path, at every base knot. The nominal path is
// the cold initial guess (initialization/base_guess.cpp): the straight line from the start to the
// goal, the height following the terrain under the nominal feet (+ nominal_base_height), the
// Euler angles interpolated from the start's to the goal's. Residuals, each times
// sqrt(weight * dt_k / T) (dt_k the knot's share of the plan's nominal time, so each term is a
// mean square over the plan): (z - z_nom) / 5 cm; (e - e_nom) / 0.1 rad per angle; the offset
// across the straight line (base_line.hpp, as the path-shape sets draw it) / 5 cm and along it
// from the nominal (minimum-jerk) progress / 5 cm (both left out when the goal is within 1 cm of
// the start: no line). Why: the demo's base weaved 86 mm side to side and rolled +-7 deg where
// nothing asked for it; with the other terms alone the pallet_15 base backed up 48 mm to make its
// steps.
#include <cmath>

#include "../constraints/base_line.hpp"
#include "costs.hpp"
#include "terrastride/planner/piece_math.hpp"

namespace terrastride::planner {

namespace {
constexpr double kLengthScale = 0.05;  // m
constexpr double kAngleScale = 0.1;    // rad
}  // namespace

void add_nominal_pose_cost(SrbdProblem& problem, double height_weight, double heading_weight,
                           double lateral_weight, double progress_weight) {
  const Layout& L = problem.layout();
  const int S = L.num_segments;
  const std::vector<double>& guess = problem.initial_guess();
  const double T = L.nominal_knot_time[S];
  // The line of the path-shape sets (base_line.hpp): the motion's line in a re-plan.
  const BaseLine line = base_line_of(problem);
  const bool has_line = line.defined;
  const Eigen::Vector2d across = line.across, along = line.along, origin = line.origin;
  for (int k = 0; k <= S; ++k) {
    const double t_prev = k > 0 ? L.nominal_knot_time[k - 1] : L.nominal_knot_time[0];
    const double t_next = k < S ? L.nominal_knot_time[k + 1] : L.nominal_knot_time[S];
    const double share = 0.5 * (t_next - t_prev) / T;
    const int b = L.base[k];
    LocalVars lv;
    const auto pos = lv.add3(b);
    const auto eul = lv.add3(b + 6);
    const double z_nom = guess[b + 2];
    const Eigen::Vector3d e_nom(guess[b + 6], guess[b + 7], guess[b + 8]);
    const double ch = std::sqrt(height_weight * share) / kLengthScale;
    const double ce = std::sqrt(heading_weight * share) / kAngleScale;
    const double cl = has_line ? std::sqrt(lateral_weight * share) / kLengthScale : 0.0;
    const double cp = has_line ? std::sqrt(progress_weight * share) / kLengthScale : 0.0;
    const Eigen::Vector2d nominal(guess[b], guess[b + 1]);
    std::vector<double> none(6, 0.0);
    problem.add_cost(make_piece("cost_nominal_pose", lv, none, none, [=](const auto* x, auto* g) {
      g[0] = ch * (x[pos[2]] - z_nom);
      for (int i = 0; i < 3; ++i) g[1 + i] = ce * (x[eul[i]] - e_nom[i]);
      g[4] = cl * (across.x() * (x[pos[0]] - origin.x()) + across.y() * (x[pos[1]] - origin.y()));
      g[5] = cp * (along.x() * (x[pos[0]] - nominal.x()) + along.y() * (x[pos[1]] - nominal.y()));
    }));
  }
}

}  // namespace terrastride::planner
