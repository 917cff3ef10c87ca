// All post-hoc checks on one trajectory, and their plan.json "checks" keys.
#include "terrastride/collision/checks.hpp"

#include <algorithm>
#include <chrono>
#include <sstream>

#include "terrastride/collision/octree_terrain.hpp"

namespace terrastride::collision {
namespace {

std::string fmt(double v, int precision = 3) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(precision);
  s << v;
  return s.str();
}

const char* kJointNames[3] = {"HAA", "HFE", "KFE"};

}  // namespace

std::map<std::string, double> CheckReport::keys() const {
  std::map<std::string, double> k;
  k["torque_ratio_max"] = torque.ratio_max;
  k["torque_violations"] = torque.violating_samples;
  k["energy_proxy_J"] = torque.energy_proxy_J;
  if (torque.velocity_checked) {
    k["velocity_ratio_max"] = torque.velocity_ratio_max;
    k["velocity_violations"] = torque.velocity_violating_samples;
  }
  k["ik_failures"] = kinematics.unreachable_samples;
  k["joint_limit_violations"] = kinematics.joint_limit_samples;
  if (clearance) {
    k["shin_min_distance_m"] = clearance->shin_min_distance;
    k["shin_collisions"] = clearance->shin_collisions;
    k["shin_collisions_certain"] = clearance->shin_collisions_certain;
    k["shin_contacts_uncertain"] = clearance->shin_contacts_uncertain;
    k["shin_min_certain_distance_m"] = clearance->shin_min_certain_distance;
    if (!clearance->legs.empty() && !clearance->legs.front().thigh_distance.empty()) {
      k["thigh_min_distance_m"] = clearance->thigh_min_distance;
      k["thigh_collisions"] = clearance->thigh_collisions;
      k["thigh_collisions_certain"] = clearance->thigh_collisions_certain;
      k["thigh_contacts_uncertain"] = clearance->thigh_contacts_uncertain;
      k["thigh_min_certain_distance_m"] = clearance->thigh_min_certain_distance;
    }
  }
  if (trunk) {
    k["trunk_min_distance_m"] = trunk->min_distance;
    k["trunk_collisions"] = trunk->collisions;
    k["trunk_collisions_certain"] = trunk->collisions_certain;
    k["trunk_contacts_uncertain"] = trunk->contacts_uncertain;
    k["trunk_min_certain_distance_m"] = trunk->min_certain_distance;
  }
  if (footholds) {
    k["unsafe_footholds"] = footholds->unsafe;
    // An analytic scene's margin is 1e9 where no edge is in reach: there the figure means
    // "nothing to measure", and a number that large would read as a real distance. Left out.
    if (footholds->worst >= 0 && footholds->worst_margin < 1e8)
      k["foothold_margin_min_m"] = footholds->worst_margin;
  }
  return k;
}

