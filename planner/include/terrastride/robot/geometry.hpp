// The robot's geometry, defined once for the planner's constraint pieces (any scalar type, so the
// same code gives values and automatic derivatives) and for the post-hoc checks (double): the base
// orientation from ZYX Euler angles, a leg's inverse kinematics and knee, and the part of the shin
// next to the foot that the shin models leave out. The checks thereby judge a plan with the
// planner's own geometry. Leg geometry as in docs/design.md §4.2 and robot_model.hpp (LegModel).
#pragma once

#include <Eigen/Core>
#include <cmath>

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

// Inverse kinematics, step 1: the foot at `foot_in_base` seen from the leg. gamma is the angle of
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
