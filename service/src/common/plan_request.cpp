#include "common/plan_request.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/level_reach.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {

using nlohmann::json;

namespace {

const json* find(const json& fields, const char* name) {
  const auto it = fields.find(name);
  return it == fields.end() || it->is_null() ? nullptr : &*it;
}

double number(const json& fields, const char* name, double fallback) {
  const json* v = find(fields, name);
  if (!v) return fallback;
  if (!v->is_number()) throw RequestFieldError(name, "must be a number");
  const double d = v->get<double>();
  if (!std::isfinite(d)) throw RequestFieldError(name, "must be a finite number");
  return d;
}

std::string text(const json& fields, const char* name, const std::string& fallback) {
  const json* v = find(fields, name);
  if (!v) return fallback;
  if (!v->is_string()) throw RequestFieldError(name, "must be a string");
  return v->get<std::string>();
}

bool flag(const json& fields, const char* name, bool fallback) {
  const json* v = find(fields, name);
  if (!v) return fallback;
  if (!v->is_boolean()) throw RequestFieldError(name, "must be true or false");
  return v->get<bool>();
}

Eigen::Vector3d triple(const json& fields, const char* name, const char* meaning) {
  const json* v = find(fields, name);
  if (!v->is_array() || v->size() != 3 ||
      !std::all_of(v->begin(), v->end(), [](const json& e) { return e.is_number(); }))
    throw RequestFieldError(name, std::string("must be [") + meaning + "] (three numbers)");
  Eigen::Vector3d out;
  for (int i = 0; i < 3; ++i) out[i] = (*v)[i].get<double>();
  if (!out.allFinite()) throw RequestFieldError(name, "must be three finite numbers");
  return out;
}

std::string joined(const std::vector<std::string>& names) {
  std::string list;
  for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
  return list;
}

// "a,b" or ["a", "b"].
std::vector<std::string> constraint_sets(const json& v) {
  std::vector<std::string> sets;
  if (v.is_string()) {
    std::stringstream ss(v.get<std::string>());
    std::string item;
    while (std::getline(ss, item, ','))
      if (!item.empty()) sets.push_back(item);
  } else if (v.is_array()) {
    for (const json& e : v) {
      if (!e.is_string()) throw RequestFieldError("constraints", "entries must be strings");
      sets.push_back(e.get<std::string>());
    }
  } else {
    throw RequestFieldError("constraints", "must be a comma-separated string or an array");
  }
  if (sets.empty()) throw RequestFieldError("constraints", "is empty");
  const auto available = planner::constraint_set_names();
  for (const auto& name : sets)
    if (std::find(available.begin(), available.end(), name) == available.end())
      throw RequestFieldError(
          "constraints", "'" + name + "' is not available (available: " + joined(available) + ")");
  return sets;
}

std::vector<std::pair<std::string, double>> feasibility_settings(const json& v) {
  if (!v.is_object())
    throw RequestFieldError("feasibility", "must be an object {\"NAME\": number, ...}");
  std::vector<std::pair<std::string, double>> settings;
  for (const auto& [name, value] : v.items()) {
    if (!value.is_number() || !std::isfinite(value.get<double>()))
      throw RequestFieldError("feasibility", name + " = " + value.dump() + " is not a number");
    settings.emplace_back(name, value.get<double>());
  }
  try {
    planner::feasibility_options(settings);
  } catch (const std::invalid_argument& e) {
    throw RequestFieldError("feasibility", e.what());
  }
  return settings;
}

// A PlanFileError from plan_from_json(..., "init") reads "init: PROBLEM"; the field is "init".
RequestFieldError file_error(const char* field, const std::string& message) {
  const std::string prefix = std::string(field) + ": ";
  return RequestFieldError(field,
                           message.rfind(prefix, 0) == 0 ? message.substr(prefix.size()) : message);
}

// The previous plan a re-plan continues: for this robot, with its feet, a timeline that spans
// it, and no longer than a plan may be.
void read_init(const json& fields, const robot::RobotModel& robot, PlanRequest* r) {
  const json* init = find(fields, "init");
  if (!init) {
    for (const char* key : {"start_time", "start_state"})
      if (find(fields, key)) throw RequestFieldError(key, "needs \"init\" (the plan it continues)");
    return;
  }
  if (!init->is_object())
    throw RequestFieldError("init",
                            "must be a plan.json object (a previous plan with JSON samples)");
  try {
    r->previous = planner::plan_from_json(*init, "init");
  } catch (const planner::PlanFileError& e) {
    throw file_error("init", e.what());
  }
  if (r->previous.robot != robot.name)
    throw RequestFieldError(
        "init", "plan is for robot '" + r->previous.robot + "', not '" + robot.name + "'");
  std::vector<std::string> feet;
  for (const auto& leg : robot.legs) feet.push_back(leg.name);
  if (r->previous.feet != feet)
    throw RequestFieldError("init", "the plan's feet (" + joined(r->previous.feet) +
                                        ") differ from robot " + robot.name + "'s (" +
                                        joined(feet) + ")");
  planner::check_plan_horizon(r->previous.duration, "init.duration");
  try {
    planner::timeline_of(r->previous);  // the contact schedule the re-plan continues
  } catch (const std::invalid_argument& e) {
    throw RequestFieldError("init", e.what());
  }
  r->replan = true;
  r->start_time = number(fields, "start_time", 0.0);
  if (!(r->start_time >= 0.0 && r->start_time < r->previous.duration)) {
    std::ostringstream m;
    m << "must be within [0, " << r->previous.duration << ") s, the duration of the plan it "
      << "continues";
    throw RequestFieldError("start_time", m.str());
  }
  if (const json* state = find(fields, "start_state")) {
    try {
      r->start_state =
          planner::start_state_from_json(*state, "start_state", r->previous, r->start_time);
    } catch (const planner::PlanFileError& e) {
      throw file_error("start_state", e.what());
    }
    r->has_start_state = true;
  }
}

}  // namespace

