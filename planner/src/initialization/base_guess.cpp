// The initial guess of the base: from the start state to a goal pose that rests on the terrain,
// along a minimum-jerk profile, at a height that follows the terrain under the nominal feet.
#include <algorithm>
#include <cmath>
#include <vector>

#include "initial_guess.hpp"

namespace terrastride::planner::initialization {

BaseBoundary guess_base_motion(const GuessInputs& in, Variables* variables) {
  const robot::RobotModel& robot = in.robot;
  const terrain::HeightField& terrain = in.terrain;
  const ProblemOptions& options = in.options;
  const Layout& L = in.layout;
  const SrbdProblem::StartState* start = in.start;
  std::vector<double>& x0 = variables->initial;
  const int S = L.num_segments;
  const int nf = static_cast<int>(robot.legs.size());
  const double T = in.timeline.duration();

  // Start and goal poses. The base height follows the terrain under the nominal feet.
  auto base_height = [&](double x, double y, double yaw) {
    double h = 0.0;
    for (const auto& leg : robot.legs) {
      const Eigen::Vector3d p = nominal_foot_world(leg, Eigen::Vector3d(x, y, 0.0), yaw);
      h += terrain.height(p.x(), p.y());
    }
    return h / nf + robot.nominal_base_height;
  };
  Eigen::Vector3d p_start, e_start(options.start.z(), 0.0, 0.0), v_start = Eigen::Vector3d::Zero(),
                                                                 r_start = Eigen::Vector3d::Zero();
  if (start) {
    p_start = start->position;
    e_start = start->euler_zyx;
    v_start = start->linear_velocity;
    r_start = start->euler_rates;
  } else {
    p_start = Eigen::Vector3d(options.start.x(), options.start.y(),
                              base_height(options.start.x(), options.start.y(), e_start[0]));
  }
  Eigen::Vector3d goal_xyyaw =
      options.has_goal ? options.goal : Eigen::Vector3d(p_start.x(), p_start.y(), e_start[0]);
  // Degrees of freedom the robot cannot move stay at their start value.
  if (!robot.base_dof_free[0]) goal_xyyaw.x() = p_start.x();
  if (!robot.base_dof_free[1]) goal_xyyaw.y() = p_start.y();
  if (!robot.base_dof_free[3]) goal_xyyaw.z() = e_start[0];
  const Eigen::Vector3d p_goal(goal_xyyaw.x(), goal_xyyaw.y(),
                               base_height(goal_xyyaw.x(), goal_xyyaw.y(), goal_xyyaw.z()));
  // The goal's pitch and roll follow the plane fitted (least squares, in the yawed base frame)
  // through the terrain heights under the nominal feet. With the goal on a slope or a staircase a
  // level base cannot rest there: on the stairs scenario the front feet stand 0.24 m above the
  // hind feet at the goal, more than the range-of-motion box's 2 x 0.10 m allows at zero pitch.
  auto terrain_tilt = [&](double x, double y, double yaw) {
    double sxx = 0, sxh = 0, syy = 0, syh = 0, sx = 0, sy = 0, sh = 0;
    std::vector<double> heights;
    for (const auto& leg : robot.legs) {
      const Eigen::Vector3d p = nominal_foot_world(leg, Eigen::Vector3d(x, y, 0.0), yaw);
      heights.push_back(terrain.height(p.x(), p.y()));
      sx += leg.nominal_foot.x();
      sy += leg.nominal_foot.y();
      sh += heights.back();
    }
    const double mx = sx / nf, my = sy / nf, mh = sh / nf;
    for (int f = 0; f < nf; ++f) {
      const auto& leg = robot.legs[f];
      const double h = heights[f] - mh;
      const double dx = leg.nominal_foot.x() - mx, dy = leg.nominal_foot.y() - my;
      sxx += dx * dx;
      sxh += dx * h;
      syy += dy * dy;
      syh += dy * h;
    }
    // R = Rz(yaw) Ry(pitch) Rx(roll): a positive pitch lowers the nose, a positive roll lifts
    // the left side.
    const double pitch = sxx > 1e-9 ? -std::atan(sxh / sxx) : 0.0;
    const double roll = syy > 1e-9 ? std::atan(syh / syy) : 0.0;
    return Eigen::Vector2d(pitch, roll);
  };
  const Eigen::Vector2d tilt_goal = terrain_tilt(goal_xyyaw.x(), goal_xyyaw.y(), goal_xyyaw.z());
  const Eigen::Vector3d e_goal(goal_xyyaw.z(), tilt_goal.x(), tilt_goal.y());

  // Progress from start to goal follows a minimum-jerk profile, s(u) = 10u^3 - 15u^4 + 6u^5, so
  // the guess leaves and reaches rest smoothly. (A linear ramp between resting end knots put
  // spikes of up to 8 m g into the first and last segments' accelerations.)
  auto progress = [T](double t, double* rate) {
    const double u = std::clamp(t / T, 0.0, 1.0), u2 = u * u;
    if (rate) *rate = 30.0 * u2 * (1.0 - u) * (1.0 - u) / T;
    return u2 * u * (10.0 - 15.0 * u + 6.0 * u2);
  };
  // The base height follows the terrain under the nominal feet, averaged over a window around t
  // (triangular weights): a foot crossing a step edge then lifts the guess gradually instead of
  // by a step between two knots.
  constexpr double kHeightWindow = 0.4;  // s, half width
  auto smoothed_height = [&](double t) {
    double sum = 0.0, weight = 0.0;
    constexpr int kSamples = 8;
    for (int i = -kSamples; i <= kSamples; ++i) {
      const double ti = std::clamp(t + kHeightWindow * i / kSamples, 0.0, T);
      const double w = 1.0 - std::abs(static_cast<double>(i)) / (kSamples + 1);
      const double u = progress(ti, nullptr);
      const Eigen::Vector3d p = (1 - u) * p_start + u * p_goal;
      sum += w * base_height(p.x(), p.y(), (1 - u) * e_start[0] + u * e_goal[0]);
      weight += w;
    }
    return sum / weight;
  };
  for (int k = 0; k <= S; ++k) {
    const double t = L.nominal_knot_time[k];
    double rate = 0.0;
    const double u = progress(t, &rate);
    const int b = L.base[k];
    const Eigen::Vector3d p = (1 - u) * p_start + u * p_goal;
    const Eigen::Vector3d e = (1 - u) * e_start + u * e_goal;
    const bool inner = k > 0 && k < S;
    constexpr double kDt = 1e-3;
    const double zb = k == 0 ? p_start.z() : smoothed_height(t);
    const double zd =
        inner ? (smoothed_height(t + kDt) - smoothed_height(t - kDt)) / (2 * kDt) : 0.0;
    for (int d = 0; d < 3; ++d) {
      x0[b + d] = d == 2 ? zb : p[d];
      x0[b + 3 + d] = d == 2 ? zd : rate * (p_goal[d] - p_start[d]);
      x0[b + 6 + d] = e[d];
      x0[b + 9 + d] = rate * (e_goal[d] - e_start[d]);
    }
  }
  return {p_start, e_start, v_start, r_start, p_goal, e_goal};
}

void fix_base_boundary(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables) {
  const Layout& L = in.layout;
  const int S = L.num_segments;
  const Eigen::Vector3d &p_start = boundary.start_position, &e_start = boundary.start_euler,
                        &v_start = boundary.start_velocity, &r_start = boundary.start_euler_rates,
                        &p_goal = boundary.goal_position, &e_goal = boundary.goal_euler;
  auto fix = [&](int i, double v) { variables->fix(i, v); };
  {
    const int b = L.base[0];
    for (int d = 0; d < 3; ++d) {
      fix(b + d, p_start[d]);
      fix(b + 3 + d, v_start[d]);
      fix(b + 6 + d, e_start[d]);
      fix(b + 9 + d, r_start[d]);
    }
    const int g = L.base[S];
    if (in.options.has_goal) {
      fix(g + 0, p_goal.x());
      fix(g + 1, p_goal.y());
      fix(g + 6, e_goal[0]);
    }
    fix(g + 7, e_goal[1]);
    fix(g + 8, e_goal[2]);
    for (int d = 0; d < 3; ++d) {
      fix(g + 3 + d, 0.0);
      fix(g + 9 + d, 0.0);
    }
  }
  for (int k = 0; k <= S; ++k) {
    const int b = L.base[k];
    for (int d = 0; d < 3; ++d) {
      if (!in.robot.base_dof_free[d]) {
        fix(b + d, p_start[d]);
        fix(b + 3 + d, 0.0);
      }
      // euler order yaw, pitch, roll = dof 3, 4, 5
      if (!in.robot.base_dof_free[3 + d]) {
        fix(b + 6 + d, e_start[d]);
        fix(b + 9 + d, 0.0);
      }
    }
  }
}

}  // namespace terrastride::planner::initialization
