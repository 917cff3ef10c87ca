// The report's "Simulated execution" section (sections.hpp): the plan run in MuJoCo by
// simulation::simulate_plan, as tracking error over time, torques against the limits, contact
// events and the verdict.
#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "report/sections.hpp"
#include "terrastride/simulation/simulation.hpp"

namespace terrastride::service::report {
namespace {

using nlohmann::json;

constexpr const char* kSource =
    "simulation::simulate_plan (MuJoCo, model generated from the robot file, tracking controller)";

// Contact events from the recorded samples: maximal runs of samples with force on one part.
struct Event {
  std::string part;
  double t_start, t_end, peak_N;
};

void collect_events(const std::vector<simulation::SimulationSample>& samples, double dt,
                    const std::string& part, const std::function<double(size_t)>& force,
                    std::vector<Event>* events) {
  bool open = false;
  for (size_t k = 0; k < samples.size(); ++k) {
    const double f = force(k);
    if (f > 0) {
      if (!open) events->push_back({part, samples[k].t, samples[k].t + dt, 0.0});
      open = true;
      events->back().t_end = samples[k].t + dt;
      events->back().peak_N = std::max(events->back().peak_N, f);
    } else {
      open = false;
    }
  }
}

// The verdict's rows in the plan's summary; a fail is a problem, a warn a note.
void verdict_rows(const PlanSections& s, const std::string& verdict,
                  const std::vector<std::string>& reasons, const std::string& where) {
  const std::string status = verdict == "pass" ? "ok" : verdict == "warn" ? "note" : "problem";
  std::string note = reasons.empty() ? "within every threshold" : reasons.front();
  if (reasons.size() > 1) note += " (and " + std::to_string(reasons.size() - 1) + " more)";
  s.summary.push_back(row("simulated execution (MuJoCo)", verdict, "", status, note + where));
  if (verdict == "fail")
    s.problems.push_back(problem("simulation_fail", s.input.name,
                                 "the plan fails in simulated execution: " +
                                     (reasons.empty() ? std::string("fall") : reasons.front())));
}

// The section of a plan that was not simulated here: the verdict its plan file recorded, or why
// there is none.
json unsimulated_section(const PlanSections& s) {
  // A verdict plan.json recorded (`plan --simulate`, `check --simulate` do not write it back).
  const json& extra = s.input.trajectory.extra;
  if (extra.contains("post_hoc") && extra["post_hoc"].contains("simulation") &&
      extra["post_hoc"]["simulation"].contains("verdict")) {
    const json& rec = extra["post_hoc"]["simulation"];
    const auto reasons = rec.value("reasons", std::vector<std::string>{});
    verdict_rows(s, rec["verdict"].get<std::string>(), reasons, " (recorded in the plan file)");
    return {{"recorded", rec},
            {"absent",
             "the series are not in the plan file: run 'terrastride report --simulate' to "
             "simulate the plan on this terrain"}};
  }
  if (!s.simulation_error.empty())
    return {{"absent", "the simulation could not run the plan: " + s.simulation_error}};
  return {{"absent",
           "the plan was not simulated (run 'terrastride report --simulate', or plan with "
           "--simulate)"}};
}

// The plotted series, at most some 1500 points of each: tracking errors over time, and per leg
// the torque ratio to the limits and the actual and planned contact.
struct Series {
  json time = json::array(), position_error = json::array(), tilt_error = json::array(),
       height_error = json::array();
  std::vector<json> torque_ratio, contact, planned;
};

Series plotted_series(const simulation::SimulationReport& r, const robot::RobotModel& model) {
  const size_t n_legs = model.legs.size();
  const size_t stride = std::max<size_t>(1, r.samples.size() / 1500);
  Series out;
  out.torque_ratio.assign(n_legs, json::array());
  out.contact.assign(n_legs, json::array());
  out.planned.assign(n_legs, json::array());
  for (size_t k = 0; k < r.samples.size(); k += stride) {
    const auto& smp = r.samples[k];
    out.time.push_back(num(smp.t, 3));
    out.position_error.push_back(num((smp.base_position - smp.planned_position).norm(), 4));
    out.height_error.push_back(num(smp.base_position.z() - smp.planned_position.z(), 4));
    // Orientation error from the ZYX angles (the report shows degrees).
    const Eigen::Vector3d de = smp.base_euler_zyx - smp.planned_euler_zyx;
    Eigen::Vector3d wrapped;
    for (int a = 0; a < 3; ++a) wrapped[a] = std::remainder(de[a], 2 * M_PI);
    out.tilt_error.push_back(num(wrapped.cwiseAbs().maxCoeff() * 180.0 / M_PI, 2));
    for (size_t i = 0; i < n_legs && i < smp.joint_torque.size(); ++i) {
      double ratio = 0.0;
      for (int j = 0; j < 3; ++j)
        ratio = std::max(ratio, std::abs(smp.joint_torque[i][j]) / model.legs[i].torque_limit[j]);
      out.torque_ratio[i].push_back(num(ratio, 3));
      out.contact[i].push_back(smp.foot_contact[i] ? 1 : 0);
      out.planned[i].push_back(smp.planned_contact[i] ? 1 : 0);
    }
  }
  return out;
}

// Contact events of the parts that should not touch (shins, thighs, trunk), over the full-rate
// samples, in time order.
std::vector<Event> body_contact_events(const simulation::SimulationReport& r,
                                       const robot::RobotModel& model) {
  const double record_dt =
      r.samples.size() > 1 ? r.samples[1].t - r.samples[0].t : std::max(r.dt, 1e-3);
  std::vector<Event> events;
  for (size_t i = 0; i < model.legs.size(); ++i) {
    collect_events(
        r.samples, record_dt, model.legs[i].name + " shin",
        [&](size_t k) { return r.samples[k].shin_force[i]; }, &events);
    collect_events(
        r.samples, record_dt, model.legs[i].name + " thigh",
        [&](size_t k) { return r.samples[k].thigh_force[i]; }, &events);
  }
  collect_events(
      r.samples, record_dt, "trunk", [&](size_t k) { return r.samples[k].trunk_force; }, &events);
  std::sort(events.begin(), events.end(),
            [](const Event& a, const Event& b) { return a.t_start < b.t_start; });
  return events;
}

json events_json(const std::vector<Event>& events) {
  json event_list = json::array();
  for (const auto& e : events)
    event_list.push_back({{"part", e.part},
                          {"t_start", num(e.t_start, 3)},
                          {"t_end", num(e.t_end, 3)},
                          {"duration_s", num(e.t_end - e.t_start, 3)},
                          {"peak_force_N", num(e.peak_N, 1)}});
  return event_list;
}

// Foot events: stances that touched down late or early, or not at all.
json stances_json(const simulation::SimulationReport& r, const robot::RobotModel& model) {
  json stances = json::array();
  for (const auto& st : r.stances)
    stances.push_back({{"foot", model.legs[st.foot].name},
                       {"t_start", num(st.t_start, 3)},
                       {"t_end", num(st.t_end, 3)},
                       {"touchdown_t", st.touched_down ? num(st.touchdown_t, 3) : json()},
                       {"touchdown_error_m", num(st.touchdown_error, 4)},
                       {"slip_m", num(st.slip, 4)}});
  return stances;
}

json legs_json(const simulation::SimulationReport& r, const robot::RobotModel& model,
               const Series& series) {
  json legs = json::array();
  for (size_t i = 0; i < model.legs.size() && i < r.torque_max.size(); ++i)
    legs.push_back({{"name", model.legs[i].name},
                    {"torque_ratio", series.torque_ratio[i]},
                    {"contact", series.contact[i]},
                    {"planned_contact", series.planned[i]},
                    {"torque_max_Nm", vec3(r.torque_max[i], 1)},
                    {"torque_limit_Nm", vec3(model.legs[i].torque_limit, 1)},
                    {"saturated_s", vec3(r.saturated_time[i], 3)},
                    {"shin_impulse_Ns", num(r.shin_impulse[i], 3)},
                    {"thigh_impulse_Ns", num(r.thigh_impulse[i], 3)}});
  return legs;
}

// The run's rows in the plan's summary: the verdict, tracking, saturation and shin contact.
void summary_rows(const PlanSections& s, const simulation::SimulationReport& r,
                  size_t n_events) {
  const auto& th = r.thresholds;
  verdict_rows(s, r.verdict, r.reasons, "");
  s.summary.push_back(
      row("simulated base position error RMS / max",
          fmt(r.position_rms * 1000, 1) + " / " + fmt(r.position_max * 1000, 1), "mm",
          r.position_rms > th.position_rms_m || r.position_max > th.position_max_m ? "note" : "ok",
          "limits " + fmt(th.position_rms_m * 1000, 0) + " / " + fmt(th.position_max_m * 1000, 0) +
              " mm"));
  s.summary.push_back(row("simulated torque saturation", num(100 * r.saturation_fraction, 2), "%",
                          r.saturation_fraction > th.saturation_fraction ? "note" : "ok",
                          "of the time with a joint at its limit (limit " +
                              fmt(100 * th.saturation_fraction, 1) + " %)"));
  s.summary.push_back(row("simulated shin contact impulse (worst leg)", num(r.shin_impulse_max, 3),
                          "N s", r.shin_impulse_max >= th.shin_impulse_Ns ? "note" : "ok",
                          std::to_string(n_events) +
                              " contact events of shins, thighs or "
                              "trunk (limit " +
                              fmt(th.shin_impulse_Ns, 1) + " N s)"));
}

}  // namespace

json simulation_section(const PlanSections& s) {
  const simulation::SimulationReport* sim = s.simulation;
  if (!s.simulation_error.empty())
    s.summary.push_back(
        row("simulated execution (MuJoCo)", "not run", "", "note", s.simulation_error));
  if (!sim) return unsimulated_section(s);
  const simulation::SimulationReport& r = *sim;
  const Series series = plotted_series(r, s.model);
  const std::vector<Event> events = body_contact_events(r, s.model);
  const auto& th = r.thresholds;
  json out = {{"source", kSource},
              {"terrain", r.terrain},
              {"verdict", r.verdict},
              {"reasons", r.reasons},
              {"fell", r.fell},
              {"fall_t", r.fell ? num(r.fall_t, 3) : json()},
              {"dt", r.dt},
              {"duration_s", num(r.duration, 3)},
              {"realtime_factor", num(r.realtime_factor, 1)},
              {"time", series.time},
              {"position_error_m", series.position_error},
              {"height_error_m", series.height_error},
              {"orientation_error_deg", series.tilt_error},
              {"legs", legs_json(r, s.model, series)},
              {"contact_events", events_json(events)},
              {"stances", stances_json(r, s.model)},
              {"position_error_rms_m", num(r.position_rms, 4)},
              {"position_error_max_m", num(r.position_max, 4)},
              {"saturation_fraction", num(r.saturation_fraction, 4)},
              {"slip_max_m", num(r.slip_max, 4)},
              {"touchdown_error_max_m", num(r.touchdown_error_max, 4)},
              {"missed_touchdowns", r.missed_touchdowns},
              {"shin_impulse_max_Ns", num(r.shin_impulse_max, 3)},
              {"trunk_impulse_Ns", num(r.trunk_impulse, 3)},
              {"thresholds",
               {{"position_rms_m", th.position_rms_m},
                {"position_max_m", th.position_max_m},
                {"saturation_fraction", th.saturation_fraction},
                {"slip_m", th.slip_m},
                {"touchdown_error_m", th.touchdown_error_m},
                {"shin_impulse_Ns", th.shin_impulse_Ns},
                {"fall_height_m", th.fall_height_m}}}};
  summary_rows(s, r, events.size());
  return out;
}

}  // namespace terrastride::service::report
