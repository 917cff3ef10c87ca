// The plan's quality (planner/quality.hpp): how natural the motion is, as rows of the
// plan's summary table and as the plan's "quality" object. Computed from the samples, so a plan
// file from before the quality block has them too; the energy proxy is the torque check's.
// Figures beyond the quality targets are notes, not problems: a plan can be feasible and safe
// and still move less calmly than it could.
#include <cmath>

#include "report/sections.hpp"
#include "terrastride/planner/quality.hpp"

namespace terrastride::service::report {

using nlohmann::json;

json quality_section(const PlanSections& s) {
  const planner::Trajectory& traj = s.input.trajectory;
  const planner::PlanQuality q = planner::plan_quality(traj);
  json out = planner::quality_to_json(q, traj.feet);
  out["energy_proxy_J"] = num(s.checks.torque.energy_proxy_J, 2);
  auto target = [&](const std::string& label, double value, const std::string& unit, double limit,
                    const std::string& what) {
    const bool over = value > limit;
    s.summary.push_back(row(label, num(value, 4), unit, over ? "note" : "ok",
                            what + (over ? "; above the target " : "; target <= ") +
                                fmt(limit, 3) + " " + unit));
  };
  target("largest force step", q.force_step_max_N, "N per 10 ms", 20.0,
         "change of one contact force between samples, lift-off and touch-down included");
  target("acceleration at the start", q.start_acceleration, "m/s^2", 0.1,
         "a plan from rest starts at rest");
  target("acceleration at the end", q.end_acceleration, "m/s^2", 0.1, "the plan ends at rest");
  target("backward motion", q.backward_max_m, "m", 0.005,
         "largest retreat along the start-to-end direction");
  target("lateral sway", q.lateral_sway_m, "m", 0.02,
         "largest distance from the straight line from start to end");
  target("swing rise", q.swing_rise_max_m, "m", 0.10,
         "highest swing above the higher of its lift-off and touch-down points");
  s.summary.push_back(row("body height variation", num(q.body_height_variation_m, 4), "m", "ok",
                          "range of the base height above the feet in contact"));
  s.summary.push_back(row("base jerk (99th percentile)", num(q.jerk_p99, 3), "m/s^3", "ok",
                          "differences of the sampled accelerations"));
  if (q.has_support_margin && std::isfinite(q.support_margin_min_m))
    s.summary.push_back(row("static support margin (min)", num(q.support_margin_min_m, 4), "m",
                            "ok",
                            "base against the hull of the feet down while one swings (three or more), "
                            "positive inside; "
                            "10th percentile " +
                                fmt(q.support_margin_p10_m, 3) + " m"));
  if (q.path_ratio > 0)
    s.summary.push_back(row("path length / straight distance", num(q.path_ratio, 4), "", "ok",
                            "horizontal path of the base"));
  s.summary.push_back(row("energy proxy", num(s.checks.torque.energy_proxy_J, 1), "J", "ok",
                          "integral of sum |tau q'| over joints (torque check)"));
  return out;
}

}  // namespace terrastride::service::report
