// The initial guess of the feet: each stance foothold at the nominal foot under the guessed base
// (moved to the nearest usable spot), each swing a straight line between its footholds lifted
// above the terrain around it.
#include <algorithm>
#include <cmath>
#include <vector>

#include "initial_guess.hpp"
#include "terrastride/planner/foothold_planarity.hpp"

namespace terrastride::planner::initialization {

namespace {

// The guessed base's position and yaw at time t (linear between the knots around t).
void guessed_base_at(const Layout& L, const std::vector<double>& x0, double t, Eigen::Vector3d* pos,
                     double* yaw) {
  const int S = L.num_segments;
  int k = 0;
  while (k < S && L.nominal_knot_time[k + 1] < t) ++k;
  const int k1 = std::min(k + 1, S);
  const double t0 = L.nominal_knot_time[k], t1 = L.nominal_knot_time[k1];
  const double u = t1 > t0 ? std::clamp((t - t0) / (t1 - t0), 0.0, 1.0) : 0.0;
  *pos = (1 - u) * Eigen::Vector3d(x0[L.base[k]], x0[L.base[k] + 1], x0[L.base[k] + 2]) +
         u * Eigen::Vector3d(x0[L.base[k1]], x0[L.base[k1] + 1], x0[L.base[k1] + 2]);
  *yaw = (1 - u) * x0[L.base[k] + 6] + u * x0[L.base[k1] + 6];
}

}  // namespace

void guess_footholds(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables) {
  const robot::RobotModel& robot = in.robot;
  const terrain::HeightField& terrain = in.terrain;
  const ProblemOptions& options = in.options;
  const Layout& L = in.layout;
  const SrbdProblem::StartState* start = in.start;
  const std::vector<double>& x0 = variables->initial;
  const Eigen::Vector3d& p_start = boundary.start_position;
  const Eigen::Vector3d& e_start = boundary.start_euler;
  // Footholds: nominal positions under the base at the middle of each stance, on the terrain.
  for (const auto& st : L.stances) {
    Eigen::Vector3d p;
    if (st.fixed) {
      if (start) {
        p = start->foot_position[st.foot];
      } else {
        p = nominal_foot_world(robot.legs[st.foot], p_start, e_start[0]);
        p.z() = terrain.height(p.x(), p.y());
      }
      for (int d = 0; d < 3; ++d) variables->fix(st.pos_var + d, p[d]);
    } else {
      const double tm =
          0.5 * (L.nominal_knot_time[st.first_seg] + L.nominal_knot_time[st.last_seg + 1]);
      Eigen::Vector3d b;
      double yaw;
      guessed_base_at(L, x0, tm, &b, &yaw);
      p = nominal_foot_world(robot.legs[st.foot], b, yaw);
      // Start from the nearest locally planar spot (see the foothold_planarity constraint), so
      // the solver does not begin with feet on step edges, and one at a height the leg can reach
      // from the guessed base (within 1.5 times the range-of-motion box's half-height of the
      // nominal foot height): a planar trench floor 0.30 m down under the nominal foot is no
      // foothold (gap scene, 1 m goal: the hind feet started there and the solve ended infeasible).
      const double probe = options.clearance_probe, tol = 0.5 * options.foothold_planarity;
      const auto& leg = robot.legs[st.foot];
      auto usable = [&](double x, double y) {
        if (foothold_planarity_error(terrain, x, y, probe) > tol) return false;
        const double below_base = terrain.height(x, y) - b.z() - leg.nominal_foot.z();
        return std::abs(below_base) <= 1.5 * leg.range_of_motion.z();
      };
      if (probe > 0.0 && tol > 0.0 && !usable(p.x(), p.y())) {
        bool found = false;
        for (int r = 1; r <= 20 && !found; ++r)
          for (const auto& dir : {Eigen::Vector2d(1, 0), Eigen::Vector2d(-1, 0),
                                  Eigen::Vector2d(0, 1), Eigen::Vector2d(0, -1)}) {
            const Eigen::Vector2d q = p.head<2>() + 0.01 * r * dir;
            if (usable(q.x(), q.y())) {
              p.head<2>() = q;
              found = true;
              break;
            }
          }
      }
      p.z() = terrain.height(p.x(), p.y());
      for (int d = 0; d < 3; ++d) variables->initial[st.pos_var + d] = p[d];
    }
  }
}

void guess_swing_feet(const GuessInputs& in, const BaseBoundary& boundary, Variables* variables) {
  const robot::RobotModel& robot = in.robot;
  const terrain::HeightField& terrain = in.terrain;
  const ProblemOptions& options = in.options;
  const Layout& L = in.layout;
  const SrbdProblem::StartState* start = in.start;
  std::vector<double>& x0 = variables->initial;
  const int S = L.num_segments;
  const Eigen::Vector3d& p_start = boundary.start_position;
  const Eigen::Vector3d& e_start = boundary.start_euler;
  // Swing knots: straight line between the footholds, lifted by the clearance.
  for (const auto& sw : L.swings) {
    const int f = sw.foot;
    const int k0 = sw.first_seg, k1 = sw.last_seg + 1;
    Eigen::Vector3d pa, pb;
    const bool start_in_swing = L.foot_vel[f][k0] >= 0;  // knot 0 in swing
    if (start_in_swing) {
      pa = start ? start->foot_position[f] : nominal_foot_world(robot.legs[f], p_start, e_start[0]);
      if (!start) pa.z() = terrain.height(pa.x(), pa.y());
    } else {
      pa = Eigen::Vector3d(x0[L.foot_pos[f][k0]], x0[L.foot_pos[f][k0] + 1],
                           x0[L.foot_pos[f][k0] + 2]);
    }
    if (L.foot_vel[f][k1] < 0) {
      pb = Eigen::Vector3d(x0[L.foot_pos[f][k1]], x0[L.foot_pos[f][k1] + 1],
                           x0[L.foot_pos[f][k1] + 2]);
    } else {
      Eigen::Vector3d b;
      double yaw;
      guessed_base_at(L, x0, L.nominal_knot_time[k1], &b, &yaw);
      pb = nominal_foot_world(robot.legs[f], b, yaw);
      pb.z() = terrain.height(pb.x(), pb.y());
    }
    const double ta = L.nominal_knot_time[k0], tb = L.nominal_knot_time[k1];
    for (int k = k0; k <= k1; ++k) {
      if (L.foot_vel[f][k] < 0) continue;
      const double u = (L.nominal_knot_time[k] - ta) / (tb - ta);
      Eigen::Vector3d p = (1 - u) * pa + u * pb;
      // Above the highest terrain around the foot (the clearance constraint probes there too).
      double ground = std::max(pa.z(), pb.z());
      const double d = options.clearance_probe;
      for (const auto& o : {Eigen::Vector2d(0, 0), Eigen::Vector2d(d, 0), Eigen::Vector2d(-d, 0),
                            Eigen::Vector2d(0, d), Eigen::Vector2d(0, -d)})
        ground = std::max(ground, terrain.height(p.x() + o.x(), p.y() + o.y()));
      p.z() = std::max(p.z(), ground) + options.swing_clearance * 1.5;
      Eigen::Vector3d v = (pb - pa) / (tb - ta);
      if (k == 0) {
        p = pa;
        v = start ? start->foot_velocity[f] : Eigen::Vector3d::Zero();
        for (int d = 0; d < 3; ++d) {
          variables->fix(L.foot_pos[f][k] + d, p[d]);
          variables->fix(L.foot_vel[f][k] + d, v[d]);
        }
        continue;
      }
      if (k == S) v.setZero();
      for (int d = 0; d < 3; ++d) {
        x0[L.foot_pos[f][k] + d] = p[d];
        x0[L.foot_vel[f][k] + d] = v[d];
      }
    }
  }
}

}  // namespace terrastride::planner::initialization
