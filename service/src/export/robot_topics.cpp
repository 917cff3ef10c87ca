// The robot's Foxglove topics (robot_topics.hpp).
#include "export/robot_topics.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

#include "terrastride/robot/geometry.hpp"
#include "terrastride/robot/leg_kinematics.hpp"
#include "terrastride/service/cli.hpp"

namespace terrastride::service::foxglove {

namespace {

constexpr double kArrowMetresPerNewton = 1.0 / 1000.0;  // a 500 N foot force: a 0.5 m arrow
const char* const kJointNames[3] = {"haa", "hfe", "kfe"};

// ---- Schemas of the numeric topics.

json number_schema(const std::string& description) {
  return {{"type", "number"}, {"description", description}};
}
json time_schema() {
  return {{"type", "object"},
          {"title", "time"},
          {"properties",
           {{"sec", {{"type", "integer"}, {"minimum", 0}}},
            {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}}},
          {"required", {"sec", "nsec"}}};
}
json object_schema(const std::string& title, json properties, json required = json::array()) {
  return {{"title", title},
          {"type", "object"},
          {"properties", std::move(properties)},
          {"required", std::move(required)}};
}
json per_leg_schema(const std::string& title, const robot::RobotModel& model, const json& leg) {
  json props = {{"timestamp", time_schema()}};
  for (const auto& l : model.legs) props[l.name] = leg;
  return object_schema(title, props, {"timestamp"});
}

json vector3_schema() {
  return object_schema(
      "foxglove.Vector3",
      {{"x", number_schema("x")}, {"y", number_schema("y")}, {"z", number_schema("z")}},
      {"x", "y", "z"});
}

// ---- The robot at one moment.

struct RobotPose {
  Eigen::Vector3d base = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  std::vector<Eigen::Vector3d> q;        // per leg (IK of the foot; the nearest when out of reach)
  std::vector<robot::LegFrames> frames;  // per leg, base frame
};

RobotPose robot_pose(const robot::RobotModel& model, const Eigen::Vector3d& base,
                     const Eigen::Vector3d& euler, const std::vector<Eigen::Vector3d>& feet) {
  RobotPose p;
  p.base = base;
  p.R = robot::rotation_zyx<double>(euler);
  for (size_t l = 0; l < feet.size(); ++l) {
    const robot::IkResult ik =
        robot::inverse_kinematics(model.legs[l], p.R.transpose() * (feet[l] - base));
    p.q.push_back(ik.q);
    p.frames.push_back(robot::leg_frames(model.legs[l], ik.q));
  }
  return p;
}

// map -> base -> LEG_hip -> LEG_thigh -> LEG_shin (each link's frame at its joint, turned with it).
json robot_transforms(const Clock& clock, double t, const std::string& prefix,
                      const robot::RobotModel& model, const RobotPose& p) {
  json out = json::array();
  out.push_back(transform(clock, t, kMapFrame, prefix + "base", p.base, Eigen::Quaterniond(p.R)));
  for (size_t l = 0; l < p.frames.size(); ++l) {
    const robot::LegFrames& f = p.frames[l];
    const std::string leg = prefix + model.legs[l].name;
    out.push_back(transform(clock, t, prefix + "base", leg + "_hip", f.origin[0],
                            Eigen::Quaterniond(f.rotation[0])));
    out.push_back(transform(clock, t, leg + "_hip", leg + "_thigh",
                            f.rotation[0].transpose() * (f.origin[1] - f.origin[0]),
                            Eigen::Quaterniond(f.rotation[0].transpose() * f.rotation[1])));
    out.push_back(transform(clock, t, leg + "_thigh", leg + "_shin",
                            f.rotation[1].transpose() * (f.origin[2] - f.origin[1]),
                            Eigen::Quaterniond(f.rotation[1].transpose() * f.rotation[2])));
  }
  return out;
}

// The links as primitives in their own frames (frame-locked: they move with /tf): the trunk box,
// per leg the hip offset, the thigh and the shin as cylinders, the foot as a sphere (blue in
// stance). `shin_colors` colours each shin (empty: grey).
json robot_entities(const Clock& clock, double t, const std::string& prefix,
                    const robot::RobotModel& model, const RobotPose& p, const json& body,
                    const std::vector<json>& shin_colors, const std::vector<bool>& contact) {
  json entities = json::array();
  if (model.trunk) {
    json e = entity(clock, t, prefix + "trunk", prefix + "base", true);
    e["cubes"].push_back(cube(model.trunk->center, model.trunk->size, body));
    entities.push_back(std::move(e));
  }
  const json grey = color(0.35, 0.35, 0.4);
  for (size_t l = 0; l < p.frames.size(); ++l) {
    const robot::LegModel& leg = model.legs[l];
    const robot::LegFrames& f = p.frames[l];
    const std::string name = prefix + leg.name;
    const double thigh_d = leg.thigh_radius > 0 ? 2 * leg.thigh_radius : 0.04;
    const double shin_d = leg.shin_radius > 0 ? 2 * leg.shin_radius : 0.03;
    const Eigen::Vector3d hfe = f.rotation[0].transpose() * (f.origin[1] - f.origin[0]);
    const Eigen::Vector3d knee = f.rotation[1].transpose() * (f.origin[2] - f.origin[1]);
    const Eigen::Vector3d foot = f.rotation[2].transpose() * (f.foot - f.origin[2]);
    json hip = entity(clock, t, name + "_hip", name + "_hip", true);
    hip["spheres"].push_back(sphere(Eigen::Vector3d::Zero(), thigh_d * 1.2, grey));
    if (hfe.norm() > 1e-3)
      hip["cylinders"].push_back(cylinder_between(Eigen::Vector3d::Zero(), hfe, thigh_d, grey));
    json thigh = entity(clock, t, name + "_thigh", name + "_thigh", true);
    thigh["cylinders"].push_back(cylinder_between(Eigen::Vector3d::Zero(), knee, thigh_d, grey));
    json shin = entity(clock, t, name + "_shin", name + "_shin", true);
    shin["spheres"].push_back(sphere(Eigen::Vector3d::Zero(), shin_d * 1.2, grey));
    shin["cylinders"].push_back(cylinder_between(Eigen::Vector3d::Zero(), foot, shin_d,
                                                 shin_colors.empty() ? grey : shin_colors[l]));
    shin["spheres"].push_back(sphere(foot, 2 * model.foot_radius,
                                     contact[l] ? color(0.1, 0.3, 0.9) : color(0.6, 0.6, 0.65)));
    for (json* e : {&hip, &thigh, &shin}) entities.push_back(std::move(*e));
  }
  return scene_update(std::move(entities));
}

json force_entities(const Clock& clock, double t, const std::string& id,
                    const std::vector<Eigen::Vector3d>& feet,
                    const std::vector<Eigen::Vector3d>& forces, const std::vector<bool>& contact,
                    const json& c) {
  json e = entity(clock, t, id);
  for (size_t f = 0; f < feet.size(); ++f)
    if (contact[f] && forces[f].norm() > 1e-6)
      e["arrows"].push_back(force_arrow(feet[f], forces[f], c, kArrowMetresPerNewton));
  return scene_update(json::array({e}));
}

void set_finite(json& obj, const char* key, double v) {
  if (std::isfinite(v)) obj[key] = v;
}

// Per leg: the foot force, its normal part on the terrain under the foot, the friction-cone
// margin mu f_n - |f_t| (N; < 0 slips), the force-polytope margin 1 - max_i |J_i^T f| / tau_i
// (< 0: a joint's torque limit cannot hold the force) and the foothold's safety margin (m).
json foot_state(const robot::RobotModel& model, size_t l, const Eigen::Vector3d& foot,
                const Eigen::Vector3d& force, bool contact, const RobotPose& p,
                const terrain::HeightField* field, double friction) {
  json s = {{"force", vec3(force)}, {"contact", contact ? 1 : 0}};
  if (field) {
    Eigen::Vector2d g;
    field->height_and_gradient(foot.x(), foot.y(), &g);
    const Eigen::Vector3d n = Eigen::Vector3d(-g.x(), -g.y(), 1.0).normalized();
    const double fn = force.dot(n), ft = (force - fn * n).norm();
    set_finite(s, "normal_force", fn);
    if (contact) set_finite(s, "friction_margin", friction * fn - ft);
    // Capped at 1 m: far from any unsafe cell the margin reads 1e9, which flattens a plot.
    set_finite(s, "foothold_margin",
               std::min(1.0, field->safety_margin(foot.x(), foot.y(), model.foot_radius).margin));
  }
  if (contact) {
    const robot::ForcePolytope poly = robot::exact_force_polytope(model.legs[l], p.q[l]);
    set_finite(s, "polytope_margin", 1.0 - poly.torque_ratio(p.R.transpose() * force));
  }
  return s;
}

std::string format(const char* fmt, double a, double b = 0, double c = 0) {
  char buf[256];
  std::snprintf(buf, sizeof buf, fmt, a, b, c);
  return buf;
}

}  // namespace

void add_robot_schemas(Publisher& pub, const robot::RobotModel& model) {
  json joint = object_schema(
      "terrastride.Joint",
      {{"angle", number_schema("rad")},
       {"velocity", number_schema("rad/s")},
       {"torque",
        number_schema("N m (plan: leg dynamics, checks' torque check; sim: MuJoCo's motor)")},
       {"torque_limit", number_schema("N m, the robot file's")},
       {"torque_ratio", number_schema("|torque| / torque_limit (> 1: over the limit)")},
       {"velocity_limit", number_schema("rad/s, the robot file's (0: none given)")}});
  json leg =
      object_schema("terrastride.LegJoints", {{"haa", joint}, {"hfe", joint}, {"kfe", joint}});
  pub.add_schema("terrastride.JointStates", per_leg_schema("terrastride.JointStates", model, leg));
  json foot = object_schema(
      "terrastride.Foot",
      {{"force", vector3_schema()},
       {"normal_force", number_schema("N, along the terrain normal under the foot")},
       {"friction_margin", number_schema("N, mu f_n - |f_t| (< 0: outside the friction cone)")},
       {"polytope_margin",
        number_schema("1 - max_i |J_i^T f| / tau_lim_i (< 0: beyond a torque limit)")},
       {"foothold_margin",
        number_schema("m, the terrain's safety margin under the foot (at most 1)")},
       {"contact", number_schema("1 in contact, 0 in swing")},
       {"planned_contact", number_schema("sim: 1 where the plan has contact")},
       {"shin_force", number_schema("sim: N, contact force on the shin")}});
  pub.add_schema("terrastride.FootStates", per_leg_schema("terrastride.FootStates", model, foot));
  pub.add_schema(
      "terrastride.Tracking",
      object_schema("terrastride.Tracking",
                    {{"timestamp", time_schema()},
                     {"position_error", vector3_schema()},
                     {"position_error_norm", number_schema("m, simulated - planned base")},
                     {"yaw_error", number_schema("rad")},
                     {"pitch_error", number_schema("rad")},
                     {"roll_error", number_schema("rad")}},
                    {"timestamp", "position_error", "position_error_norm"}));
}

namespace {

// Footholds coloured by their worst margin, and the base path, at t = 0.
void publish_plan_overviews(Publisher& pub, const Clock& clock, const planner::Trajectory& traj,
                            const collision::CheckReport& checks, RobotTopicStats* stats) {
  json fh = entity(clock, 0, "footholds");
  if (checks.footholds)
    for (const auto& f : checks.footholds->footholds) {
      fh["spheres"].push_back(sphere(f.position, 0.05, margin_color(f.margin)));
      fh["metadata"].push_back({{"key", traj.feet[f.leg] + "@" + std::to_string(f.t_start)},
                                {"value", std::to_string(f.margin)}});
      ++stats->footholds;
    }
  pub.publish(pub.channel("/plan/footholds", "foxglove.SceneUpdate"), clock.ns(0),
              scene_update(json::array({fh})));
  std::vector<Eigen::Vector3d> path;
  for (const auto& s : traj.samples) path.push_back(s.base.position);
  json pe = entity(clock, 0, "base_path");
  pe["lines"].push_back(line_strip(path, color(0.0, 0.85, 0.95), 0.01));
  pub.publish(pub.channel("/plan/base_path", "foxglove.SceneUpdate"), clock.ns(0),
              scene_update(json::array({pe})));
}

// /plan/joints at sample k: angles and velocities of the checks' kinematics, torques of their
// torque check, against the robot file's limits.
json plan_joints(const Clock& clock, double t, const robot::RobotModel& model,
                 const collision::CheckReport& checks, size_t k) {
  json msg = {{"timestamp", clock.stamp(t)}};
  for (size_t l = 0; l < model.legs.size(); ++l) {
    const robot::LegModel& leg = model.legs[l];
    const collision::LegTorqueSeries* torque = nullptr;
    for (const auto& s : checks.torque.legs)
      if (s.leg == leg.name) torque = &s;
    json joints = json::object();
    for (int j = 0; j < 3; ++j) {
      json v = {{"torque_limit", leg.torque_limit[j]}, {"velocity_limit", leg.velocity_limit[j]}};
      if (l < checks.kinematics.legs.size() && k < checks.kinematics.legs[l].size() &&
          checks.kinematics.legs[l][k].has_q()) {
        set_finite(v, "angle", checks.kinematics.legs[l][k].q[j]);
        set_finite(v, "velocity", checks.kinematics.legs[l][k].qd[j]);
      }
      if (torque && k < torque->tau.size()) {
        set_finite(v, "torque", torque->tau[k][j]);
        set_finite(v, "torque_ratio", torque->ratio[k][j]);
      }
      joints[kJointNames[j]] = std::move(v);
    }
    msg[leg.name] = std::move(joints);
  }
  return msg;
}

// The checks' findings at the time they occur: joints over their torque limit (the first sample
// of each leg and joint), shins, thighs and trunk touching the map, unsafe footholds; and the
// verdict at t = 0.
void publish_plan_logs(Publisher& pub, const Clock& clock, const planner::Trajectory& traj,
                       const collision::CheckReport& checks, RobotTopicStats* stats) {
  const uint16_t ch = pub.channel("/log", "foxglove.Log");
  const auto log = [&](double t, int level, const std::string& text) {
    pub.publish(ch, clock.ns(clock.plan(t)),
                log_message(clock, clock.plan(t), level, "checks", text));
    ++stats->logs;
  };
  const std::vector<std::string> failures = checks.failures();
  log(0, failures.empty() ? 2 : 4,
      failures.empty() ? "post-hoc checks: all pass"
                       : "post-hoc checks: " + std::to_string(failures.size()) + " failed");
  for (const auto& f : failures) log(0, 4, f);
  for (const auto& leg : checks.torque.legs)
    for (int j = 0; j < 3; ++j)
      for (size_t k = 0; k < leg.ratio.size(); ++k)
        if (leg.ratio[k][j] > 1.0 + 1e-9) {
          log(checks.torque.time[k], 3,
              leg.leg + " " + kJointNames[j] +
                  format(" torque %.1f N m is %.2fx its limit", leg.tau[k][j], leg.ratio[k][j]));
          break;
        }
  if (checks.clearance)
    for (const auto& leg : checks.clearance->legs) {
      if (leg.first_certain_collision_t >= 0)
        log(leg.first_certain_collision_t, 4,
            leg.leg + " shin/thigh: certain collision with the map");
      else if (leg.first_collision_t >= 0)
        log(leg.first_collision_t, 3,
            leg.leg + " shin/thigh touches occupied voxels (within the map's uncertainty)");
    }
  if (checks.trunk && checks.trunk->first_collision_t >= 0)
    log(checks.trunk->first_collision_t, checks.trunk->first_certain_collision_t >= 0 ? 4 : 3,
        "trunk touches the map" +
            std::string(checks.trunk->overhang.empty() ? "" : ": " + checks.trunk->overhang));
  if (checks.footholds)
    for (const auto& f : checks.footholds->footholds)
      if (f.margin < 0)
        log(f.t_start, 3, traj.feet[f.leg] + format(" foothold unsafe: margin %.3f m", f.margin));
}

// /plan/verdict at t = 0 and at the end: every number of the checks (plan.json "checks").
void publish_plan_verdict(Publisher& pub, const Clock& clock, const planner::Trajectory& traj,
                          const collision::CheckReport& checks) {
  const auto keys = checks.keys();
  json props = {{"timestamp", time_schema()},
                {"passed", number_schema("1 when every post-hoc check passes")},
                {"failures", number_schema("failed checks")}};
  for (const auto& [k, v] : keys) props[k] = number_schema(k);
  pub.add_schema("terrastride.PlanVerdict", object_schema("terrastride.PlanVerdict", props,
                                                          {"timestamp", "passed", "failures"}));
  const uint16_t ch = pub.channel("/plan/verdict", "terrastride.PlanVerdict");
  const double end = traj.samples.empty() ? 0.0 : traj.samples.back().t;
  for (double t : {0.0, end}) {
    json msg = {{"timestamp", clock.stamp(clock.plan(t))},
                {"passed", checks.passed() ? 1 : 0},
                {"failures", checks.failures().size()}};
    for (const auto& [k, v] : keys) set_finite(msg, k.c_str(), v);
    pub.publish(ch, clock.ns(clock.plan(t)), msg);
  }
}

}  // namespace

RobotTopicStats publish_plan(Publisher& pub, const Clock& clock, const robot::RobotModel& model,
                             const planner::Trajectory& traj, const collision::CheckReport& checks,
                             const report::TerrainView& view, double friction) {
  RobotTopicStats stats;
  const uint16_t tf = pub.channel("/tf", "foxglove.FrameTransforms");
  const uint16_t robot_ch = pub.channel("/plan/robot", "foxglove.SceneUpdate");
  const uint16_t force_ch = pub.channel("/plan/contact_forces", "foxglove.SceneUpdate",
                                        {{"arrow_m_per_N", std::to_string(kArrowMetresPerNewton)}});
  const uint16_t joints_ch = pub.channel("/plan/joints", "terrastride.JointStates");
  const uint16_t feet_ch =
      pub.channel("/plan/feet", "terrastride.FootStates", {{"friction", std::to_string(friction)}});
  publish_plan_overviews(pub, clock, traj, checks, &stats);
  const auto* clearance = checks.clearance ? &*checks.clearance : nullptr;
  json contacts = entity(clock, 0, "shin_contacts");
  for (size_t k = 0; k < traj.samples.size(); ++k) {
    const auto& s = traj.samples[k];
    const double t = clock.plan(s.t);
    std::vector<Eigen::Vector3d> feet, forces;
    std::vector<bool> contact;
    for (const auto& f : s.feet) {
      feet.push_back(f.position);
      forces.push_back(f.force);
      contact.push_back(f.contact);
    }
    const RobotPose p = robot_pose(model, s.base.position, s.base.euler_zyx, feet);
    std::vector<json> shin_colors;
    json foot_states = {{"timestamp", clock.stamp(t)}};
    for (size_t l = 0; l < feet.size(); ++l) {
      int v = 0;  // the leg-capsule check's verdict: 0 clear, 1 possible, 2 certain
      if (clearance && l < clearance->legs.size() && k < clearance->legs[l].shin_verdict.size())
        v = static_cast<int>(clearance->legs[l].shin_verdict[k]);
      shin_colors.push_back(v == 2   ? color(0.9, 0.1, 0.1)
                            : v == 1 ? color(1.0, 0.6, 0.0)
                                     : color(0.35, 0.35, 0.4));
      if (v > 0) {
        const Eigen::Vector3d knee = p.base + p.R * p.frames[l].origin[2];
        contacts["spheres"].push_back(sphere(0.5 * (knee + feet[l]), 0.03, shin_colors.back()));
        ++stats.shin_contacts;
      }
      foot_states[model.legs[l].name] =
          foot_state(model, l, feet[l], forces[l], contact[l], p, view.field.get(), friction);
    }
    pub.publish(tf, clock.ns(t), {{"transforms", robot_transforms(clock, t, "", model, p)}});
    pub.publish(
        robot_ch, clock.ns(t),
        robot_entities(clock, t, "", model, p, color(0.85, 0.85, 0.9, 0.6), shin_colors, contact));
    pub.publish(
        force_ch, clock.ns(t),
        force_entities(clock, t, "plan_forces", feet, forces, contact, color(0.95, 0.45, 0.1)));
    pub.publish(joints_ch, clock.ns(t), plan_joints(clock, t, model, checks, k));
    pub.publish(feet_ch, clock.ns(t), foot_states);
  }
  pub.publish(pub.channel("/plan/shin_contacts", "foxglove.SceneUpdate"), clock.ns(0),
              scene_update(json::array({contacts})));
  publish_plan_verdict(pub, clock, traj, checks);
  publish_plan_logs(pub, clock, traj, checks, &stats);
  return stats;
}

namespace {

Eigen::Vector3d v3(const json& a, const std::string& path) {
  if (!a.is_array() || a.size() != 3 || !a[0].is_number() || !a[1].is_number() || !a[2].is_number())
    throw CommandError("--sim " + path + ": a 3-vector expected, got " + a.dump());
  return {a[0].get<double>(), a[1].get<double>(), a[2].get<double>()};
}

// /sim/joints: the joint angles (IK of the simulated feet) and MuJoCo's motor torques.
json sim_joints(const Clock& clock, double t, const robot::RobotModel& model, const json& s,
                const RobotPose& p, const std::string& path) {
  json msg = {{"timestamp", clock.stamp(t)}};
  for (size_t l = 0; l < model.legs.size(); ++l) {
    const robot::LegModel& leg = model.legs[l];
    const json& foot = s["feet"][l];
    const Eigen::Vector3d tau = foot.contains("joint_torque") ? v3(foot["joint_torque"], path)
                                                              : Eigen::Vector3d::Constant(NAN);
    json joints = json::object();
    for (int j = 0; j < 3; ++j) {
      json v = {{"torque_limit", leg.torque_limit[j]}, {"velocity_limit", leg.velocity_limit[j]}};
      set_finite(v, "angle", p.q[l][j]);
      set_finite(v, "torque", tau[j]);
      if (leg.torque_limit[j] > 0)
        set_finite(v, "torque_ratio", std::abs(tau[j]) / leg.torque_limit[j]);
      joints[kJointNames[j]] = std::move(v);
    }
    msg[leg.name] = std::move(joints);
  }
  return msg;
}

json sim_tracking(const Clock& clock, double t, const json& s, const std::string& path) {
  const Eigen::Vector3d e =
      v3(s["base"]["position"], path) - v3(s["planned_base"]["position"], path);
  const Eigen::Vector3d a =
      v3(s["base"]["euler_zyx"], path) - v3(s["planned_base"]["euler_zyx"], path);
  json msg = {{"timestamp", clock.stamp(t)},
              {"position_error", vec3(e)},
              {"position_error_norm", e.norm()}};
  const auto wrap = [](double x) { return std::remainder(x, 2 * M_PI); };
  set_finite(msg, "yaw_error", wrap(a[0]));
  set_finite(msg, "pitch_error", wrap(a[1]));
  set_finite(msg, "roll_error", wrap(a[2]));
  return msg;
}

// The simulation's findings at their time (a fall, instability, slipping and missed stances) and
// its verdict at the end, on /log; its numbers (sim.json's top-level figures) on /sim/verdict.
void publish_sim_verdict(Publisher& pub, const Clock& clock, const json& sim, double end,
                         RobotTopicStats* stats) {
  const uint16_t log_ch = pub.channel("/log", "foxglove.Log");
  const auto log = [&](double t, int level, const std::string& text) {
    pub.publish(log_ch, clock.ns(clock.plan(t)),
                log_message(clock, clock.plan(t), level, "simulation", text));
    ++stats->logs;
  };
  const auto number = [&](const char* key) {
    return sim.contains(key) && sim[key].is_number() ? sim[key].get<double>() : NAN;
  };
  if (sim.value("fell", false) && std::isfinite(number("fall_t")))
    log(number("fall_t"), 4, "the robot fell");
  if (sim.value("unstable", false) && std::isfinite(number("unstable_t")))
    log(number("unstable_t"), 4, "the simulation became unstable");
  const double slip_limit =
      sim.contains("thresholds") ? sim["thresholds"].value("slip_m", 0.05) : 0.05;
  if (sim.contains("stances") && sim["stances"].is_array())
    for (const json& st : sim["stances"]) {
      const double t_end = st.value("t_end", 0.0);
      if (!st.value("touched_down", true))
        log(st.value("t_start", 0.0), 3,
            st.value("foot", std::string("?")) + " missed its touch-down");
      if (st.value("slip_m", 0.0) > slip_limit)
        log(t_end, 3,
            st.value("foot", std::string("?")) + format(" slipped %.3f m in stance (limit %.3f m)",
                                                        st.value("slip_m", 0.0), slip_limit));
    }
  const std::string verdict = sim.value("verdict", std::string("unknown"));
  std::string reasons;
  if (sim.contains("reasons") && sim["reasons"].is_array())
    for (const json& r : sim["reasons"])
      reasons +=
          (reasons.empty() ? ": " : "; ") + (r.is_string() ? r.get<std::string>() : r.dump());
  log(end,
      verdict == "pass"   ? 2
      : verdict == "fail" ? 4
                          : 3,
      "simulation verdict " + verdict + reasons);

  json props = {{"timestamp", time_schema()},
                {"passed", number_schema("1 when the verdict is pass")}};
  json msg = {{"passed", verdict == "pass" ? 1 : 0}};
  for (const auto& [k, v] : sim.items())
    if (v.is_number() && std::isfinite(v.get<double>())) {
      props[k] = number_schema(k);
      msg[k] = v;
    } else if (v.is_boolean()) {
      props[k] = number_schema(k + " (1 true)");
      msg[k] = v.get<bool>() ? 1 : 0;
    }
  pub.add_schema("terrastride.SimulationVerdict",
                 object_schema("terrastride.SimulationVerdict", props, {"timestamp", "passed"}));
  const uint16_t ch = pub.channel("/sim/verdict", "terrastride.SimulationVerdict");
  for (double t : {0.0, end}) {
    msg["timestamp"] = clock.stamp(clock.plan(t));
    pub.publish(ch, clock.ns(clock.plan(t)), msg);
  }
}

}  // namespace

RobotTopicStats publish_simulation(Publisher& pub, const Clock& clock,
                                   const robot::RobotModel& model, const json& sim,
                                   const std::string& path, const terrain::HeightField* field,
                                   double friction) {
  RobotTopicStats stats;
  const uint16_t tf = pub.channel("/tf", "foxglove.FrameTransforms");
  const uint16_t robot_ch = pub.channel("/sim/robot", "foxglove.SceneUpdate");
  const uint16_t force_ch = pub.channel("/sim/contact_forces", "foxglove.SceneUpdate",
                                        {{"arrow_m_per_N", std::to_string(kArrowMetresPerNewton)}});
  const uint16_t joints_ch = pub.channel("/sim/joints", "terrastride.JointStates");
  const uint16_t feet_ch = pub.channel("/sim/feet", "terrastride.FootStates");
  const uint16_t track_ch = pub.channel("/sim/tracking", "terrastride.Tracking");
  const uint16_t log_ch = pub.channel("/log", "foxglove.Log");
  std::vector<std::array<bool, 3>> saturated(model.legs.size(), {false, false, false});
  double end = 0.0;
  try {
    for (const json& s : sim["samples"]) {
      const double t = clock.plan(s["t"].get<double>());
      end = s["t"].get<double>();
      std::vector<Eigen::Vector3d> feet, forces;
      std::vector<bool> contact;
      for (const json& f : s["feet"]) {
        feet.push_back(v3(f["position"], path));
        forces.push_back(v3(f["force"], path));
        contact.push_back(f["contact"].get<bool>());
      }
      const RobotPose p = robot_pose(model, v3(s["base"]["position"], path),
                                     v3(s["base"]["euler_zyx"], path), feet);
      json foot_states = {{"timestamp", clock.stamp(t)}};
      for (size_t l = 0; l < feet.size(); ++l) {
        const json& f = s["feet"][l];
        json st = foot_state(model, l, feet[l], forces[l], contact[l], p, field, friction);
        st["planned_contact"] = f.value("planned_contact", false) ? 1 : 0;
        if (f.contains("shin_force") && f["shin_force"].is_number())
          set_finite(st, "shin_force", f["shin_force"].get<double>());
        foot_states[model.legs[l].name] = std::move(st);
      }
      pub.publish(tf, clock.ns(t), {{"transforms", robot_transforms(clock, t, "sim_", model, p)}});
      pub.publish(
          robot_ch, clock.ns(t),
          robot_entities(clock, t, "sim_", model, p, color(0.3, 0.5, 0.95, 0.5), {}, contact));
      pub.publish(
          force_ch, clock.ns(t),
          force_entities(clock, t, "sim_forces", feet, forces, contact, color(0.2, 0.4, 1.0)));
      const json joints = sim_joints(clock, t, model, s, p, path);
      for (size_t l = 0; l < model.legs.size(); ++l)  // the first time each motor saturates
        for (int j = 0; j < 3; ++j) {
          const json& v = joints[model.legs[l].name][kJointNames[j]];
          if (saturated[l][j] || !v.contains("torque_ratio") ||
              v["torque_ratio"].get<double>() < 1.0 - 1e-6)
            continue;
          saturated[l][j] = true;
          pub.publish(log_ch, clock.ns(t),
                      log_message(clock, t, 3, "simulation",
                                  model.legs[l].name + " " + kJointNames[j] +
                                      format(" motor at its torque limit (%.1f N m)",
                                             model.legs[l].torque_limit[j])));
          ++stats.logs;
        }
      pub.publish(joints_ch, clock.ns(t), joints);
      pub.publish(feet_ch, clock.ns(t), foot_states);
      if (s.contains("planned_base"))
        pub.publish(track_ch, clock.ns(t), sim_tracking(clock, t, s, path));
    }
  } catch (const json::exception& e) {
    throw CommandError("--sim " + path + ": " + e.what());
  }
  publish_sim_verdict(pub, clock, sim, end, &stats);
  return stats;
}

}  // namespace terrastride::service::foxglove
