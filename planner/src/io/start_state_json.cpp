// A robot's measured state to re-plan from, in plan.json's terms (`terrastride plan
// --start-state`, the socket's "start_state").
#include <algorithm>
#include <cmath>

#include "json_reader.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {

using io::Reader;
using nlohmann::json;

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
  return start_state_from_json(io::read_json_file(path, "start-state file"), path, previous,
                               start_time);
}

}  // namespace terrastride::planner