planner::WarmStart PlanRequest::warm_start() const {
  planner::WarmStart w;
  if (!replan) return w;
  w.previous = &previous;
  w.shift = start_time;
  if (has_start_state) w.start = &start_state;
  return w;
}

PlanRequest read_plan_request(const json& fields, const robot::RobotModel& robot) {
  if (!fields.is_object()) throw RequestFieldError("request", "must be a JSON object");
  PlanRequest r;
  planner::PlannerOptions& po = r.options;
  r.terrain = text(fields, "terrain", r.terrain);
  if (r.terrain.empty()) throw RequestFieldError("terrain", "is empty");
  read_init(fields, robot, &r);
  const json& extra = r.previous.extra;

  // The gait: a re-plan continues init's contact schedule, so another gait cannot apply.
  po.gait = text(fields, "gait", r.replan ? r.previous.gait : "crawl");
  if (r.replan && po.gait != r.previous.gait)
    throw RequestFieldError("gait", "'" + po.gait + "' differs from init's gait '" +
                                        r.previous.gait +
                                        "': a re-plan continues the contact schedule of the plan "
                                        "it starts from (plan anew for another gait)");
  // Left out: init's for a re-plan, otherwise enough for the goal (read below).
  const bool cycles_given = find(fields, "cycles") != nullptr;
  const double cycles = number(fields, "cycles", r.replan ? extra.value("cycles", 3.0) : 3.0);
  if (cycles != std::floor(cycles))
    throw RequestFieldError("cycles", "must be an integer within [1, 50]");
  po.cycles = static_cast<int>(std::clamp(cycles, -1.0, 1e6));  // the limits below name it
  // Left out: the gait's duration. An explicit 0 is a mistake, not a request for the default.
  if (find(fields, "duration")) {
    po.duration = number(fields, "duration", 0.0);
    if (!(po.duration > 0.0))
      throw RequestFieldError("duration", "must be > 0 s (leave it out for the gait's default)");
  }
  po.has_goal = true;
  if (find(fields, "goal"))
    po.goal = triple(fields, "goal", "x, y, yaw");
  else
    po.goal = r.replan ? planner::goal_of(r.previous) : Eigen::Vector3d(1.0, 0.0, 0.0);
  if (find(fields, "start")) {
    if (r.replan)
      throw RequestFieldError("start",
                              "a re-plan starts from init at start_time (give "
                              "start_state for a measured pose)");
    po.start = triple(fields, "start", "x, y, yaw");
  }
  if (!cycles_given && !r.replan && po.start.allFinite() && po.goal.allFinite())
    po.cycles = planner::default_cycles(robot, po.start, po.goal);
  if (const json* c = find(fields, "constraints"))
    po.constraints = constraint_sets(*c);
  else if (r.replan && extra.contains("constraints"))
    po.constraints = constraint_sets(extra["constraints"]);  // what init was planned with
  else
    po.constraints = planner::kDefaultRequestConstraints;
  if (const json* f = find(fields, "feasibility"))
    po.feasibility_settings = feasibility_settings(*f);
  else if (r.replan && extra.contains("feasibility_settings"))
    po.feasibility_settings = feasibility_settings(extra["feasibility_settings"]);
  po.optimize_timing =
      flag(fields, "optimize_timing", r.replan ? extra.value("optimize_timing", false) : false);
  po.max_time = number(fields, "max_time", 0.0);
  r.sample_dt = number(fields, "sample_dt", r.sample_dt);
  r.samples = text(fields, "samples", r.samples);
  if (r.samples != "json" && r.samples != "attachment")
    throw RequestFieldError("samples", "must be \"json\" or \"attachment\"");
  planner::check_plan_request(po, r.sample_dt);
  return r;
}

