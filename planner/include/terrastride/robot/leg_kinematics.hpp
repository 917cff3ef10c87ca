// Kinematics, dynamics and exact force polytopes of one 3-DoF HAA-HFE-KFE leg, in the base frame.
#pragma once

#include <Eigen/Core>
#include <array>
#include <optional>
#include <string>

#include "terrastride/robot/robot_model.hpp"

namespace terrastride::robot {

using Vector3 = Eigen::Vector3d;
using Matrix3 = Eigen::Matrix3d;

// Forward kinematics: foot centre position in the base frame.
Vector3 foot_position(const LegModel& leg, const Vector3& q);

// Positions of the HFE joint and of the knee (KFE joint) in the base frame (the knee is the
// planner's, geometry.hpp's knee_in_base).
Vector3 hfe_position(const LegModel& leg, const Vector3& q);
Vector3 knee_position(const LegModel& leg, const Vector3& q);

// 3x3 foot Jacobian d(foot)/dq in the base frame.
Matrix3 foot_jacobian(const LegModel& leg, const Vector3& q);

// The leg's joint frames in the base frame at joint angles q: joint i's origin, the orientation
// of the link it moves (the frame its LinkInertia is given in) and its axis; and the foot centre.
struct LegFrames {
  std::array<Vector3, 3> origin;
  std::array<Matrix3, 3> rotation;
  std::array<Vector3, 3> axis;
  Vector3 foot = Vector3::Zero();
};
LegFrames leg_frames(const LegModel& leg, const Vector3& q);

// The general leg's inverse kinematics (LegShape::general): damped Newton (Levenberg-Marquardt)
// on the forward kinematics from several starts across the joint ranges; of the answers that
// reach the foot, the one within the joint ranges nearest the middle of the ranges. A foot out of
// reach gets the closest configuration found; `residual` (when given) receives its distance (m).
Vector3 general_leg_angles(const LegModel& leg, const Vector3& foot_in_base, double* residual);

enum class IkStatus { ok, unreachable, outside_joint_limits };

struct IkResult {
  IkStatus status = IkStatus::unreachable;
  Vector3 q = Vector3::Zero();  // filled also when outside the joint limits
  std::string message;          // why it failed, naming the leg and the position
  bool ok() const { return status == IkStatus::ok; }
};

// Inverse kinematics on the leg's knee branch: the planner's (geometry.hpp; closed form for the
// in-plane and lateral-offset legs, the numeric solve otherwise), with a foot out of reach
// reported as unreachable. A solution outside the joint range is returned with status
// outside_joint_limits.
IkResult inverse_kinematics(const LegModel& leg, const Vector3& foot_in_base);

// Joint-space dynamics of the leg on a fixed base: tau = M(q) qdd + c(q, qd) + g(q) - J^T f,
// where f is the force the ground exerts on the foot, expressed in the base frame, and
// `gravity_base` is the gravity vector in the base frame (for example (0, 0, -9.81) when level).
struct LegDynamicsTerms {
  Matrix3 mass_matrix = Matrix3::Zero();
  Vector3 coriolis = Vector3::Zero();  // c(q, qd)
  Vector3 gravity = Vector3::Zero();   // g(q)
};

// Recursive Newton-Euler inverse dynamics: joint torques for q, qd, qdd with no contact force.
Vector3 inverse_dynamics(const LegModel& leg, const Vector3& q, const Vector3& qd,
                         const Vector3& qdd, const Vector3& gravity_base);

LegDynamicsTerms dynamics_terms(const LegModel& leg, const Vector3& q, const Vector3& qd,
                                const Vector3& gravity_base);

// Joint torques needed along a motion with a contact force (ground on foot, base frame).
Vector3 joint_torques(const LegModel& leg, const Vector3& q, const Vector3& qd, const Vector3& qdd,
                      const Vector3& foot_force_base, const Vector3& gravity_base);

// Exact force polytope at a configuration: P = { f : |J_i^T f| <= tau_i }, i.e. the six
// half-spaces n^T f <= d with n = +-J_i/|J_i|, d = tau_i/|J_i| (J_i the i-th column of J).
struct ForcePolytope {
  std::array<Vector3, 6> normals;  // unit; rows 2i and 2i+1 are +-J_i/|J_i|
  std::array<double, 6> offsets{};
  std::array<Vector3, 8> vertices;  // J^-T (s o tau), s in {+-1}^3
  // Largest |J_i^T f| / tau_i for a force f; <= 1 inside the polytope.
  double torque_ratio(const Vector3& f) const;
  Matrix3 jacobian = Matrix3::Zero();
  Vector3 torque_limit = Vector3::Zero();
};

ForcePolytope exact_force_polytope(const LegModel& leg, const Vector3& q);

}  // namespace terrastride::robot
