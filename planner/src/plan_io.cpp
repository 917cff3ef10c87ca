#include "terrastride/planner/plan_io.hpp"

#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <initializer_list>

#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {
namespace {

using nlohmann::json;

json vec3(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

// Field access with a path for error messages.
class Reader {
 public:
  Reader(const std::string& source, const json& node, std::string path)
      : source_(source), node_(node), path_(std::move(path)) {}

  [[noreturn]] void fail(const std::string& field, const std::string& problem) const {
    throw PlanFileError(source_ + ": " + join(field) + ": " + problem);
  }
  const json& at(const std::string& field) const {
    if (!node_.is_object()) throw PlanFileError(source_ + ": " + path_ + ": must be an object");
    const auto it = node_.find(field);
    if (it == node_.end()) fail(field, "missing");
    return *it;
  }
  bool has(const std::string& field) const { return node_.is_object() && node_.contains(field); }
  Reader sub(const std::string& field) const { return Reader(source_, at(field), join(field)); }
  Reader element(const std::string& field, size_t i) const {
    return Reader(source_, at(field)[i], join(field) + "[" + std::to_string(i) + "]");
  }
  double number(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_number()) fail(field, "must be a number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) fail(field, "must be finite");
    return d;
  }
  int integer(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_number_integer()) fail(field, "must be an integer");
    return v.get<int>();
  }
  std::string text(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_string()) fail(field, "must be a string");
    return v.get<std::string>();
  }
  bool boolean(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_boolean()) fail(field, "must be true or false");
    return v.get<bool>();
  }
  Eigen::Vector3d vec3(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_array() || v.size() != 3) fail(field, "must be an array of 3 numbers");
    Eigen::Vector3d out;
    for (int i = 0; i < 3; ++i) {
      // nlohmann writes NaN as null: report it as non-finite.
      if (!v[i].is_number())
        fail(field, "element " + std::to_string(i) + " is not a finite number");
      out[i] = v[i].get<double>();
      if (!std::isfinite(out[i])) fail(field, "element " + std::to_string(i) + " is not finite");
    }
    return out;
  }
  // This node must be a JSON object holding no keys but `known` (a misspelt optional field
  // would otherwise be silently ignored).
  void only(std::initializer_list<const char*> known) const {
    if (!node_.is_object())
      throw PlanFileError(source_ + ": " + (path_.empty() ? "top level" : path_) +
                          ": must be an object");
    for (const auto& [key, value] : node_.items()) {
      bool ok = false;
      std::string list;
      for (const char* k : known) {
        ok = ok || key == k;
        list += (list.empty() ? "" : ", ") + std::string(k);
      }
      if (!ok) fail(key, "unknown field (known: " + list + ")");
    }
  }
  size_t array_size(const std::string& field) const {
    const json& v = at(field);
    if (!v.is_array()) fail(field, "must be an array");
    return v.size();
  }

 private:
  std::string join(const std::string& field) const {
    return path_.empty() ? field : path_ + "." + field;
  }
  const std::string& source_;
  const json& node_;
  std::string path_;
};

// The JSON document in `path`; `what` names the file's role in the error when it cannot be opened.
json read_json_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PlanFileError(path + ": cannot open " + what);
  try {
    return json::parse(in);
  } catch (const json::exception& e) {  // parse errors, and numbers beyond double (1e999)
    throw PlanFileError(path + ": not valid JSON: " + e.what());
  }
}

const char* const kKnownKeys[] = {"robot", "gait",    "duration", "sample_dt",
                                  "feet",  "samples", "solver",   "checks"};

}  // namespace

json plan_to_json(const Trajectory& t) {
  json out = json::object();
  // Extra keys first so the standard keys below always win.
  for (const auto& [key, value] : t.extra.items()) out[key] = value;
  out["robot"] = t.robot;
  out["gait"] = t.gait;
  out["duration"] = t.duration;
  out["sample_dt"] = t.sample_dt;
  out["feet"] = t.feet;
  json samples = json::array();
  for (const TrajectorySample& s : t.samples) {
    json feet = json::array();
    for (const FootState& f : s.feet)
      feet.push_back({{"position", vec3(f.position)},
                      {"velocity", vec3(f.velocity)},
                      {"force", vec3(f.force)},
                      {"contact", f.contact}});
    samples.push_back({{"t", s.t},
                       {"base",
                        {{"position", vec3(s.base.position)},
                         {"euler_zyx", vec3(s.base.euler_zyx)},
                         {"linear_velocity", vec3(s.base.linear_velocity)},
                         {"angular_velocity", vec3(s.base.angular_velocity)},
                         {"linear_acceleration", vec3(s.base.linear_acceleration)},
                         {"angular_acceleration", vec3(s.base.angular_acceleration)}}},
                       {"feet", feet}});
  }
  out["samples"] = std::move(samples);
  out["solver"] = {{"status", t.solver.status},
                   {"iterations", t.solver.iterations},
                   {"wall_s", t.solver.wall_s},
                   {"n_variables", t.solver.n_variables},
                   {"n_constraints", t.solver.n_constraints}};
  json checks = json::object();
  for (const auto& [name, value] : t.checks) checks[name] = value;
  out["checks"] = checks;
  return out;
}

