#include "terrastride/planner/dense_checks.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/piece_math.hpp"
#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"

namespace terrastride::planner {

std::map<std::string, double> dense_checks(const robot::RobotModel& robot,
                                           const terrain::HeightField& terrain,
                                           const Trajectory& dense,
                                           const DenseCheckLimits& limits) {
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
          std::fprintf(stderr, "pen %g at t=%g foot %zu p=(%g %g %g)\n",
                       hs.height - ft.position.z(), s.t, f, ft.position.x(), ft.position.y(),
                       ft.position.z());
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
        std::fprintf(stderr, "rom %g at t=%g foot %zu contact %d pb=(%g %g %g)\n", ex.maxCoeff(),
                     s.t, f, int(ft.contact), pb.x(), pb.y(), pb.z());
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

namespace {

// The worst instant of one (foot, segment) for one kind of excess.
struct SegmentWorst {
  double excess = 0.0;
  double sigma = 0.0;
  void take(double e, double at) {
    if (e > excess) {
      excess = e;
      sigma = at;
    }
  }
};

Eigen::Vector3d vec3_of(const std::vector<double>& x, int i) {
  return i < 0 ? Eigen::Vector3d::Zero() : Eigen::Vector3d(x[i], x[i + 1], x[i + 2]);
}

// One foot at one instant of a segment, what its torques need: the angles and their rates (ok:
// inverse kinematics reached the foot), the contact force and the apparent gravity (g less the
// base's acceleration), both in the base frame.
struct LegInstant {
  bool ok = false;
  Eigen::Vector3d q, qd, force_base, gravity_base;
};

// The torques of a stance foot along one segment as the post-hoc torque check computes them
// (collision::check_joint_torques: tau = M q'' + c + g - J^T f, q'' the central difference of q'
// on the sample grid, one-sided at the segment's ends and next to IK failures), its worst ratio
// per segment into `worst` and over the plan into `out`.
void stance_torques(const robot::LegModel& leg, const std::vector<LegInstant>& at, double dt,
                    int foot, double t0, SegmentWorst* worst, JointDenseCheck* out) {
  const int n = static_cast<int>(at.size());
  for (int k = 0; k < n; ++k) {
    if (!at[k].ok) continue;
    const bool prev = k > 0 && at[k - 1].ok, next = k + 1 < n && at[k + 1].ok;
    Eigen::Vector3d qdd = Eigen::Vector3d::Zero();
    if (prev && next) qdd = (at[k + 1].qd - at[k - 1].qd) / (2 * dt);
    else if (next) qdd = (at[k + 1].qd - at[k].qd) / dt;
    else if (prev) qdd = (at[k].qd - at[k - 1].qd) / dt;
    const Eigen::Vector3d tau =
        robot::joint_torques(leg, at[k].q, at[k].qd, qdd, at[k].force_base, at[k].gravity_base);
    const double sigma = static_cast<double>(k) / (n - 1);
    for (int j = 0; j < 3; ++j) {
      const double ratio = std::abs(tau[j]) / leg.torque_limit[j];
      worst->take(ratio - 1.0, sigma);
      if (ratio > out->torque_ratio) {
        out->torque_ratio = ratio;
        out->torque_foot = foot;
        out->torque_joint = j;
        out->torque_t = t0 + sigma * dt * (n - 1);
      }
    }
  }
}

// The points of one (segment, foot): one per distinct worst instant, with the rows it needs.
void add_violations(int f, int s, const SegmentWorst& range, const SegmentWorst& velocity,
                    const SegmentWorst& torque, std::vector<JointPoint>* out) {
  const std::size_t first = out->size();
  auto mark = [&](const SegmentWorst& w, bool JointPoint::*kind) {
    if (!(w.excess > 0.0)) return;
    for (std::size_t i = first; i < out->size(); ++i)
      if ((*out)[i].sigma == w.sigma) {
        (*out)[i].*kind = true;
        return;
      }
    JointPoint point{f, s, w.sigma};
    point.*kind = true;
    out->push_back(point);
  };
  mark(range, &JointPoint::range);
  mark(velocity, &JointPoint::velocity);
  mark(torque, &JointPoint::torque);
}

}  // namespace

bool has_torque_limits(const robot::RobotModel& robot) {
  for (const auto& leg : robot.legs)
    if (!(leg.torque_limit.minCoeff() > 0.0)) return false;
  return !robot.legs.empty();
}

JointDenseCheck dense_joint_check(const SrbdProblem& problem, const std::vector<double>& x,
                                  double max_dt) {
  if (!(max_dt > 0.0)) throw std::invalid_argument("dense_joint_check: max_dt must be > 0");
  const robot::RobotModel& robot = problem.robot();
  const Layout& L = problem.layout();
  const int nf = static_cast<int>(robot.legs.size());
  const bool velocities = has_velocity_limits(robot), torques = has_torque_limits(robot);
  const Eigen::Vector3d gravity(0.0, 0.0, -kGravity);
  JointDenseCheck out;
  double t0 = 0.0;
  for (int s = 0; s < L.num_segments; ++s) {
    const double h = x[L.interval_var[L.seg_interval[s]]] * L.seg_fraction[s];
    const int steps = std::max(1, static_cast<int>(std::ceil(h / max_dt - 1e-9)));
    std::vector<SegmentWorst> range(nf), velocity(nf), torque(nf);
    std::vector<std::vector<LegInstant>> legs(nf, std::vector<LegInstant>(steps + 1));
    const int b0 = L.base[s], b1 = L.base[s + 1];
    for (int i = 0; i <= steps; ++i) {
      const double sigma = static_cast<double>(i) / steps;
      Eigen::Vector3d r, rv, ra, e, ev;
      hermite<double>(sigma, h, vec3_of(x, b0), vec3_of(x, b0 + 3), vec3_of(x, b1),
                      vec3_of(x, b1 + 3), &r, &rv, &ra);
      hermite<double>(sigma, h, vec3_of(x, b0 + 6), vec3_of(x, b0 + 9), vec3_of(x, b1 + 6),
                      vec3_of(x, b1 + 9), &e, &ev, nullptr);
      const Eigen::Matrix3d rt = rotation_zyx<double>(e).transpose();
      for (int f = 0; f < nf; ++f) {
        const robot::LegModel& leg = robot.legs[f];
        Eigen::Vector3d p, pv;
        hermite<double>(sigma, h, vec3_of(x, L.foot_pos[f][s]), vec3_of(x, L.foot_vel[f][s]),
                        vec3_of(x, L.foot_pos[f][s + 1]), vec3_of(x, L.foot_vel[f][s + 1]), &p, &pv,
                        nullptr);
        const robot::IkResult ik = robot::inverse_kinematics(leg, rt * (p - r));
        if (ik.status == robot::IkStatus::unreachable) continue;  // the post-hoc check's failure
        for (int j = 0; j < 3; ++j) {
          const double beyond = std::max(leg.q_min[j] - ik.q[j], ik.q[j] - leg.q_max[j]);
          range[f].take(beyond, sigma);
          if (beyond > out.range_excess_rad) {
            out.range_excess_rad = beyond;
            out.range_foot = f;
            out.range_joint = j;
            out.range_t = t0 + sigma * h;
          }
        }
        if (!velocities && !(torques && L.contact[f][s])) continue;
        const Eigen::Vector3d qd = joint_velocity_rows<double>(leg, r, rv, e, ev, p, pv);
        if (torques && L.contact[f][s]) {
          // The force is linear in time inside a stance segment; a missing knot is zero force.
          const Eigen::Vector3d force = (1.0 - sigma) * vec3_of(x, L.force[f][s][0]) +
                                        sigma * vec3_of(x, L.force[f][s][1]);
          legs[f][i] = {true, ik.q, qd, rt * force, rt * (gravity - ra)};
        }
        if (!velocities) continue;
        for (int j = 0; j < 3; ++j) {
          const double ratio = std::abs(qd[j]) / leg.velocity_limit[j];
          velocity[f].take(ratio - 1.0, sigma);
          if (ratio > out.velocity_ratio) {
            out.velocity_ratio = ratio;
            out.velocity_foot = f;
            out.velocity_joint = j;
            out.velocity_t = t0 + sigma * h;
          }
        }
      }
    }
    out.samples += steps + (s + 1 == L.num_segments ? 1 : 0);
    for (int f = 0; f < nf; ++f) {
      if (torques && L.contact[f][s])
        stance_torques(robot.legs[f], legs[f], h / steps, f, t0, &torque[f], &out);
      add_violations(f, s, range[f], velocity[f], torque[f], &out.violations);
    }
    t0 += h;
  }
  return out;
}

}  // namespace terrastride::planner
