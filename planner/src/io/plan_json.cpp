// plan.json's document: a Trajectory to JSON and back (format in docs/design.md, 3.5 plan.json).
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "json_reader.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace terrastride::planner {
namespace {

using io::Reader;
using nlohmann::json;

json vec3(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

const char* const kKnownKeys[] = {"robot",   "robot_file", "gait",   "duration", "sample_dt",
                                  "feet",    "samples",    "solver", "checks"};

}  // namespace

json samples_to_json(const std::vector<TrajectorySample>& samples) {
  json out = json::array();
  for (const TrajectorySample& s : samples) {
    json feet = json::array();
    for (const FootState& f : s.feet)
      feet.push_back({{"position", vec3(f.position)},
                      {"velocity", vec3(f.velocity)},
                      {"force", vec3(f.force)},
                      {"contact", f.contact}});
    out.push_back({{"t", s.t},
                   {"base",
                    {{"position", vec3(s.base.position)},
                     {"euler_zyx", vec3(s.base.euler_zyx)},
                     {"linear_velocity", vec3(s.base.linear_velocity)},
                     {"angular_velocity", vec3(s.base.angular_velocity)},
                     {"linear_acceleration", vec3(s.base.linear_acceleration)},
                     {"angular_acceleration", vec3(s.base.angular_acceleration)}}},
                   {"feet", feet}});
  }
  return out;
}

namespace {

// The document with "samples" null when `with_samples` is false (plan_text splices them in).
json plan_document(const Trajectory& t, bool with_samples) {
  json out = json::object();
  // Extra keys first so the standard keys below always win.
  for (const auto& [key, value] : t.extra.items()) out[key] = value;
  out["robot"] = t.robot;
  if (!t.robot_definition.empty())
    out["robot_file"] = {{"hash", robot::robot_definition_hash(t.robot_definition)},
                         {"yaml", t.robot_definition}};
  out["gait"] = t.gait;
  out["duration"] = t.duration;
  out["sample_dt"] = t.sample_dt;
  out["feet"] = t.feet;
  out["samples"] = with_samples ? samples_to_json(t.samples) : json();
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

// The text json::dump(1) gives the samples array at the document's top level, one level
// deeper: every line after the first indented by one more space (strings hold no raw newlines).
std::string indented_one_level(const std::string& text) {
  std::string out;
  out.reserve(text.size() + text.size() / 16);
  for (const char c : text) {
    out += c;
    if (c == '\n') out += ' ';
  }
  return out;
}

}  // namespace

json plan_to_json(const Trajectory& t) { return plan_document(t, true); }

SerialisedSamples serialise_samples(const std::vector<TrajectorySample>& samples) {
  SerialisedSamples out;
  out.count = samples.size();
  if (!samples.empty()) {
    out.first_t = samples.front().t;
    out.last_t = samples.back().t;
  }
  out.text = indented_one_level(samples_to_json(samples).dump(1));
  return out;
}

std::string plan_text(const Trajectory& t, const SerialisedSamples* samples) {
  if (!samples) return plan_to_json(t).dump(1) + "\n";
  if (samples->count != t.samples.size() ||
      (!t.samples.empty() &&
       (samples->first_t != t.samples.front().t || samples->last_t != t.samples.back().t)))
    throw std::logic_error("plan_text: the serialised samples are not this plan's");
  std::string text = plan_document(t, false).dump(1);
  // Only a top-level key starts a line with exactly one space of indentation, so this is the
  // "samples" key of the document and not a string or a nested key.
  const std::string key = "\n \"samples\": null";
  const std::size_t at = text.find(key);
  if (at == std::string::npos) throw std::logic_error("plan_text: no samples key in the document");
  text.replace(at + key.size() - 4, 4, samples->text);
  return text + "\n";
}

Trajectory plan_from_json(const json& j, const std::string& source) {
  if (!j.is_object()) throw PlanFileError(source + ": a plan must be a JSON object");
  const Reader top(source, j, "");
  Trajectory t;
  t.robot = top.text("robot");
  if (top.has("robot_file")) {
    // The robot the plan was made with; its hash guards against an edited or truncated copy.
    const Reader rf = top.sub("robot_file");
    t.robot_definition = rf.text("yaml");
    const std::string hash = rf.text("hash");
    const std::string actual = robot::robot_definition_hash(t.robot_definition);
    if (hash != actual)
      rf.fail("hash", "is " + hash + " but the robot file text hashes to " + actual +
                          " (the plan's robot definition was altered)");
  }
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

}  // namespace terrastride::planner
