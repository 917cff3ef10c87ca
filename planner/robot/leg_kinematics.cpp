#include "terrastride/robot/leg_kinematics.hpp"

#include "terrastride/robot/geometry.hpp"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>
#include <Eigen/Cholesky>

namespace terrastride::robot {
namespace {

Matrix3 rot_x(double a) { return Eigen::AngleAxisd(a, Vector3::UnitX()).toRotationMatrix(); }
Matrix3 rot_y(double a) { return Eigen::AngleAxisd(a, Vector3::UnitY()).toRotationMatrix(); }

using ChainFrames = LegFrames;

ChainFrames chain_frames(const LegModel& leg, const Vector3& q) {
  ChainFrames fr;
  if (leg.shape != LegShape::in_plane) {
    // The general chain (robot_model.hpp, LegModel): R_i about the q = 0 axis, carried along.
    Matrix3 r = Matrix3::Identity();
    Vector3 o = leg.haa_origin;
    for (int i = 0; i < 3; ++i) {
      fr.origin[i] = o;
      fr.axis[i] = r * leg.joint_axis[i];
      r = r * Eigen::AngleAxisd(q[i], leg.joint_axis[i]).toRotationMatrix();
      fr.rotation[i] = r;
      o = o + r * leg.joint_offset[i];
    }
    fr.foot = o;
    return fr;
  }
  // The in-plane leg (HyQ), as it always was:
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

static const char* kJointNames[3] = {"HAA", "HFE", "KFE"};

// Status and message for joint angles q that reach the foot (or not, by `excess` m).
IkResult finish_ik(const LegModel& leg, const Vector3& foot_in_base, const Vector3& q,
                   double excess) {
  IkResult res;
  res.q = q;
  if (excess > 1e-9) {
    res.status = IkStatus::unreachable;
    std::ostringstream s;
    s << "leg " << leg.name << ": foot " << format_vec(foot_in_base)
      << " (base frame) is out of reach (" << excess << " m beyond the leg's reach)";
    res.message = s.str();
    return res;
  }
  for (int i = 0; i < 3; ++i) {
    if (q[i] < leg.q_min[i] - 1e-9 || q[i] > leg.q_max[i] + 1e-9) {
      res.status = IkStatus::outside_joint_limits;
      std::ostringstream s;
      s << "leg " << leg.name << ": foot " << format_vec(foot_in_base) << " needs "
        << kJointNames[i] << " = " << q[i] * 180.0 / M_PI << " deg, outside ["
        << leg.q_min[i] * 180.0 / M_PI << ", " << leg.q_max[i] * 180.0 / M_PI << "] deg";
      res.message = s.str();
      return res;
    }
  }
  res.status = IkStatus::ok;
  return res;
}

IkResult other_shape_ik(const LegModel& leg, const Vector3& foot_in_base) {
  double excess = 0.0;
  Vector3 q;
  if (leg.shape == LegShape::lateral_offset) {
    q = lateral_offset_joint_angles<double>(leg, foot_in_base, &excess);
  } else {
    q = general_leg_angles(leg, foot_in_base, &excess);
  }
  return finish_ik(leg, foot_in_base, q, excess);
}

}  // namespace

Vector3 general_leg_angles(const LegModel& leg, const Vector3& foot_in_base, double* residual) {
  // Starts: the middle of the ranges and the eight corners of the box spanning the middle half.
  const Vector3 mid = 0.5 * (leg.q_min + leg.q_max), quarter = 0.25 * (leg.q_max - leg.q_min);
  std::vector<Vector3> starts{mid};
  for (int k = 0; k < 8; ++k)
    starts.push_back(mid + Vector3((k & 1) ? quarter.x() : -quarter.x(),
                                   (k & 2) ? quarter.y() : -quarter.y(),
                                   (k & 4) ? quarter.z() : -quarter.z()));
  Vector3 best = mid;
  double best_err = HUGE_VAL, best_score = HUGE_VAL;
  for (const Vector3& start : starts) {
    Vector3 q = start;
    double lambda = 1e-3;
    Vector3 e = foot_in_base - foot_position(leg, q);
    for (int it = 0; it < 100 && e.norm() > 1e-13; ++it) {
      const Matrix3 j = foot_jacobian(leg, q);
      const Matrix3 a = j.transpose() * j + lambda * Matrix3::Identity();
      const Vector3 step = a.ldlt().solve(j.transpose() * e);
      const Vector3 e_new = foot_in_base - foot_position(leg, q + step);
      if (e_new.norm() < e.norm()) {
        q += step;
        e = e_new;
        lambda = std::max(lambda * 0.3, 1e-12);
      } else {
        lambda *= 10.0;
        if (lambda > 1e8) break;
      }
    }
    for (int i = 0; i < 3; ++i) {
      q[i] = std::remainder(q[i], 2.0 * M_PI);
      q[i] = into_joint_range<double>(q[i], leg.q_min[i], leg.q_max[i]);
    }
    const double err = e.norm();
    // Reaching the foot first, then within the ranges, then nearest the middle.
    bool inside = true;
    for (int i = 0; i < 3; ++i) inside = inside && q[i] >= leg.q_min[i] && q[i] <= leg.q_max[i];
    const double score = (inside ? 0.0 : 10.0) + (q - mid).cwiseQuotient(2.0 * quarter + Vector3::Constant(1e-9)).squaredNorm() * 1e-3;
    const bool reaches = err < 1e-9, best_reaches = best_err < 1e-9;
    if ((reaches && !best_reaches) || (reaches == best_reaches && (reaches ? score < best_score : err < best_err))) {
      best = q;
      best_err = err;
      best_score = score;
    }
  }
  if (residual) *residual = best_err;
  return best;
}

Vector3 foot_position(const LegModel& leg, const Vector3& q) { return chain_frames(leg, q).foot; }
LegFrames leg_frames(const LegModel& leg, const Vector3& q) { return chain_frames(leg, q); }
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
  if (leg.shape != LegShape::in_plane) return other_shape_ik(leg, foot_in_base);
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