nlohmann::json settle_stance_feet(PlanRequest* request, const terrain::HeightField& terrain) {
  json corrections = json::array();
  if (!request->replan || !request->has_start_state) return corrections;
  const planner::PhaseTimeline timeline = planner::timeline_of(request->previous);
  int interval = 0;
  while (interval + 1 < timeline.num_intervals() &&
         timeline.events[interval + 1] <= request->start_time)
    ++interval;
  auto& feet = request->start_state.foot_position;
  for (std::size_t f = 0; f < feet.size() && f < timeline.contact.size(); ++f) {
    if (!timeline.contact[f][interval]) continue;  // a swinging foot may be anywhere above
    Eigen::Vector3d& p = feet[f];
    const double ground = terrain.sample(p.x(), p.y()).height;
    const double off = p.z() - ground;
    if (std::abs(off) <= 1e-9) continue;
    if (std::abs(off) > kStanceTolerance) {
      std::ostringstream m;
      m << "feet." << request->previous.feet[f] << ": in stance at start_time "
        << request->start_time << " s but " << std::abs(off) * 1e3 << " mm "
        << (off > 0 ? "above" : "below") << " the terrain (foot z " << p.z() << " m, terrain "
        << ground << " m at x " << p.x() << ", y " << p.y() << "); a stance foot must be within "
        << kStanceTolerance * 1e3 << " mm of the ground the plan uses (is the state estimate or "
        << "the map off?)";
      throw RequestFieldError("start_state", m.str());
    }
    corrections.push_back(
        {{"foot", request->previous.feet[f]}, {"measured_z", p.z()}, {"terrain_z", ground}});
    p.z() = ground;
  }
  return corrections;
}

void check_stances_on_terrain(const PlanRequest& request, const robot::RobotModel& robot,
                              const terrain::HeightField& terrain) {
  if (request.replan) return;
  // First the level: a goal on a ceiling or a cupboard top is named as such, with its height and
  // the start's, rather than as ground that was not observed or is not safe.
  planner::check_level_reach(terrain, robot, request.options.start, request.options.goal);
  const auto* grid = dynamic_cast<const terrain::TerrainMap*>(&terrain);
  const Eigen::Vector2d lo = terrain.min_corner(), hi = terrain.max_corner();
  auto check = [&](const char* field, const Eigen::Vector3d& pose, bool need_safe) {
    for (const auto& leg : robot.legs) {
      const Eigen::Vector3d foot =
          robot::nominal_foot_world(leg, Eigen::Vector3d(pose.x(), pose.y(), 0.0), pose.z());
      const double x = foot.x(), y = foot.y();
      std::ostringstream where;
      where << "the nominal " << leg.name << " foot at (" << x << ", " << y << ")";
      std::string problem;
      if (x < lo.x() || x > hi.x() || y < lo.y() || y > hi.y()) {
        std::ostringstream m;
        m << " is outside the map (x in [" << lo.x() << ", " << hi.x() << "], y in [" << lo.y()
          << ", " << hi.y() << "])";
        problem = m.str();
      } else if (!terrain.observed(x, y)) {
        problem = " is on ground the scan did not observe";
      } else if (need_safe) {
        const bool safe = grid ? grid->safe(x, y, robot.foot_radius)
                               : terrain.safety_margin(x, y, robot.foot_radius).margin > 0.0;
        if (!safe)
          problem = " is not a safe foothold for the " + std::to_string(robot.foot_radius) +
                    " m foot (an edge, a step or a slope)";
      }
      if (!problem.empty()) {
        std::ostringstream m;
        m << "[" << pose.x() << ", " << pose.y() << ", " << pose.z() << "]: " << where.str()
          << problem << "; choose a " << field << " on the mapped ground";
        throw RequestFieldError(field, m.str());
      }
    }
  };
  check("start", request.options.start, /*need_safe=*/true);
  check("goal", request.options.goal, /*need_safe=*/false);
}

}  // namespace terrastride::service
