// Joint torques along a trajectory: tau = M q̈ + c + g - J^T f (paper (21)), per leg and sample.
#include <algorithm>
#include <cmath>
#include <limits>

#include "terrastride/collision/checks.hpp"

namespace terrastride::collision {
namespace {

// |q'_i| / q'_lim_i per leg, joint and sample; q' from the kinematics (the foot velocity relative
// to the base through J^-1, as the torques use).
void check_joint_velocities(const robot::RobotModel& model, const TrajectoryKinematics& kin,
                            const TorqueOptions& options, TorqueReport* rep) {
  for (const auto& leg : model.legs)
    if (!(leg.velocity_limit.minCoeff() > 0)) return;  // no limits to check against
  rep->velocity_checked = true;
  const size_t n = kin.time.size();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<char> violating(n, 0);
  for (size_t i = 0; i < model.legs.size(); ++i) {
    const auto& leg = model.legs[i];
    LegTorqueSeries& series = rep->legs[i];
    series.velocity_ratio.assign(n, Eigen::Vector3d::Constant(nan));
    for (size_t k = 0; k < n; ++k) {
      const LegSample& ls = kin.legs[i][k];
      if (!ls.has_q()) continue;
      const Eigen::Vector3d ratio = ls.qd.cwiseAbs().cwiseQuotient(leg.velocity_limit);
      series.velocity_ratio[k] = ratio;
      bool leg_violates = false;
      for (int j = 0; j < 3; ++j) {
        series.worst_velocity_ratio[j] = std::max(series.worst_velocity_ratio[j], ratio[j]);
        if (ratio[j] > 1.0 + options.violation_tolerance) leg_violates = true;
        if (ratio[j] > rep->velocity_ratio_max || rep->velocity_worst_sample < 0) {
          rep->velocity_ratio_max = ratio[j];
          rep->velocity_worst_sample = static_cast<int>(k);
          rep->velocity_worst_leg = static_cast<int>(i);
          rep->velocity_worst_joint = j;
        }
      }
      if (leg_violates) {
        ++series.velocity_violating_samples;
        violating[k] = 1;
      }
    }
  }
  for (char v : violating) rep->velocity_violating_samples += v;
}

}  // namespace

TorqueReport check_joint_torques(const robot::RobotModel& model, const planner::Trajectory& traj,
                                 const TrajectoryKinematics& kin, const TorqueOptions& options) {
  const size_t n = traj.samples.size();
  const size_t n_legs = model.legs.size();
  if (kin.time.size() != n || kin.legs.size() != n_legs)
    throw TrajectoryError("kinematics do not belong to this trajectory (sample or leg count)");
  const double nan = std::numeric_limits<double>::quiet_NaN();
  TorqueReport rep;
  rep.time = kin.time;
  rep.legs.resize(n_legs);
  std::vector<char> violating(n, 0);

  for (size_t i = 0; i < n_legs; ++i) {
    const auto& leg = model.legs[i];
    LegTorqueSeries& series = rep.legs[i];
    series.leg = leg.name;
    series.tau.assign(n, Eigen::Vector3d::Constant(nan));
    series.ratio.assign(n, Eigen::Vector3d::Constant(nan));
    for (size_t k = 0; k < n; ++k) {
      const LegSample& ls = kin.legs[i][k];
      // IK failures are reported by the kinematics; they count as violations there, not here.
      if (!ls.has_q()) continue;
      const auto& s = traj.samples[k];
      const Eigen::Matrix3d rt = rotation_zyx(s.base.euler_zyx).transpose();
      Eigen::Vector3d g_world = options.gravity;
      if (options.include_base_acceleration) g_world -= s.base.linear_acceleration;
      // A swing foot carries no load whatever the plan's force field says.
      const Eigen::Vector3d f_base =
          s.feet[i].contact ? Eigen::Vector3d(rt * s.feet[i].force) : Eigen::Vector3d::Zero();
      const Eigen::Vector3d tau =
          robot::joint_torques(leg, ls.q, ls.qd, ls.qdd, f_base, rt * g_world);
      const Eigen::Vector3d ratio = tau.cwiseAbs().cwiseQuotient(leg.torque_limit);
      series.tau[k] = tau;
      // Mechanical power |tau_j q'_j| summed over joints, integrated with each sample's share of
      // the time (half the steps on both sides): the energy proxy of plan.json's quality block.
      const double dt = 0.5 * ((k + 1 < n ? traj.samples[k + 1].t : traj.samples[k].t) -
                               (k > 0 ? traj.samples[k - 1].t : traj.samples[k].t));
      rep.energy_proxy_J += tau.cwiseProduct(ls.qd).cwiseAbs().sum() * dt;
      series.ratio[k] = ratio;
      bool leg_violates = false;
      for (int j = 0; j < 3; ++j) {
        if (ratio[j] > series.worst_ratio[j] || series.worst_sample[j] < 0) {
          series.worst_ratio[j] = ratio[j];
          series.worst_sample[j] = static_cast<int>(k);
        }
        if (ratio[j] > 1.0 + options.violation_tolerance) leg_violates = true;
        if (ratio[j] > rep.ratio_max || rep.worst_sample < 0) {
          rep.ratio_max = ratio[j];
          rep.worst_sample = static_cast<int>(k);
          rep.worst_leg = static_cast<int>(i);
          rep.worst_joint = j;
        }
      }
      if (leg_violates) {
        ++series.violating_samples;
        violating[k] = 1;
      }
    }
  }
  for (char v : violating) rep.violating_samples += v;
  check_joint_velocities(model, kin, options, &rep);
  return rep;
}

}  // namespace terrastride::collision
