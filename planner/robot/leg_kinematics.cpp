#include "terrastride/robot/leg_kinematics.hpp"

#include "terrastride/robot/geometry.hpp"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <sstream>

namespace terrastride::robot {
namespace {

Matrix3 rot_x(double a) { return Eigen::AngleAxisd(a, Vector3::UnitX()).toRotationMatrix(); }
Matrix3 rot_y(double a) { return Eigen::AngleAxisd(a, Vector3::UnitY()).toRotationMatrix(); }

// Joint frames of the chain in the base frame: origin, orientation and joint axis of HAA, HFE, KFE.
struct ChainFrames {
  std::array<Vector3, 3> origin;
  std::array<Matrix3, 3> rotation;
  std::array<Vector3, 3> axis;
  Vector3 foot;
};

ChainFrames chain_frames(const LegModel& leg, const Vector3& q) {
  ChainFrames fr;
  // HAA turns by -side*qA about x, i.e. by qA about the axis -side*x.
  fr.origin[0] = leg.haa_origin;
  fr.rotation[0] = rot_x(-leg.side * q[0]);
  fr.axis[0] = -leg.side * Vector3::UnitX();
  fr.origin[1] = fr.origin[0] + fr.rotation[0] * Vector3(0, 0, -leg.l0);
  fr.rotation[1] = fr.rotation[0] * rot_y(q[1]);
  fr.axis[1] = fr.rotation[0] * Vector3::UnitY();
  fr.origin[2] = fr.origin[1] + fr.rotation[1] * Vector3(0, 0, -leg.l1);
  fr.rotation[2] = fr.rotation[1] * rot_y(q[2]);
  fr.axis[2] = fr.axis[1];
  fr.foot = fr.origin[2] + fr.rotation[2] * Vector3(0, 0, -leg.l2);
  return fr;
}

std::string format_vec(const Vector3& v) {
  std::ostringstream s;
  s.precision(4);
  s << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return s.str();
}

}  // namespace

Vector3 foot_position(const LegModel& leg, const Vector3& q) { return chain_frames(leg, q).foot; }
Vector3 hfe_position(const LegModel& leg, const Vector3& q) {
  return chain_frames(leg, q).origin[1];
}
Vector3 knee_position(const LegModel& leg, const Vector3& q) {
  return knee_in_base<double>(leg, q);  // the knee the planner's shin_ik set uses
}

Matrix3 foot_jacobian(const LegModel& leg, const Vector3& q) {
  const ChainFrames fr = chain_frames(leg, q);
  Matrix3 jac;
  for (int i = 0; i < 3; ++i) jac.col(i) = fr.axis[i].cross(fr.foot - fr.origin[i]);
  return jac;
}

IkResult inverse_kinematics(const LegModel& leg, const Vector3& foot_in_base) {
  IkResult res;
  if (!foot_in_base.allFinite()) {
    res.message = "leg " + leg.name + ": foot position is not finite";
    return res;
  }
  // The planner's IK equations (geometry.hpp). The planner's rows clamp a foot beyond reach to the
  // stretched knee; here it is reported.
  const LegPlane<double> plane = leg_plane<double>(leg, foot_in_base);
  const double x = plane.x, z = plane.z, cos_knee = plane.cos_knee;
  // A hair of slack absorbs round-off at full extension; anything beyond is out of reach.
  constexpr double kSlack = 1e-12;
  if (cos_knee > 1 + kSlack || cos_knee < -1 - kSlack) {
    res.status = IkStatus::unreachable;
    res.message = "leg " + leg.name + ": foot " + format_vec(foot_in_base) +
                  " (base frame) is out of reach (hip-foot distance " +
                  std::to_string(std::hypot(x, z)) + " m, leg reaches " +
                  std::to_string(std::abs(leg.l1 - leg.l2)) + ".." +
                  std::to_string(leg.l1 + leg.l2) + " m)";
    return res;
  }
  res.q = leg_angles<double>(leg, plane, std::clamp(cos_knee, -1.0, 1.0));
  static const char* kJointNames[3] = {"HAA", "HFE", "KFE"};
  for (int i = 0; i < 3; ++i) {
    if (res.q[i] < leg.q_min[i] - 1e-9 || res.q[i] > leg.q_max[i] + 1e-9) {
      res.status = IkStatus::outside_joint_limits;
      std::ostringstream s;
      s << "leg " << leg.name << ": foot " << format_vec(foot_in_base) << " needs " << kJointNames[i]
        << " = " << res.q[i] * 180.0 / M_PI << " deg, outside [" << leg.q_min[i] * 180.0 / M_PI
        << ", " << leg.q_max[i] * 180.0 / M_PI << "] deg";
      res.message = s.str();
      return res;
    }
  }
  res.status = IkStatus::ok;
  return res;
}

Vector3 inverse_dynamics(const LegModel& leg, const Vector3& q, const Vector3& qd,
                         const Vector3& qdd, const Vector3& gravity_base) {
  const ChainFrames fr = chain_frames(leg, q);
  // Forward pass (base frame coordinates). Gravity enters as an upward acceleration of the base.
  std::array<Vector3, 3> omega, omega_dot, acc_origin;
  Vector3 w = Vector3::Zero(), wd = Vector3::Zero(), a = -gravity_base;
  for (int i = 0; i < 3; ++i) {
    if (i > 0) {
      const Vector3 d = fr.origin[i] - fr.origin[i - 1];
      a = a + omega_dot[i - 1].cross(d) + omega[i - 1].cross(omega[i - 1].cross(d));
    }
    acc_origin[i] = a;
    const Vector3 w_new = w + fr.axis[i] * qd[i];
    wd = wd + fr.axis[i] * qdd[i] + w.cross(fr.axis[i] * qd[i]);
    w = w_new;
    omega[i] = w;
    omega_dot[i] = wd;
  }
  // Backward pass: force and moment (about each joint origin) transmitted into link i.
  Vector3 tau;
  Vector3 f_next = Vector3::Zero(), n_next = Vector3::Zero();
  for (int i = 2; i >= 0; --i) {
    const LinkInertia& link = leg.links[i];
    const Vector3 c = fr.rotation[i] * link.com;  // CoM relative to the joint origin
    const Vector3 a_c = acc_origin[i] + omega_dot[i].cross(c) + omega[i].cross(omega[i].cross(c));
    const Matrix3 inertia_base = fr.rotation[i] * link.inertia * fr.rotation[i].transpose();
    const Vector3 force = link.mass * a_c;
    const Vector3 moment = inertia_base * omega_dot[i] + omega[i].cross(inertia_base * omega[i]);
    Vector3 n = moment + c.cross(force) + n_next;
    if (i < 2) n += (fr.origin[i + 1] - fr.origin[i]).cross(f_next);
    const Vector3 f = force + f_next;
    tau[i] = fr.axis[i].dot(n);
    f_next = f;
    n_next = n;
  }
  return tau;
}

LegDynamicsTerms dynamics_terms(const LegModel& leg, const Vector3& q, const Vector3& qd,
                                const Vector3& gravity_base) {
  LegDynamicsTerms terms;
  const Vector3 zero = Vector3::Zero();
  terms.gravity = inverse_dynamics(leg, q, zero, zero, gravity_base);
  terms.coriolis = inverse_dynamics(leg, q, qd, zero, zero);
  for (int j = 0; j < 3; ++j)
    terms.mass_matrix.col(j) = inverse_dynamics(leg, q, zero, Vector3::Unit(j), zero);
  return terms;
}

Vector3 joint_torques(const LegModel& leg, const Vector3& q, const Vector3& qd, const Vector3& qdd,
                      const Vector3& foot_force_base, const Vector3& gravity_base) {
  return inverse_dynamics(leg, q, qd, qdd, gravity_base) -
         foot_jacobian(leg, q).transpose() * foot_force_base;
}

double ForcePolytope::torque_ratio(const Vector3& f) const {
  const Vector3 tau = jacobian.transpose() * f;
  return tau.cwiseAbs().cwiseQuotient(torque_limit).maxCoeff();
}

ForcePolytope exact_force_polytope(const LegModel& leg, const Vector3& q) {
  ForcePolytope poly;
  poly.jacobian = foot_jacobian(leg, q);
  poly.torque_limit = leg.torque_limit;
  for (int i = 0; i < 3; ++i) {
    const Vector3 col = poly.jacobian.col(i);
    const double norm = col.norm();
    poly.normals[2 * i] = col / norm;
    poly.normals[2 * i + 1] = -col / norm;
    poly.offsets[2 * i] = poly.offsets[2 * i + 1] = leg.torque_limit[i] / norm;
  }
  const Matrix3 jt_inv = poly.jacobian.transpose().inverse();
  for (int k = 0; k < 8; ++k) {
    const Vector3 s((k & 1) ? 1.0 : -1.0, (k & 2) ? 1.0 : -1.0, (k & 4) ? 1.0 : -1.0);
    poly.vertices[k] = jt_inv * s.cwiseProduct(leg.torque_limit);
  }
  return poly;
}

}  // namespace terrastride::robot
