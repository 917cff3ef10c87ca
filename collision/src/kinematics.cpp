// Leg kinematics along a trajectory: validation, IK, joint velocities and accelerations.
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <cmath>
#include <sstream>

#include "terrastride/collision/checks.hpp"

namespace terrastride::collision {
namespace {

constexpr size_t kMaxIssues = 20;

void require_finite(const Eigen::Vector3d& v, const std::string& field) {
  if (!v.allFinite()) throw TrajectoryError(field + ": not a finite 3-vector");
}

}  // namespace

// Shared validation: every check reads the same fields, so they are checked once, here.
void validate_trajectory(const robot::RobotModel& model, const planner::Trajectory& traj) {
  if (!traj.robot.empty() && traj.robot != model.name)
    throw TrajectoryError("robot: the plan is for '" + traj.robot + "', the model is '" +
                          model.name + "'");
  if (traj.samples.empty()) throw TrajectoryError("samples: the plan has no samples");
  if (traj.feet.size() != model.legs.size())
    throw TrajectoryError("feet: " + std::to_string(traj.feet.size()) + " feet for robot " +
                          model.name + " with " + std::to_string(model.legs.size()) + " legs");
  for (size_t i = 0; i < traj.feet.size(); ++i) {
    if (traj.feet[i] != model.legs[i].name)
      throw TrajectoryError("feet[" + std::to_string(i) + "]: '" + traj.feet[i] + "' but robot " +
                            model.name + " has leg '" + model.legs[i].name + "' there");
  }
  for (size_t k = 0; k < traj.samples.size(); ++k) {
    const auto& s = traj.samples[k];
    const std::string at = "samples[" + std::to_string(k) + "]";
    if (!std::isfinite(s.t)) throw TrajectoryError(at + ".t: not a finite number");
    if (k > 0 && !(s.t > traj.samples[k - 1].t))
      throw TrajectoryError(at + ".t: times must increase (" + std::to_string(s.t) + " after " +
                            std::to_string(traj.samples[k - 1].t) + ")");
    require_finite(s.base.position, at + ".base.position");
    require_finite(s.base.euler_zyx, at + ".base.euler_zyx");
    require_finite(s.base.linear_velocity, at + ".base.linear_velocity");
    require_finite(s.base.angular_velocity, at + ".base.angular_velocity");
    require_finite(s.base.linear_acceleration, at + ".base.linear_acceleration");
    require_finite(s.base.angular_acceleration, at + ".base.angular_acceleration");
    if (s.feet.size() != model.legs.size())
      throw TrajectoryError(at + ".feet: " + std::to_string(s.feet.size()) + " entries for " +
                            std::to_string(model.legs.size()) + " legs");
    for (size_t i = 0; i < s.feet.size(); ++i) {
      const std::string f = at + ".feet[" + std::to_string(i) + "]";
      require_finite(s.feet[i].position, f + ".position");
      require_finite(s.feet[i].velocity, f + ".velocity");
      require_finite(s.feet[i].force, f + ".force");
    }
  }
}

TrajectoryKinematics leg_kinematics(const robot::RobotModel& model,
                                    const planner::Trajectory& traj) {
  validate_trajectory(model, traj);
  const size_t n = traj.samples.size();
  const size_t n_legs = model.legs.size();
  TrajectoryKinematics kin;
  kin.time.resize(n);
  kin.legs.assign(n_legs, std::vector<LegSample>(n));
  std::vector<char> unreachable(n, 0), limits(n, 0);
  // Whether q̇ came from J^-1 (false: singular J, difference q below).
  std::vector<std::vector<char>> qd_ok(n_legs, std::vector<char>(n, 0));

  for (size_t k = 0; k < n; ++k) {
    const auto& s = traj.samples[k];
    kin.time[k] = s.t;
    const Eigen::Matrix3d rt = rotation_zyx(s.base.euler_zyx).transpose();
    for (size_t i = 0; i < n_legs; ++i) {
      const auto& leg = model.legs[i];
      const auto& foot = s.feet[i];
      LegSample& ls = kin.legs[i][k];
      const Eigen::Vector3d rel = foot.position - s.base.position;
      ls.foot_base = rt * rel;
      const robot::IkResult ik = robot::inverse_kinematics(leg, ls.foot_base);
      switch (ik.status) {
        case robot::IkStatus::ok:
          ls.status = LegSampleStatus::ok;
          break;
        case robot::IkStatus::outside_joint_limits:
          ls.status = LegSampleStatus::outside_joint_limits;
          limits[k] = 1;
          break;
        case robot::IkStatus::unreachable:
          ls.status = LegSampleStatus::unreachable;
          unreachable[k] = 1;
          break;
      }
      if (!ik.ok() && kin.issues.size() < kMaxIssues)
        kin.issues.push_back({static_cast<int>(k), s.t, static_cast<int>(i), ik.message});
      if (!ls.has_q()) continue;
      ls.q = ik.q;
      // Foot velocity relative to the base, in the base frame: R^T (v_foot - v_base - w x (p - r)).
      const Eigen::Vector3d v_rel =
          rt * (foot.velocity - s.base.linear_velocity - s.base.angular_velocity.cross(rel));
      const Eigen::Matrix3d jac = robot::foot_jacobian(leg, ls.q);
      // Near a singularity (straight knee) J^-1 amplifies velocity noise into absurd q̇; the
      // finite difference of q is better conditioned there. |det J| over the product of its column
      // norms is 1 for orthogonal columns and 0 for dependent ones.
      const double volume = std::abs(jac.determinant()) /
                            (jac.col(0).norm() * jac.col(1).norm() * jac.col(2).norm() + 1e-300);
      if (volume > 1e-3) {
        ls.qd = jac.inverse() * v_rel;
        qd_ok[i][k] = 1;
      }
    }
  }
  for (size_t k = 0; k < n; ++k) {
    kin.unreachable_samples += unreachable[k];
    kin.joint_limit_samples += limits[k];
  }

  // Central differences on a possibly non-uniform time grid (one-sided at the ends and next to
  // samples without q); a lone sample between two IK failures gets zero.
  auto diff = [&](size_t i, size_t k, auto value) -> Eigen::Vector3d {
    const auto& ls = kin.legs[i];
    const bool prev = k > 0 && ls[k - 1].has_q();
    const bool next = k + 1 < n && ls[k + 1].has_q();
    if (prev && next) return (value(k + 1) - value(k - 1)) / (kin.time[k + 1] - kin.time[k - 1]);
    if (next) return (value(k + 1) - value(k)) / (kin.time[k + 1] - kin.time[k]);
    if (prev) return (value(k) - value(k - 1)) / (kin.time[k] - kin.time[k - 1]);
    return Eigen::Vector3d::Zero();
  };
  for (size_t i = 0; i < n_legs; ++i) {
    auto& ls = kin.legs[i];
    for (size_t k = 0; k < n; ++k) {
      if (ls[k].has_q() && !qd_ok[i][k]) ls[k].qd = diff(i, k, [&](size_t j) { return ls[j].q; });
    }
    for (size_t k = 0; k < n; ++k) {
      if (ls[k].has_q()) ls[k].qdd = diff(i, k, [&](size_t j) { return ls[j].qd; });
    }
  }
  return kin;
}

}  // namespace terrastride::collision
