// The robot's geometry, defined once for the planner's constraint pieces (any scalar type, so the
// same code gives values and automatic derivatives) and for the post-hoc checks (double): the base
// orientation from ZYX Euler angles, a leg's inverse kinematics and knee, and the part of the shin
// next to the foot that the shin models leave out. The checks thereby judge a plan with the
// planner's own geometry. Leg geometry as in docs/design.md §4.2 and robot_model.hpp (LegModel).
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <type_traits>

#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::robot {

template <class T>
using Vector3T = Eigen::Matrix<T, 3, 1>;

// R = Rz(yaw) Ry(pitch) Rx(roll) for euler = (yaw, pitch, roll): base frame to world frame.
template <class T>
Eigen::Matrix<T, 3, 3> rotation_zyx(const Vector3T<T>& e) {
  using std::cos;
  using std::sin;
  const T cy = cos(e[0]), sy = sin(e[0]), cp = cos(e[1]), sp = sin(e[1]), cr = cos(e[2]),
          sr = sin(e[2]);
  Eigen::Matrix<T, 3, 3> R;
  R << cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, sy * cp, sy * sp * sr + cy * cr,
      sy * sp * cr - cy * sr, -sp, cp * sr, cp * cr;
  return R;
}

// The value of a scalar: itself for double, .value() for an automatic-derivative scalar.
template <class T>
double scalar_value(const T& v) {
  if constexpr (std::is_arithmetic_v<T>)
    return static_cast<double>(v);
  else
    return v.value();
}

// Rotation by `angle` about the unit axis `a` (Rodrigues), for any scalar type.
template <class T>
Eigen::Matrix<T, 3, 3> axis_rotation(const Eigen::Vector3d& a, const T& angle) {
  using std::cos;
  using std::sin;
  const T c = cos(angle), s = sin(angle);
  const T v = 1.0 - c;
  Eigen::Matrix<T, 3, 3> R;
  R << c + a.x() * a.x() * v, a.x() * a.y() * v - a.z() * s, a.x() * a.z() * v + a.y() * s,
      a.y() * a.x() * v + a.z() * s, c + a.y() * a.y() * v, a.y() * a.z() * v - a.x() * s,
      a.z() * a.x() * v - a.y() * s, a.z() * a.y() * v + a.x() * s, c + a.z() * a.z() * v;
  return R;
}

// The general leg's joints and foot in the base frame at joint angles q (robot_model.hpp,
// LegModel): foot = o + R0 (d0 + R1 (d1 + R2 d2)).
template <class T>
struct LegPoints {
  Vector3T<T> hfe, knee, foot;
};
template <class T>
LegPoints<T> general_leg_points(const LegModel& leg, const Vector3T<T>& q) {
  const Eigen::Matrix<T, 3, 3> R0 = axis_rotation<T>(leg.joint_axis[0], q[0]);
  const Eigen::Matrix<T, 3, 3> R01 = R0 * axis_rotation<T>(leg.joint_axis[1], q[1]);
  const Eigen::Matrix<T, 3, 3> R012 = R01 * axis_rotation<T>(leg.joint_axis[2], q[2]);
  LegPoints<T> p;
  p.hfe = leg.haa_origin.cast<T>() + R0 * leg.joint_offset[0].cast<T>();
  p.knee = p.hfe + R01 * leg.joint_offset[1].cast<T>();
  p.foot = p.knee + R012 * leg.joint_offset[2].cast<T>();
  return p;
}

// A joint angle moved by whole turns into [lo, hi] when that is possible (a URDF range may reach
// beyond +-pi; the closed forms answer in (-pi, pi]).
template <class T>
T into_joint_range(T q, double lo, double hi) {
  constexpr double kTurn = 2.0 * M_PI;
  if (q < lo && q + kTurn <= hi) return q + kTurn;
  if (q > hi && q - kTurn >= lo) return q - kTurn;
  return q;
}

