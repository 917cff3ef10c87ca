// Trajectories built in the tests, so the checks are tested without the planner.
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <functional>
#include <string>

#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::collision::test {

inline robot::RobotModel hyq() {
  return robot::load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml");
}

// The robot standing still in its nominal stance with the base at `base` (level unless `euler`),
// every foot in contact carrying m g / n_legs straight up, for `duration` s at `dt`.
inline planner::Trajectory standing(const robot::RobotModel& model, double duration = 0.2,
                                    double dt = 0.002,
                                    const Eigen::Vector3d& base = Eigen::Vector3d(0, 0, 0.58),
                                    const Eigen::Vector3d& euler = Eigen::Vector3d::Zero()) {
  planner::Trajectory traj;
  traj.robot = model.name;
  traj.gait = "stand";
  traj.duration = duration;
  traj.sample_dt = dt;
  for (const auto& leg : model.legs) traj.feet.push_back(leg.name);
  const Eigen::Matrix3d rot = rotation_zyx(euler);
  const int n = static_cast<int>(std::lround(duration / dt)) + 1;
  for (int k = 0; k < n; ++k) {
    planner::TrajectorySample s;
    s.t = k * dt;
    s.base.position = base;
    s.base.euler_zyx = euler;
    for (const auto& leg : model.legs) {
      planner::FootState f;
      f.position = base + rot * leg.nominal_foot;
      f.force = Eigen::Vector3d(0, 0, model.mass * 9.81 / model.legs.size());
      f.contact = true;
      s.feet.push_back(f);
    }
    traj.samples.push_back(s);
  }
  return traj;
}

// Moves leg `leg` along joint angles q(t) (with q̇(t)) while the base follows `base_pose(t)` with
// constant linear velocity v and yaw rate w: foot positions and world velocities consistent with
// the kinematics, so the check's q̇ and q̈ can be compared with the analytic ones.
struct BaseMotion {
  Eigen::Vector3d position0 = Eigen::Vector3d(0, 0, 0.58);
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
  double yaw_rate = 0.0;
};

inline void drive_leg(const robot::RobotModel& model, planner::Trajectory& traj, int leg_index,
                      const std::function<Eigen::Vector3d(double)>& q,
                      const std::function<Eigen::Vector3d(double)>& qd, const BaseMotion& motion) {
  const auto& leg = model.legs[leg_index];
  for (auto& s : traj.samples) {
    const double t = s.t;
    s.base.position = motion.position0 + motion.velocity * t;
    s.base.linear_velocity = motion.velocity;
    s.base.euler_zyx = Eigen::Vector3d(motion.yaw_rate * t, 0, 0);
    s.base.angular_velocity = Eigen::Vector3d(0, 0, motion.yaw_rate);
    const Eigen::Matrix3d rot = rotation_zyx(s.base.euler_zyx);
    for (size_t i = 0; i < model.legs.size(); ++i) {
      auto& f = s.feet[i];
      if (static_cast<int>(i) == leg_index) {
        const Eigen::Vector3d p_b = robot::foot_position(leg, q(t));
        const Eigen::Vector3d v_b = robot::foot_jacobian(leg, q(t)) * qd(t);
        f.position = s.base.position + rot * p_b;
        f.velocity = s.base.linear_velocity + s.base.angular_velocity.cross(rot * p_b) + rot * v_b;
        f.force.setZero();
        f.contact = false;
      } else {
        const Eigen::Vector3d p_b = model.legs[i].nominal_foot;
        f.position = s.base.position + rot * p_b;
        f.velocity = s.base.linear_velocity + s.base.angular_velocity.cross(rot * p_b);
      }
    }
  }
}

// A synthetic crawl of `duration` s at `dt`: the base moves 1 m along +x at constant speed while
// the legs swing one at a time (LH, LF, RH, RF) in `cycles` cycles, each foot landing on
// `height(x, y)` and lifting 0.12 m above the higher of its lift-off and touch-down heights. It is
// kinematically smooth, not dynamically consistent: it exercises the checks, not the planner.
inline planner::Trajectory synthetic_crawl(const robot::RobotModel& model,
                                           const std::function<double(double, double)>& height,
                                           double duration = 11.0, double dt = 0.002,
                                           int cycles = 3) {
  planner::Trajectory traj;
  traj.robot = model.name;
  traj.gait = "crawl";
  traj.duration = duration;
  traj.sample_dt = dt;
  for (const auto& leg : model.legs) traj.feet.push_back(leg.name);
  const double distance = 1.0;
  const double speed = distance / duration;
  const int order[4] = {2, 0, 3, 1};  // LH, LF, RH, RF
  const double swing_time = duration / (cycles * 4.0) * 0.8;
  const double step = distance / cycles;
  const int n = static_cast<int>(std::lround(duration / dt)) + 1;
  for (int k = 0; k < n; ++k) {
    const double t = k * dt;
    planner::TrajectorySample s;
    s.t = t;
    const double bx = speed * t;
    for (size_t i = 0; i < model.legs.size(); ++i) {
      const auto& leg = model.legs[i];
      int slot = 0;
      while (order[slot] != static_cast<int>(i)) ++slot;
      // Steps taken so far and the phase within the current swing, if any.
      int steps = 0;
      double phase = -1;
      for (int c = 0; c < cycles; ++c) {
        const double t0 = (c * 4 + slot + 0.1) * duration / (cycles * 4.0);
        if (t >= t0 + swing_time) {
          ++steps;
        } else if (t >= t0) {
          phase = (t - t0) / swing_time;
        }
      }
      const double x0 = leg.nominal_foot.x() + steps * step;
      const double y = leg.nominal_foot.y();
      planner::FootState f;
      if (phase < 0) {
        f.position = Eigen::Vector3d(x0, y, height(x0, y));
        f.contact = true;
        f.force = Eigen::Vector3d(0, 0, model.mass * 9.81 / 3.0);
      } else {
        const double x1 = x0 + step;
        const double s_ = 0.5 - 0.5 * std::cos(M_PI * phase);
        const double sd = 0.5 * M_PI * std::sin(M_PI * phase) / swing_time;
        const double z0 = height(x0, y), z1 = height(x1, y);
        const double lift = 0.12 + std::max(z0, z1);
        const double zb = z0 + (z1 - z0) * s_;
        const double bump = (lift - std::max(z0, z1) + std::abs(z1 - z0)) * std::sin(M_PI * phase);
        f.position = Eigen::Vector3d(x0 + step * s_, y, zb + bump);
        f.velocity = Eigen::Vector3d(step * sd, 0, 0);
        f.contact = false;
      }
      s.feet.push_back(f);
    }
    // The base rides at the nominal height above the mean foot height.
    double mean_z = 0;
    for (const auto& f : s.feet) mean_z += f.position.z() / s.feet.size();
    s.base.position = Eigen::Vector3d(bx, 0, mean_z + model.nominal_base_height);
    s.base.linear_velocity = Eigen::Vector3d(speed, 0, 0);
    traj.samples.push_back(s);
  }
  return traj;
}

}  // namespace terrastride::collision::test
