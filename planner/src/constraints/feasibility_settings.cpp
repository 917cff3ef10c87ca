// FeasibilityOptions from NAME=VALUE settings (`terrastride plan --feasibility`), validated.
#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>
#include <string>

#include "terrastride/planner/feasibility.hpp"

namespace terrastride::planner {

namespace {

// One settable field: how to store a value, and the range it must lie in.
struct Setting {
  std::function<void(FeasibilityOptions&, double)> set;
  double lo, hi;
  bool integer;
  const char* unit;
};

const std::map<std::string, Setting>& settings_table() {
  static const std::map<std::string, Setting> t = {
      {"foot_margin",
       {[](FeasibilityOptions& o, double v) { o.foot_margin = v; }, -0.1, 0.5, false, "m"}},
      {"shin_points",
       {[](FeasibilityOptions& o, double v) { o.shin_points = static_cast<int>(v); }, 1, 100, true,
        ""}},
      {"shin_exclusion",
       {[](FeasibilityOptions& o, double v) { o.shin_exclusion = v; }, -1.0, 1.0, false,
        "m (negative: the default)"}},
      {"shin_clearance",
       {[](FeasibilityOptions& o, double v) { o.shin_clearance = v; }, -1.0, 0.5, false,
        "m (negative: the default)"}},
      {"shin_ik_margin",
       {[](FeasibilityOptions& o, double v) { o.shin_ik_margin = v; }, 0.0, 0.1, false, "m"}},
      {"shin_yaw_points",
       {[](FeasibilityOptions& o, double v) { o.shin_yaw_points = static_cast<int>(v); }, 1, 20,
        true, ""}},
      {"shin_softmin",
       {[](FeasibilityOptions& o, double v) { o.shin_softmin = v; }, 0.0, 0.05, false,
        "m (0: a row per point)"}},
      {"leg_probe_margin",
       {[](FeasibilityOptions& o, double v) { o.leg_probe_margin = v; }, -1.0, 0.2, false,
        "m (negative: no probes)"}},
      {"leg_capsule_margin",
       {[](FeasibilityOptions& o, double v) { o.leg_capsule_margin = v; }, 0.0, 0.1, false, "m"}},
      {"leg_clearance_points",
       {[](FeasibilityOptions& o, double v) { o.leg_clearance_points = static_cast<int>(v); }, 1,
        20, true, ""}},
      {"thigh_points",
       {[](FeasibilityOptions& o, double v) { o.thigh_points = static_cast<int>(v); }, 2, 30, true,
        ""}},
      {"trunk_margin",
       {[](FeasibilityOptions& o, double v) { o.trunk_margin = v; }, 0.0, 0.3, false, "m"}},
      {"polytope_softmax",
       {[](FeasibilityOptions& o, double v) { o.polytope_softmax = v; }, 0.0, 0.1, false,
        "m g (0: a row per facet)"}},
      {"polytope_inner_points",
       {[](FeasibilityOptions& o, double v) { o.polytope_inner_points = static_cast<int>(v); }, 0,
        20, true, ""}},
      {"swing_acceleration",
       {[](FeasibilityOptions& o, double v) { o.swing_acceleration = v; }, 1e-3, 1e4, false,
        "m/s^2"}},
      {"force_rate_max",
       {[](FeasibilityOptions& o, double v) { o.force_rate_max = v; }, 0.0, 1e6, false,
        "N/s (0: no bound)"}},
      {"monotone_progress",
       {[](FeasibilityOptions& o, double v) { o.monotone_progress = static_cast<int>(v); }, 0, 1,
        true, "(1: on)"}},
      {"lateral_corridor",
       {[](FeasibilityOptions& o, double v) { o.lateral_corridor = v; }, 0.0, 1.0, false,
        "m (0: off)"}},
      {"swing_apex_rise",
       {[](FeasibilityOptions& o, double v) { o.swing_apex_rise = v; }, 0.0, 1.0, false,
        "m (0: off)"}},
      {"replan_path_shape",
       {[](FeasibilityOptions& o, double v) { o.replan_path_shape = static_cast<int>(v); }, 0, 1,
        true, "(1: re-plans from a state carry the path-shape rows too)"}},
      {"joint_margin",
       {[](FeasibilityOptions& o, double v) { o.joint_margin = v; }, 0.0, 0.5, false, "rad"}},
      {"start_return",
       {[](FeasibilityOptions& o, double v) { o.start_return = v; }, 0.0, 2.0, false,
        "s (0: a measured start, or a session step's pinned end, outside joints / "
        "range_of_motion gets no room)"}},
      {"joints_softmax",
       {[](FeasibilityOptions& o, double v) { o.joints_softmax = v; }, 0.0, 0.1, false, "rad"}},
      {"joint_velocity",
       {[](FeasibilityOptions& o, double v) { o.joint_velocity = v; }, 0.0, 1.0, false,
        "(1: joints also bounds joint velocities, for robots with velocity limits)"}},
  };
  return t;
}

std::string format(double v) {
  std::string s = std::to_string(v);
  while (s.size() > 1 && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  return s;
}

}  // namespace

namespace {
FeasibilityOptions apply_settings(FeasibilityOptions o,
                                  const std::vector<std::pair<std::string, double>>& settings) {
  const auto& table = settings_table();
  for (const auto& [name, value] : settings) {
    const auto it = table.find(name);
    if (it == table.end()) {
      std::string list;
      for (const auto& [k, v] : table) list += (list.empty() ? "" : ", ") + k;
      throw std::invalid_argument("unknown feasibility setting '" + name + "' (known: " + list +
                                  ")");
    }
    const Setting& s = it->second;
    if (!std::isfinite(value) || value < s.lo || value > s.hi ||
        (s.integer && value != std::floor(value)))
      throw std::invalid_argument("feasibility setting " + name + " = " + format(value) +
                                  ": must be " + (s.integer ? "an integer " : "") + "in [" +
                                  format(s.lo) + ", " + format(s.hi) + "]" +
                                  (*s.unit ? std::string(" ") + s.unit : std::string()));
    s.set(o, value);
  }
  return o;
}
}  // namespace

FeasibilityOptions feasibility_options(
    const std::vector<std::pair<std::string, double>>& settings) {
  return apply_settings(FeasibilityOptions{}, settings);
}

FeasibilityOptions feasibility_options(
    const robot::RobotModel& robot, const std::vector<std::pair<std::string, double>>& settings) {
  return apply_settings(robot_feasibility_defaults(robot), settings);
}

std::vector<std::string> feasibility_option_names() {
  std::vector<std::string> names;
  for (const auto& [k, v] : settings_table()) names.push_back(k);
  return names;
}

}  // namespace terrastride::planner
