#include "common/simulation_run.hpp"

#include <cmath>

namespace terrastride::service {
namespace {

using nlohmann::json;

json vec(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

json side_json(const simulation::MarginSide& s, const char* unit) {
  json out = {{"survived", s.survived}, {"unit", unit}};
  out["failed"] = s.failed >= 0 ? json(s.failed) : json();
  if (!s.failure.empty()) out["failure"] = s.failure;
  return out;
}

}  // namespace

json simulation_summary_json(const simulation::SimulationReport& r, const robot::RobotModel& model) {
  const auto& th = r.thresholds;
  json legs = json::array();
  for (size_t i = 0; i < model.legs.size() && i < r.torque_max.size(); ++i)
    legs.push_back({{"leg", model.legs[i].name},
                    {"torque_max_Nm", vec(r.torque_max[i])},
                    {"torque_limit_Nm", vec(model.legs[i].torque_limit)},
                    {"saturated_s", vec(r.saturated_time[i])},
                    {"joint_limit_s", vec(r.joint_limit_time[i])},
                    {"joint_limit_impulse_Nms", vec(r.joint_limit_impulse[i])},
                    {"shin_impulse_Ns", r.shin_impulse[i]},
                    {"thigh_impulse_Ns", r.thigh_impulse[i]}});
  json stances = json::array();
  for (const auto& s : r.stances)
    stances.push_back({{"foot", model.legs[s.foot].name},
                       {"t_start", s.t_start},
                       {"t_end", s.t_end},
                       {"touched_down", s.touched_down},
                       {"touchdown_t", s.touched_down ? json(s.touchdown_t) : json()},
                       {"touchdown_error_m", s.touchdown_error},
                       {"slip_m", s.slip},
                       {"centre_drift_m", s.centre_drift}});
  json out = {{"terrain", r.terrain},
          {"verdict", r.verdict},
          {"reasons", r.reasons},
          {"fell", r.fell},
          {"heightfield_filled_cells", r.filled_cells},
          {"fall_t", r.fell ? json(r.fall_t) : json()},
          {"unstable", r.unstable},
          {"unstable_t", r.unstable ? json(r.unstable_t) : json()},
          {"dt", r.dt},
          {"duration", r.duration},
          {"steps", r.steps},
          {"wall_s", r.wall_s},
          {"realtime_factor", r.realtime_factor},
          {"physics_wall_s", r.physics_wall_s},
          {"cpu_s", r.cpu_s},
          {"position_error_rms_m", r.position_rms},
          {"position_error_max_m", r.position_max},
          {"position_error_max_t", r.position_max_t},
          {"tilt_error_max_rad", r.tilt_max},
          {"height_drop_max_m", r.height_drop_max},
          {"saturation_fraction", r.saturation_fraction},
          {"joint_limit_impulse_max_Nms", r.joint_limit_impulse_max},
          {"joint_limit_max_s", r.joint_limit_max_s},
          {"slip_max_m", r.slip_max},
          {"centre_drift_max_m", r.centre_drift_max},
          {"touchdown_error_max_m", r.touchdown_error_max},
          {"missed_touchdowns", r.missed_touchdowns},
          {"shin_impulse_max_Ns", r.shin_impulse_max},
          {"trunk_impulse_Ns", r.trunk_impulse},
          {"legs", legs},
          {"stances", stances},
          {"controller_gains",
           {{"kp_position", r.gains.kp_position},
            {"kd_position", r.gains.kd_position},
            {"kp_orientation", r.gains.kp_orientation},
            {"kd_orientation", r.gains.kd_orientation},
            {"kp_swing", r.gains.kp_swing},
            {"kd_swing", r.gains.kd_swing},
            {"kp_stance", r.gains.kp_stance},
            {"kd_stance", r.gains.kd_stance}}},
          {"thresholds",
           {{"fall_height_m", th.fall_height_m},
            {"fall_tilt_deg", th.fall_tilt_rad * 180.0 / M_PI},
            {"body_contact_impulse_Ns", th.body_contact_impulse_Ns},
            {"position_rms_m", th.position_rms_m},
            {"position_max_m", th.position_max_m},
            {"saturation_fraction", th.saturation_fraction},
            {"slip_m", th.slip_m},
            {"touchdown_error_m", th.touchdown_error_m},
            {"shin_impulse_Ns", th.shin_impulse_Ns},
            {"joint_limit_impulse_Nms", th.joint_limit_impulse_Nms}}}};
  if (r.replans > 0)
    out["closed_loop"] = {{"replans", r.replans},
                          {"replan_failures", r.replan_failures},
                          {"first_failure", r.replan_first_failure.empty()
                                                ? json()
                                                : json(r.replan_first_failure)},
                          {"planner_wall_median_s", r.replan_wall_median},
                          {"planner_wall_max_s", r.replan_wall_max},
                          {"planner_cpu_median_s", r.replan_cpu_median},
                          {"planner_cpu_max_s", r.replan_cpu_max},
                          {"planner_wall_total_s", [&] {
                             double sum = 0.0;
                             for (double w : r.replan_wall_s) sum += w;
                             return sum;
                           }()},
                          {"planner_iterations_median", r.replan_iterations_median},
                          {"planner_iterations_max", r.replan_iterations_max},
                          {"failure_times", r.replan_failure_times},
                          {"reference_position_max_m", r.reference_position_max},
                          {"fallbacks", r.replan_fallbacks},
                          {"steps", [&] {
                             json steps = json::array();
                             for (const auto& s : r.replan_records) {
                               json step = {{"t", s.t},
                                            {"wall_ms", 1e3 * s.wall_s},
                                            {"iterations", s.iterations},
                                            {"fallback", s.fallback.empty() ? json()
                                                                            : json(s.fallback)}};
                               // The schedule the step adapted, why it fell back or failed.
                               for (const char* key :
                                    {"capture_step", "touchdowns", "held_liftoffs", "disturbance",
                                     "fallback_message", "failure"})
                                 if (s.session.is_object() && s.session.contains(key))
                                   step[key] = s.session[key];
                               steps.push_back(std::move(step));
                             }
                             return steps;
                           }()}};
  return out;
}

json simulation_samples_json(const simulation::SimulationReport& r, const robot::RobotModel& model) {
  json out = json::array();
  for (const auto& s : r.samples) {
    json feet = json::array();
    for (size_t i = 0; i < model.legs.size(); ++i)
      feet.push_back({{"contact", static_cast<bool>(s.foot_contact[i])},
                      {"planned_contact", static_cast<bool>(s.planned_contact[i])},
                      {"force", vec(s.foot_force[i])},
                      {"position", vec(s.foot_position[i])},
                      {"joint_torque", vec(s.joint_torque[i])},
                      {"shin_force", s.shin_force[i]},
                      {"thigh_force", s.thigh_force[i]}});
    out.push_back(
        {{"t", s.t},
         {"base", {{"position", vec(s.base_position)}, {"euler_zyx", vec(s.base_euler_zyx)}}},
         {"planned_base",
          {{"position", vec(s.planned_position)}, {"euler_zyx", vec(s.planned_euler_zyx)}}},
         {"feet", feet},
         {"trunk_force", s.trunk_force}});
  }
  return out;
}

json margin_json(const simulation::MarginReport& m) {
  json out = {{"nominal_verdict", m.nominal_verdict},
              {"criterion", "survives = simulation verdict not 'fail'"},
              {"push",
               {{"t", m.push_t},
                {"duration_s", m.push_duration},
                {"time_fraction", m.options.push_time_fraction},
                {"left_direction", vec(m.left)},
                {"convention",
                 "constant horizontal force on the trunk origin, perpendicular to the planned "
                 "heading at its start, for duration_s from t; left and right searched"},
                {"left", side_json(m.push_left, "N")},
                {"right", side_json(m.push_right, "N")},
                {"margin_N", m.push_margin_N},
                {"margin_Ns", m.push_margin_Ns},
                {"at_ceiling", m.push_at_ceiling},
                {"ceiling_N", m.options.push_force_max},
                {"tolerance_N", m.options.push_tolerance}}},
              {"runs", m.runs},
              {"wall_s", m.wall_s}};
  if (m.mass_searched)
    out["mass"] = {{"heavier", side_json(m.mass_heavier, "mass scale")},
                   {"lighter", side_json(m.mass_lighter, "mass scale")},
                   {"limits", {m.options.mass_scale_min, m.options.mass_scale_max}},
                   {"tolerance", m.options.mass_tolerance}};
  return out;
}

double verdict_code(const std::string& verdict) {
  if (verdict == "pass") return 0.0;
  if (verdict == "warn") return 1.0;
  return 2.0;
}

std::vector<std::string> add_simulation_check(const robot::RobotModel& model,
                                              const terrain::HeightField& terrain,
                                              const simulation::SimulationOptions& options,
                                              planner::Trajectory* traj,
                                              simulation::SimulationReport* report) {
  json& post_hoc = traj->extra["post_hoc"];
  if (!post_hoc.is_object()) post_hoc = json::object();
  if (!post_hoc.contains("failures")) post_hoc["failures"] = json::array();
  simulation::SimulationReport rep;
  try {
    rep = simulation::simulate_plan(model, *traj, terrain, options);
  } catch (const simulation::SimulationError& e) {
    const std::string failure = std::string("the simulation could not run the plan: ") + e.what();
    post_hoc["simulation"] = {{"error", e.what()}};
    post_hoc["failures"].push_back(failure);
    return {failure};
  }
  auto& c = traj->checks;
  c["sim_verdict"] = verdict_code(rep.verdict);
  c["sim_position_error_rms_m"] = rep.position_rms;
  c["sim_position_error_max_m"] = rep.position_max;
  c["sim_tilt_error_max_rad"] = rep.tilt_max;
  c["sim_saturation_fraction"] = rep.saturation_fraction;
  c["sim_slip_max_m"] = rep.slip_max;
  c["sim_touchdown_error_max_m"] = rep.touchdown_error_max;
  c["sim_missed_touchdowns"] = rep.missed_touchdowns;
  c["sim_shin_impulse_max_Ns"] = rep.shin_impulse_max;
  c["sim_joint_limit_impulse_max_Nms"] = rep.joint_limit_impulse_max;
  json summary = simulation_summary_json(rep, model);
  summary.erase("stances");  // per-stance figures: `simulate --json`; plan.json keeps the verdict
  post_hoc["simulation"] = summary;
  std::vector<std::string> failures;
  if (rep.verdict == "fail") {
    failures.push_back("simulated execution fails: " +
                       (rep.reasons.empty() ? std::string("fall") : rep.reasons.front()));
    post_hoc["failures"].push_back(failures.back());
  }
  if (report) *report = std::move(rep);
  return failures;
}

}  // namespace terrastride::service
