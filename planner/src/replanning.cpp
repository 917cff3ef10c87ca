// What a re-plan takes from the plan it continues: the contact timeline, the goal, the start state.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "plan_interpolation.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/planner/planner.hpp"

namespace terrastride::planner {

PhaseTimeline timeline_of(const Trajectory& plan) {
  const auto& ex = plan.extra;
  if (!ex.contains("timeline"))
    throw std::invalid_argument("plan has no \"timeline\" (not written by terrastride plan)");
  PhaseTimeline tl;
  tl.feet = plan.feet;
  try {
    tl.events = ex["timeline"]["events"].get<std::vector<double>>();
    for (const auto& c : ex["timeline"]["contact"])
      tl.contact.push_back(c.get<std::vector<bool>>());
    tl.first_interval_elapsed = ex["timeline"].value("first_interval_elapsed", 0.0);
    if (ex["timeline"].contains("swing_elapsed"))
      tl.swing_elapsed = ex["timeline"]["swing_elapsed"].get<std::vector<double>>();
  } catch (const nlohmann::json::exception& e) {
    throw std::invalid_argument(std::string("plan \"timeline\": ") + e.what());
  }
  if (tl.events.size() < 2 || tl.contact.size() != tl.feet.size())
    throw std::invalid_argument("plan \"timeline\": inconsistent sizes");
  // The events span the plan from 0 to its duration: a timeline that does not would have a
  // re-plan build a problem for a different (possibly enormous) horizon than the samples cover.
  for (std::size_t i = 0; i < tl.events.size(); ++i)
    if (!std::isfinite(tl.events[i]) || (i > 0 && !(tl.events[i] > tl.events[i - 1])))
      throw std::invalid_argument("plan \"timeline\": events must be finite and increasing");
  if (std::abs(tl.events.front()) > 1e-9 || std::abs(tl.events.back() - plan.duration) > 1e-6)
    throw std::invalid_argument("plan \"timeline\": events must run from 0 to the duration " +
                                std::to_string(plan.duration) + " s");
  if (!(tl.first_interval_elapsed >= 0.0) || !std::isfinite(tl.first_interval_elapsed))
    throw std::invalid_argument("plan \"timeline\": first_interval_elapsed must be >= 0");
  if (!tl.swing_elapsed.empty() && tl.swing_elapsed.size() != tl.feet.size())
    throw std::invalid_argument("plan \"timeline\": swing_elapsed must have one entry per foot");
  for (double e : tl.swing_elapsed)
    if (!(e >= 0.0) || !std::isfinite(e))
      throw std::invalid_argument("plan \"timeline\": swing_elapsed entries must be >= 0");
  for (const auto& c : tl.contact)
    if (static_cast<int>(c.size()) != tl.num_intervals())
      throw std::invalid_argument(
          "plan \"timeline\": contact lists must have one entry per interval");
  return tl;
}

Eigen::Vector3d goal_of(const Trajectory& plan) {
  if (plan.samples.empty()) throw std::invalid_argument("plan has no samples");
  const auto& last = plan.samples.back().base;
  return Eigen::Vector3d(last.position.x(), last.position.y(), last.euler_zyx[0]);
}

void set_path_line_of(const Trajectory& plan, ProblemOptions* options) {
  if (plan.samples.empty()) throw std::invalid_argument("plan has no samples");
  const auto it = plan.extra.find("path_line");
  if (it != plan.extra.end() && it->is_array() && it->size() == 4) {
    const auto& v = *it;
    for (const auto& e : v)
      if (!e.is_number()) throw RequestError("init.path_line", "must be four numbers");
    options->path_line_start = Eigen::Vector2d(v[0].get<double>(), v[1].get<double>());
    options->path_line_end = Eigen::Vector2d(v[2].get<double>(), v[3].get<double>());
    if (!options->path_line_start.allFinite() || !options->path_line_end.allFinite())
      throw RequestError("init.path_line", "must be four finite numbers");
  } else {
    options->path_line_start = plan.samples.front().base.position.head<2>();
    options->path_line_end = plan.samples.back().base.position.head<2>();
  }
  options->has_path_line = true;
}

void set_start_lead_of(const Trajectory& plan, double t, const SrbdProblem::StartState& start,
                       ProblemOptions* options) {
  options->start_lead = 0.0;
  if (!options->has_path_line) return;
  const Eigen::Vector2d d = options->path_line_end - options->path_line_start;
  if (!(d.norm() >= 0.01)) return;
  const double lead = d.normalized().dot(start.position.head<2>() -
                                         interpolate_plan(plan, t).base.position.head<2>());
  if (std::isfinite(lead)) options->start_lead = std::max(0.0, lead);
}

nlohmann::json path_line_json(const ProblemOptions& o) {
  return {o.path_line_start.x(), o.path_line_start.y(), o.path_line_end.x(), o.path_line_end.y()};
}

SrbdProblem::StartState start_state_of(const Trajectory& plan, double t) {
  return start_state_of(interpolate_plan(plan, t));
}

SrbdProblem::StartState start_state_of(const TrajectorySample& s) {
  SrbdProblem::StartState start;
  start.position = s.base.position;
  start.euler_zyx = s.base.euler_zyx;
  start.linear_velocity = s.base.linear_velocity;
  start.euler_rates = interpolation::euler_rates(s);
  for (const auto& f : s.feet) {
    start.foot_position.push_back(f.position);
    start.foot_velocity.push_back(f.velocity);
  }
  return start;
}
}  // namespace terrastride::planner
