// The registry of constraint sets (constraints.hpp): each name `--constraints` accepts, with the
// function that builds the set.
#include <algorithm>
#include <iterator>
#include <map>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/planner/constraints.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/nlp.hpp"
#include "terrastride/planner/solver_fork.hpp"

namespace terrastride::planner {

namespace {

// The built-in sets: the baseline, and the feasibility sets, each built with the problem's
// feasibility settings over its robot's defaults.
std::map<std::string, ConstraintSetBuilder> builtin_constraint_sets() {
  auto options = [](const SrbdProblem& p) {
    return feasibility_options(p.robot(), p.options().feasibility_settings);
  };
  return {{"baseline", build_baseline_set},
          {"foot", [=](SrbdProblem& p) { build_foot_set(p, options(p)); }},
          {"shin", [=](SrbdProblem& p) { build_shin_set(p, options(p)); }},
          {"shin_ik", [=](SrbdProblem& p) { build_shin_ik_set(p, options(p)); }},
          {"thigh", [=](SrbdProblem& p) { build_thigh_set(p, options(p)); }},
          {"trunk", [=](SrbdProblem& p) { build_trunk_set(p, options(p)); }},
          {"polytope", [=](SrbdProblem& p) { build_polytope_set(p, options(p)); }},
          {"swing", [=](SrbdProblem& p) { build_swing_set(p, options(p)); }},
          {"joints",
           [=](SrbdProblem& p) {
             build_joints_set(p, options(p));
             if (options(p).joint_velocity > 0) build_joint_velocity_rows(p);
           }},
          {"force_ramp", [=](SrbdProblem& p) { build_force_ramp_set(p, options(p)); }},
          {"monotone_progress",
           [=](SrbdProblem& p) { build_monotone_progress_set(p, options(p)); }},
          {"lateral_corridor", [=](SrbdProblem& p) { build_lateral_corridor_set(p, options(p)); }},
          {"swing_apex", [=](SrbdProblem& p) { build_swing_apex_set(p, options(p)); }}};
}

std::map<std::string, ConstraintSetBuilder>& registry() {
  // The built-in sets are there from the start: no static initialisers.
  static std::map<std::string, ConstraintSetBuilder> r = builtin_constraint_sets();
  return r;
}

struct RegistryLock {};
// A plan process forked while another thread looked a set up must not inherit the lock held.
std::mutex& registry_mutex() { return fork_safe_mutex<RegistryLock>(); }

}  // namespace

void register_constraint_set(const std::string& name, ConstraintSetBuilder builder) {
  std::lock_guard<std::mutex> lock(registry_mutex());
  registry()[name] = std::move(builder);
}

std::vector<std::string> constraint_set_names() {
  std::lock_guard<std::mutex> lock(registry_mutex());
  std::vector<std::string> names{"baseline"};
  for (const auto& [k, v] : registry())
    if (k != "baseline") names.push_back(k);
  names.push_back("all");  // kAllFeasibilitySets, expanded by add_constraint_sets
  return names;
}

namespace {
// "baseline", then `requested` with "all" expanded and implied sets appended (maybe repeated).
std::vector<std::string> expanded_sets(const std::vector<std::string>& requested) {
  std::vector<std::string> sets{"baseline"};  // always, and first
  for (const auto& name : requested)
    if (name == "all")
      sets.insert(sets.end(), std::begin(kAllFeasibilitySets), std::end(kAllFeasibilitySets));
    else
      sets.push_back(name);
  for (const auto& [set, implied] : kImpliedFeasibilitySets)
    if (std::find(sets.begin(), sets.end(), set) != sets.end()) sets.push_back(implied);
  return sets;
}
}  // namespace

bool requests_constraint_set(const std::vector<std::string>& requested, const std::string& set) {
  const auto sets = expanded_sets(requested);
  return std::find(sets.begin(), sets.end(), set) != sets.end();
}

void add_constraint_sets(SrbdProblem& problem, const std::vector<std::string>& requested) {
  const std::vector<std::string> sets = expanded_sets(requested);
  for (std::size_t i = 0; i < sets.size(); ++i) {
    const std::string& name = sets[i];
    if (std::find(sets.begin(), sets.begin() + i, name) != sets.begin() + i) continue;  // once
    ConstraintSetBuilder build;
    {
      std::lock_guard<std::mutex> lock(registry_mutex());
      auto it = registry().find(name);
      if (it != registry().end()) build = it->second;
    }
    if (!build) {
      std::string names;
      for (const auto& n : constraint_set_names()) names += (names.empty() ? "" : ", ") + n;
      throw std::invalid_argument("constraint set '" + name +
                                  "' is not available (available: " + names + ")");
    }
    build(problem);
  }
}

}  // namespace terrastride::planner
