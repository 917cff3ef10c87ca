#include "terrastride/planner/dense_checks.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "terrastride/robot/geometry.hpp"

namespace terrastride::planner {

std::map<std::string, double> dense_checks(const robot::RobotModel& robot,
                                           const terrain::HeightField& terrain,
                                           const Trajectory& dense, const DenseCheckLimits& limits) {
  const double g = 9.81;
  const std::size_t nf = robot.legs.size();
  double lin = 0.0, ang = 0.0, pen = 0.0, fric = 0.0, slip = 0.0, rom = 0.0, stance_h = 0.0;
  const bool rot_free = robot.base_dof_free[3] || robot.base_dof_free[4] || robot.base_dof_free[5];
  std::vector<Eigen::Vector3d> anchor(nf);
  std::vector<bool> was_contact(nf, false);
  // Largest rate of change of a contact force (N/s) between consecutive samples, a swing foot's
  // force counting as zero: a lift-off or touch-down under load shows as a step here.
  double force_rate = 0.0;
  std::vector<Eigen::Vector3d> last_force(nf, Eigen::Vector3d::Zero());
  double last_t = 0.0;
  bool first_sample = true;
  const bool debug = std::getenv("TERRASTRIDE_DEBUG_CHECKS") != nullptr;  // once, not per sample
  for (const auto& s : dense.samples) {
    if (s.feet.size() != nf) continue;
    const auto& b = s.base;
    Eigen::Vector3d sum_f = Eigen::Vector3d::Zero(), torque = Eigen::Vector3d::Zero();
    for (std::size_t f = 0; f < nf; ++f) {
      sum_f += s.feet[f].force;
      torque += (s.feet[f].position - b.position).cross(s.feet[f].force);
    }
    Eigen::Vector3d rl = robot.mass * b.linear_acceleration - sum_f;
    rl.z() += robot.mass * g;
    for (int d = 0; d < 3; ++d)
      if (robot.base_dof_free[d]) lin = std::max(lin, std::abs(rl[d]));
    const Eigen::Matrix3d R = robot::rotation_zyx(b.euler_zyx);
    if (rot_free) {
      const Eigen::Matrix3d Iw = R * robot.inertia * R.transpose();
      const Eigen::Vector3d w = b.angular_velocity;
      const Eigen::Vector3d ra = Iw * b.angular_acceleration + w.cross(Iw * w) - torque;
      ang = std::max(ang, ra.norm());
    }
    for (std::size_t f = 0; f < nf; ++f) {
      const auto& ft = s.feet[f];
      const auto hs = terrain.sample(ft.position.x(), ft.position.y());
      if (ft.contact) {
        if (!was_contact[f]) anchor[f] = ft.position;
        slip = std::max(slip, (ft.position - anchor[f]).norm());
        stance_h = std::max(stance_h, std::abs(ft.position.z() - hs.height));
        const Eigen::Vector3d n =
            Eigen::Vector3d(-hs.gradient.x(), -hs.gradient.y(), 1.0).normalized();
        const Eigen::Vector3d t1 = Eigen::Vector3d(1.0, 0.0, hs.gradient.x()).normalized();
        const Eigen::Vector3d t2 = n.cross(t1);
        const double fn = n.dot(ft.force);
        double v = std::max({-fn, std::abs(t1.dot(ft.force)) - limits.friction * fn,
                             std::abs(t2.dot(ft.force)) - limits.friction * fn});
        if (limits.max_normal_force > 0.0) v = std::max(v, fn - limits.max_normal_force);
        fric = std::max(fric, v);
      } else {
        if (debug && hs.height - ft.position.z() > pen)
          std::fprintf(stderr, "pen %g at t=%g foot %zu p=(%g %g %g)\n", hs.height - ft.position.z(),
                       s.t, f, ft.position.x(), ft.position.y(), ft.position.z());
        pen = std::max(pen, hs.height - ft.position.z());
      }
      was_contact[f] = ft.contact;
      const Eigen::Vector3d force = ft.contact ? ft.force : Eigen::Vector3d::Zero();
      if (!first_sample && s.t > last_t)
        force_rate = std::max(force_rate, (force - last_force[f]).norm() / (s.t - last_t));
      last_force[f] = force;
      const Eigen::Vector3d pb = R.transpose() * (ft.position - b.position);
      const Eigen::Vector3d ex =
          (pb - robot.legs[f].nominal_foot).cwiseAbs() - robot.legs[f].range_of_motion;
      if (debug && ex.maxCoeff() > rom)
        std::fprintf(stderr, "rom %g at t=%g foot %zu contact %d pb=(%g %g %g)\n", ex.maxCoeff(), s.t, f,
                     int(ft.contact), pb.x(), pb.y(), pb.z());
      rom = std::max(rom, ex.maxCoeff());
    }
    last_t = s.t;
    first_sample = false;
  }
  std::map<std::string, double> out;
  out["dynamics_linear_max_N"] = lin;
  if (rot_free) out["dynamics_angular_max_Nm"] = ang;
  out["penetration_max_m"] = std::max(0.0, pen);
  out["friction_violation_max_N"] = std::max(0.0, fric);
  out["slip_max_m"] = slip;
  out["range_of_motion_excess_max_m"] = std::max(0.0, rom);
  out["stance_height_error_max_m"] = stance_h;
  out["force_rate_max_N_per_s"] = force_rate;
  return out;
}

}  // namespace terrastride::planner