std::vector<std::string> CheckReport::failures() const {
  std::vector<std::string> out;
  if (kinematics.unreachable_samples > 0) {
    std::string first = kinematics.issues.empty() ? "" : ": " + kinematics.issues.front().message;
    for (const auto& issue : kinematics.issues) {
      if (issue.message.find("out of reach") != std::string::npos) {
        first = ": first at t = " + fmt(issue.t) + " s, " + issue.message;
        break;
      }
    }
    out.push_back("IK failed (foot out of reach) at " +
                  std::to_string(kinematics.unreachable_samples) + " samples" + first);
  }
  if (kinematics.joint_limit_samples > 0) {
    std::string first;
    for (const auto& issue : kinematics.issues) {
      if (issue.message.find("outside") != std::string::npos) {
        first = ": first at t = " + fmt(issue.t) + " s, " + issue.message;
        break;
      }
    }
    out.push_back("joint range exceeded at " + std::to_string(kinematics.joint_limit_samples) +
                  " samples" + first);
  }
  if (torque.violating_samples > 0) {
    const auto& leg = torque.legs[torque.worst_leg];
    out.push_back("joint torque above the limit at " + std::to_string(torque.violating_samples) +
                  " samples; worst " + fmt(torque.ratio_max) + " x limit at " + leg.leg + " " +
                  kJointNames[torque.worst_joint] +
                  ", t = " + fmt(torque.time[torque.worst_sample]) + " s");
  }
  if (torque.velocity_violating_samples > 0) {
    const auto& leg = torque.legs[torque.velocity_worst_leg];
    out.push_back("joint velocity above the limit at " +
                  std::to_string(torque.velocity_violating_samples) + " samples; worst " +
                  fmt(torque.velocity_ratio_max) + " x limit at " + leg.leg + " " +
                  kJointNames[torque.velocity_worst_joint] +
                  ", t = " + fmt(torque.time[torque.velocity_worst_sample]) + " s");
  }
  if (clearance && clearance->shin_collisions_certain + clearance->thigh_collisions_certain > 0) {
    std::string legs;
    for (const auto& l : clearance->legs) {
      if (l.shin_certain_samples + l.thigh_certain_samples == 0) continue;
      legs += (legs.empty() ? "" : ", ") + l.leg + " (shin " +
              std::to_string(l.shin_certain_samples) + ", thigh " +
              std::to_string(l.thigh_certain_samples) + ")";
    }
    std::string more;
    const int uncertain = clearance->shin_contacts_uncertain + clearance->thigh_contacts_uncertain;
    if (!clearance->certain_source.empty() && uncertain > 0)
      more = "; besides, " + std::to_string(clearance->shin_contacts_uncertain) + " (shin) and " +
             std::to_string(clearance->thigh_contacts_uncertain) +
             " (thigh) samples touch voxels only within the map's uncertainty";
    out.push_back("leg collides with the terrain at " +
                  std::to_string(clearance->shin_collisions_certain) + " samples (shin) and " +
                  std::to_string(clearance->thigh_collisions_certain) + " (thigh), first at t = " +
                  fmt(clearance->first_certain_collision_t) + " s: " + legs + more);
  }
  if (trunk && trunk->collisions_certain > 0) {
    std::string how;
    if (trunk->min_distance < -trunk->deep_contact_depth)
      how = "; deepest " + fmt(-trunk->min_distance) + " m into occupied voxels (more than the " +
            fmt(trunk->deep_contact_depth) + " m the map's voxels explain) at t = " +
            fmt(trunk->time[trunk->min_sample]) + " s, base at (" + fmt(trunk->min_base.x()) +
            ", " + fmt(trunk->min_base.y()) + ", " + fmt(trunk->min_base.z()) + ")";
    else if (trunk->min_sample >= 0)
      how = "; deepest at t = " + fmt(trunk->time[trunk->min_sample]) + " s, base at (" +
            fmt(trunk->min_base.x()) + ", " + fmt(trunk->min_base.y()) + ", " +
            fmt(trunk->min_base.z()) + ")";
    if (!trunk->overhang.empty()) how += "; " + trunk->overhang;
    out.push_back("trunk collides with the terrain at " +
                  std::to_string(trunk->collisions_certain) + " samples, first at t = " +
                  fmt(trunk->first_certain_collision_t) + " s" + how);
  }
  if (footholds && footholds->unsafe > 0) {
    const Foothold& w = footholds->footholds[footholds->worst];
    out.push_back(
        std::to_string(footholds->unsafe) + " of " + std::to_string(footholds->footholds.size()) +
        " stance footholds are unsafe; worst " +
        (w.leg >= 0 && w.leg < static_cast<int>(torque.legs.size()) ? torque.legs[w.leg].leg
                                                                    : std::to_string(w.leg)) +
        " at (" + fmt(w.position.x()) + ", " + fmt(w.position.y()) + "), t = " + fmt(w.t_start) +
        " s, margin " + fmt(w.margin, 4) + " m");
  }
  return out;
}

CheckReport run_checks(const robot::RobotModel& model, const planner::Trajectory& trajectory,
                       const CheckTerrain& terrain, const CheckOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  CheckReport rep;
  rep.kinematics = leg_kinematics(model, trajectory);
  rep.torque = check_joint_torques(model, trajectory, rep.kinematics, options.torque);
  if (terrain.octree) {
    std::shared_ptr<const CertainSolid> certain = terrain.certain;
    if (!certain && terrain.field) {
      Eigen::Vector2d lo, hi;
      trajectory_extent(model, trajectory, options.clearance.distance_cutoff + 0.05, &lo, &hi);
      certain = certain_solid_for(*terrain.field, *terrain.octree, lo, hi);
    }
    rep.clearance = check_leg_clearance(model, trajectory, rep.kinematics, *terrain.octree,
                                        options.clearance, certain.get());
    if (model.trunk && options.clearance.check_trunk)
      rep.trunk = check_trunk_clearance(model, trajectory, *terrain.octree, options.clearance,
                                        certain.get());
    if (rep.trunk && terrain.field)
      name_trunk_overhang(model, trajectory, *terrain.field, &*rep.trunk);
  }
  if (terrain.field) rep.footholds = check_footholds(trajectory, *terrain.field, model.foot_radius);
  rep.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

void trajectory_extent(const robot::RobotModel& model, const planner::Trajectory& trajectory,
                       double margin, Eigen::Vector2d* lo, Eigen::Vector2d* hi) {
  Eigen::Vector2d a = Eigen::Vector2d::Constant(1e300), b = Eigen::Vector2d::Constant(-1e300);
  auto add = [&](const Eigen::Vector3d& p) {
    a = a.cwiseMin(p.head<2>());
    b = b.cwiseMax(p.head<2>());
  };
  for (const auto& s : trajectory.samples) {
    const Eigen::Matrix3d rot = rotation_zyx(s.base.euler_zyx);
    for (const auto& leg : model.legs) add(s.base.position + rot * leg.haa_origin);
    for (const auto& f : s.feet) add(f.position);
    if (model.trunk)
      for (int c = 0; c < 8; ++c)
        add(robot::trunk_corner_world<double>(*model.trunk, c, s.base.position, s.base.euler_zyx));
  }
  if (trajectory.samples.empty()) a = b = Eigen::Vector2d::Zero();
  // Knees lie between hips and feet in x and y only up to the leg's reach, so grow by the lower
  // leg's length as well as the caller's margin.
  double reach = 0;
  for (const auto& leg : model.legs) reach = std::max(reach, leg.l2 + leg.shin_radius);
  *lo = a - Eigen::Vector2d::Constant(margin + reach);
  *hi = b + Eigen::Vector2d::Constant(margin + reach);
}

}  // namespace terrastride::collision