Trajectory plan_from_json(const json& j, const std::string& source) {
  if (!j.is_object()) throw PlanFileError(source + ": a plan must be a JSON object");
  const Reader top(source, j, "");
  Trajectory t;
  t.robot = top.text("robot");
  t.gait = top.has("gait") ? top.text("gait") : "";
  t.duration = top.number("duration");
  t.sample_dt = top.number("sample_dt");
  if (!(t.duration > 0)) top.fail("duration", "must be > 0");
  if (!(t.sample_dt > 0)) top.fail("sample_dt", "must be > 0");
  const size_t n_feet = top.array_size("feet");
  for (size_t i = 0; i < n_feet; ++i) {
    const json& name = j["feet"][i];
    if (!name.is_string()) top.fail("feet[" + std::to_string(i) + "]", "must be a string");
    t.feet.push_back(name.get<std::string>());
  }
  if (t.feet.empty()) top.fail("feet", "must name at least one foot");

  const size_t n_samples = top.array_size("samples");
  if (n_samples == 0) top.fail("samples", "must not be empty");
  t.samples.reserve(n_samples);
  for (size_t k = 0; k < n_samples; ++k) {
    const Reader s = top.element("samples", k);
    TrajectorySample sample;
    sample.t = s.number("t");
    if (!t.samples.empty() && !(sample.t > t.samples.back().t)) s.fail("t", "times must increase");
    const Reader b = s.sub("base");
    sample.base.position = b.vec3("position");
    sample.base.euler_zyx = b.vec3("euler_zyx");
    sample.base.linear_velocity = b.vec3("linear_velocity");
    sample.base.angular_velocity = b.vec3("angular_velocity");
    sample.base.linear_acceleration = b.vec3("linear_acceleration");
    sample.base.angular_acceleration = b.vec3("angular_acceleration");
    if (s.array_size("feet") != n_feet)
      s.fail("feet", "has " + std::to_string(s.array_size("feet")) + " entries, expected " +
                         std::to_string(n_feet) + " (one per name in 'feet')");
    for (size_t i = 0; i < n_feet; ++i) {
      const Reader f = s.element("feet", i);
      FootState foot;
      foot.position = f.vec3("position");
      foot.velocity = f.vec3("velocity");
      foot.force = f.vec3("force");
      foot.contact = f.boolean("contact");
      sample.feet.push_back(foot);
    }
    t.samples.push_back(std::move(sample));
  }
  if (top.has("solver")) {
    const Reader sv = top.sub("solver");
    t.solver.status = sv.text("status");
    t.solver.iterations = sv.integer("iterations");
    t.solver.wall_s = sv.number("wall_s");
    t.solver.n_variables = sv.integer("n_variables");
    t.solver.n_constraints = sv.integer("n_constraints");
  }
  if (top.has("checks")) {
    const json& checks = j["checks"];
    if (!checks.is_object()) top.fail("checks", "must be an object");
    for (const auto& [name, value] : checks.items()) {
      if (!value.is_number()) top.fail("checks." + name, "must be a number");
      t.checks[name] = value.get<double>();
    }
  }
  for (const auto& [key, value] : j.items()) {
    bool known = false;
    for (const char* k : kKnownKeys) known = known || key == k;
    if (!known) t.extra[key] = value;
  }
  return t;
}

SrbdProblem::StartState start_state_from_json(const json& j, const std::string& source,
                                              const Trajectory& previous, double start_time) {
  TrajectorySample state = interpolate_plan(previous, start_time);
  const Reader top(source, j, "");
  top.only({"base", "feet"});
  if (top.has("base")) {
    const Reader b = top.sub("base");
    b.only({"position", "euler_zyx", "linear_velocity", "angular_velocity"});
    if (b.has("position")) state.base.position = b.vec3("position");
    if (b.has("euler_zyx")) state.base.euler_zyx = b.vec3("euler_zyx");
    if (b.has("linear_velocity")) state.base.linear_velocity = b.vec3("linear_velocity");
    if (b.has("angular_velocity")) state.base.angular_velocity = b.vec3("angular_velocity");
    // The Euler rates of an angular velocity are undefined at pitch +-90 deg (gimbal lock).
    if (b.has("euler_zyx") && std::abs(std::cos(state.base.euler_zyx[1])) < 1e-3)
      b.fail("euler_zyx", "pitch " + std::to_string(state.base.euler_zyx[1]) +
                              " rad is at +-pi/2, where ZYX Euler rates are undefined");
  }
  if (top.has("feet")) {
    std::string names;
    for (const auto& n : previous.feet) names += (names.empty() ? "" : ", ") + n;
    if (!j["feet"].is_object())
      top.fail("feet", "must be an object keyed by foot name (the plan's feet: " + names + ")");
    const Reader feet = top.sub("feet");
    for (const auto& [name, value] : j["feet"].items()) {
      const auto it = std::find(previous.feet.begin(), previous.feet.end(), name);
      if (it == previous.feet.end())
        feet.fail(name, "unknown foot (the plan's feet: " + names + ")");
      const Reader f = feet.sub(name);
      f.only({"position", "velocity"});
      FootState& foot = state.feet.at(static_cast<size_t>(it - previous.feet.begin()));
      if (f.has("position")) foot.position = f.vec3("position");
      if (f.has("velocity")) foot.velocity = f.vec3("velocity");
    }
  }
  return start_state_of(state);
}

SrbdProblem::StartState read_start_state_file(const std::string& path, const Trajectory& previous,
                                              double start_time) {
  return start_state_from_json(read_json_file(path, "start-state file"), path, previous,
                               start_time);
}

void write_plan_file(const std::string& path, const Trajectory& trajectory) {
  const std::string text = plan_to_json(trajectory).dump(1) + "\n";
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw PlanFileError(path + ": cannot write (directory missing or not writable)");
    out << text;
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      throw PlanFileError(path + ": write failed (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw PlanFileError(path + ": cannot move the finished plan into place");
  }
}

Trajectory read_plan_file(const std::string& path) {
  return plan_from_json(read_json_file(path, "plan file"), path);
}

}  // namespace terrastride::planner