// Closed-form inverse kinematics of the lateral_offset leg (HAA about +-x, HFE and KFE about
// +-y, any offsets; robot_model.hpp, LegShape). In the HAA joint's frame the foot's lateral
// coordinate is the constant w = d0.y + d1.y + d2.y, so HAA turns (w, u_z) onto the foot's (y, z)
// with u_z = -sqrt(y^2 + z^2 - w^2) (the foot below the HAA axis); HFE and KFE then form a planar
// two-link chain in x-z from the HFE joint, solved on the leg's knee branch. `reach_excess`
// (when given) receives how far the foot lies beyond reach (> 0: unreachable; the answer is then
// the stretched or folded leg towards it, finite and differentiable for the planner's rows).
template <class T>
Vector3T<T> lateral_offset_joint_angles(const LegModel& leg, const Vector3T<T>& foot_in_base,
                                        double* reach_excess = nullptr) {
  using std::acos;
  using std::atan2;
  using std::sqrt;
  const Eigen::Vector3d &d0 = leg.joint_offset[0], &d1 = leg.joint_offset[1],
                        &d2 = leg.joint_offset[2];
  const double s0 = leg.joint_axis[0].x(), s1 = leg.joint_axis[1].y(), s2 = leg.joint_axis[2].y();
  const Vector3T<T> v = foot_in_base - leg.haa_origin.cast<T>();
  const double w = d0.y() + d1.y() + d2.y();
  double excess = 0.0;
  T h2 = v[1] * v[1] + v[2] * v[2] - w * w;
  constexpr double kMinH2 = 1e-10;
  if (h2 < kMinH2) {
    excess = std::max(excess, std::sqrt(w * w) - std::sqrt(std::max(0.0, scalar_value(h2) + w * w)));
    h2 = T(kMinH2);
  }
  const T uz = -sqrt(h2);
  const T theta0 = atan2(w * v[2] - uz * v[1], w * v[1] + uz * v[2]);
  const T px = v[0] - d0.x(), pz = uz - d0.z();
  const double a = d1.x() * d2.x() + d1.z() * d2.z(), b = d1.x() * d2.z() - d1.z() * d2.x();
  const double r = std::sqrt(a * a + b * b), phi = std::atan2(b, a);
  const double n1 = d1.x() * d1.x() + d1.z() * d1.z(), n2 = d2.x() * d2.x() + d2.z() * d2.z();
  T c = (px * px + pz * pz - n1 - n2) / (2.0 * r);
  constexpr double kMaxCos = 1.0 - 1e-6;
  const double c_value = scalar_value(c);
  if (c_value > 1.0 + 1e-12 || c_value < -1.0 - 1e-12) {
    const double dist = std::sqrt(scalar_value(px * px + pz * pz));
    const double reach = std::sqrt(n1 + n2 + 2.0 * r), fold = std::sqrt(std::max(0.0, n1 + n2 - 2.0 * r));
    excess = std::max(excess, c_value > 1.0 ? dist - reach : fold - dist);
  }
  if (c > kMaxCos) c = T(kMaxCos);
  if (c < -kMaxCos) c = T(-kMaxCos);
  const double sigma = s2 * static_cast<double>(leg.knee_sign);
  const T theta2 = phi + sigma * acos(c);
  using std::cos;
  using std::sin;
  const T qx = d1.x() + d2.x() * cos(theta2) + d2.z() * sin(theta2);
  const T qz = d1.z() - d2.x() * sin(theta2) + d2.z() * cos(theta2);
  const T theta1 = atan2(px * qz - pz * qx, px * qx + pz * qz);
  if (reach_excess) *reach_excess = excess;
  Vector3T<T> q(s0 * theta0, s1 * theta1, s2 * theta2);
  for (int i = 0; i < 3; ++i) q[i] = into_joint_range<T>(q[i], leg.q_min[i], leg.q_max[i]);
  return q;
}

// Inverse kinematics of the general leg for any scalar type: the damped Newton solve in double
// (leg_kinematics.cpp, general_leg_angles), then one Newton step in T, which carries the exact
// first derivatives dq/dfoot = J^-1 (the planner's rows need no more).
template <class T>
Vector3T<T> general_joint_angles(const LegModel& leg, const Vector3T<T>& foot_in_base) {
  const Eigen::Vector3d p(scalar_value(foot_in_base[0]), scalar_value(foot_in_base[1]),
                          scalar_value(foot_in_base[2]));
  const Eigen::Vector3d q = general_leg_angles(leg, p, nullptr);
  const Eigen::Matrix3d jinv = foot_jacobian(leg, q).inverse();
  Vector3T<T> dp;
  for (int i = 0; i < 3; ++i) dp[i] = foot_in_base[i] - p[i];
  Vector3T<T> out;
  for (int i = 0; i < 3; ++i)
    out[i] = q[i] + jinv(i, 0) * dp[0] + jinv(i, 1) * dp[1] + jinv(i, 2) * dp[2];
  return out;
}

// Inverse kinematics of the in-plane leg (HyQ), step 1: the foot at `foot_in_base` seen from the leg. gamma is the angle of
// the plane the HAA joint turns the leg into, (x, z) the foot in that plane relative to the HFE
// joint, and cos_knee the cosine of the knee angle that puts the foot at that distance (outside
// [-1, 1]: the foot is out of reach).
template <class T>
struct LegPlane {
  T gamma, x, z, cos_knee;
};
template <class T>
LegPlane<T> leg_plane(const LegModel& leg, const Vector3T<T>& foot_in_base) {
  using std::atan2;
  using std::sqrt;
  const Vector3T<T> v = foot_in_base - leg.haa_origin.cast<T>();
  LegPlane<T> p;
  p.gamma = atan2(v[1], -v[2]);
  const T rho = sqrt(v[1] * v[1] + v[2] * v[2]);
  p.x = v[0];
  p.z = -(rho - leg.l0);
  p.cos_knee =
      (p.x * p.x + p.z * p.z - leg.l1 * leg.l1 - leg.l2 * leg.l2) / (2.0 * leg.l1 * leg.l2);
  return p;
}

// Inverse kinematics, step 2: the joint angles (HAA, HFE, KFE) on the leg's knee branch for the
// knee cosine `cos_knee` (within [-1, 1]).
template <class T>
Vector3T<T> leg_angles(const LegModel& leg, const LegPlane<T>& p, const T& cos_knee) {
  using std::acos;
  using std::atan2;
  using std::cos;
  using std::sin;
  const T qK = static_cast<double>(leg.knee_sign) * acos(cos_knee);
  const T qH = atan2(-p.x, -p.z) - atan2(leg.l2 * sin(qK), leg.l1 + leg.l2 * cos(qK));
  return Vector3T<T>(-static_cast<double>(leg.side) * p.gamma, qH, qK);
}

// The joint angles of `leg` for the foot at `foot_in_base`, for any scalar type. A foot beyond
// reach (the range-of-motion box allows a little) gets the stretched knee's angles, so that a
// constraint row stays finite and differentiable there. (inverse_kinematics in leg_kinematics.hpp
// reports such a foot as unreachable instead.)
template <class T>
Vector3T<T> leg_joint_angles(const LegModel& leg, const Vector3T<T>& foot_in_base) {
  if (leg.shape == LegShape::lateral_offset)
    return lateral_offset_joint_angles<T>(leg, foot_in_base);
  if (leg.shape == LegShape::general) return general_joint_angles<T>(leg, foot_in_base);
  const LegPlane<T> p = leg_plane<T>(leg, foot_in_base);
  T c = p.cos_knee;
  if (c > 1.0 - 1e-6) c = T(1.0 - 1e-6);
  if (c < -1.0 + 1e-6) c = T(-1.0 + 1e-6);
  return leg_angles<T>(leg, p, c);
}

// The knee (the KFE joint) in the base frame at joint angles q.
template <class T>
Vector3T<T> knee_in_base(const LegModel& leg, const Vector3T<T>& q) {
  using std::cos;
  using std::sin;
  if (leg.shape != LegShape::in_plane) return general_leg_points<T>(leg, q).knee;
  const T gamma = -static_cast<double>(leg.side) * q[0];
  const T ky = T(0.0), kz = -leg.l0 - leg.l1 * cos(q[1]), kx = -leg.l1 * sin(q[1]);
  const T cg = cos(gamma), sg = sin(gamma);
  return Vector3T<T>(leg.haa_origin.x() + kx, leg.haa_origin.y() + cg * ky - sg * kz,
                     leg.haa_origin.z() + sg * ky + cg * kz);
}

// The trunk box's corner k (0..7) in the base frame: bit 0 of k picks +x (set) or -x, bit 1 +y or
// -y, bit 2 +z or -z. Corners 0-3 are the bottom face.
inline Eigen::Vector3d trunk_corner_in_base(const TrunkBox& box, int k) {
  const Eigen::Vector3d h = box.half_size();
  return box.center + Eigen::Vector3d((k & 1) ? h.x() : -h.x(), (k & 2) ? h.y() : -h.y(),
                                      (k & 4) ? h.z() : -h.z());
}

// The trunk box's corner k in the world for the base at `base` with ZYX Euler angles `euler`
// (yaw, pitch, roll), for any scalar type (the planner's trunk clearance rows differentiate it).
template <class T>
Vector3T<T> trunk_corner_world(const TrunkBox& box, int k, const Vector3T<T>& base,
                               const Vector3T<T>& euler) {
  return base + rotation_zyx<T>(euler) * trunk_corner_in_base(box, k).cast<T>();
}

// The trunk box's centre in the world (its axes are the base's: rotation_zyx(euler)).
template <class T>
Vector3T<T> trunk_center_world(const TrunkBox& box, const Vector3T<T>& base,
                               const Vector3T<T>& euler) {
  return base + rotation_zyx<T>(euler) * box.center.cast<T>();
}

// The HFE joint (the thigh's upper end) in the base frame at joint angles q: the HAA joint turns
// the leg's plane about the base's x axis, and the HFE axis lies l0 down that plane.
template <class T>
Vector3T<T> hfe_in_base(const LegModel& leg, const Vector3T<T>& q) {
  using std::cos;
  using std::sin;
  if (leg.shape != LegShape::in_plane) return general_leg_points<T>(leg, q).hfe;
  const T gamma = -static_cast<double>(leg.side) * q[0];
  return Vector3T<T>(T(leg.haa_origin.x()), leg.haa_origin.y() + sin(gamma) * leg.l0,
                     leg.haa_origin.z() - cos(gamma) * leg.l0);
}

// The shin's part next to the foot point that stands on the ground by design, and that the shin
// models leave out (the planner's shin sets and the post-hoc capsule check): the foot sphere (2
// foot radii from the contact point to its top), the shin's end cap (its radius) and `margin`.
constexpr double kShinExclusionMargin = 0.01;  // m
inline double shin_exclusion(const RobotModel& robot, const LegModel& leg,
                             double margin = kShinExclusionMargin) {
  return 2.0 * robot.foot_radius + leg.shin_radius + margin;
}

}  // namespace terrastride::robot
