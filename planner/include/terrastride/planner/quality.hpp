// How natural a planned motion is, as a robot engineer would judge it: figures read
// from the plan's samples alone, written as plan.json's "quality" block, shown by the report and
// printed by the scenario benchmark. The energy proxy needs the joint torques, so the post-hoc
// torque check adds it (collision::TorqueReport::energy_proxy_J, key energy_proxy_J).
#pragma once

#include <nlohmann/json.hpp>
#include <vector>

#include "terrastride/planner/trajectory.hpp"

namespace terrastride::planner {

struct SwingApex {
  int foot = -1;
  double lift_off_t = 0.0, touch_down_t = 0.0;
  // Highest foot point of the swing above the higher of its lift-off and touch-down points (m).
  double rise_m = 0.0;
};

struct PlanQuality {
  // Path length of the base in the horizontal plane over the straight distance from its first to
  // its last sample (1 = straight; absent, -1, when the base ends within 1 cm of its start).
  double path_ratio = -1.0;
  // Largest retreat along the start-to-end direction: how far the base falls back behind the
  // furthest point it had reached (m; 0 when it never backs up).
  double backward_max_m = 0.0;
  // Largest horizontal distance of the base from the straight line from its start to its end (m).
  double lateral_sway_m = 0.0;
  // Range (max - min) of the base height above the mean height of the feet in contact (m).
  double body_height_variation_m = 0.0;
  // 99th percentile of |r'''| (base jerk, m/s^3) by differences of the sampled accelerations.
  double jerk_p99 = 0.0;
  // Largest change of one contact force between two samples, per 10 ms (N), lift-offs and
  // touch-downs included (a swing foot's force is zero).
  double force_step_max_N = 0.0;
  // |r''| and |w'| at the first and the last sample (m/s^2, rad/s^2).
  double start_acceleration = 0.0, end_acceleration = 0.0;
  double start_angular_acceleration = 0.0, end_angular_acceleration = 0.0;
  // Static support margin: over the samples with a foot in the air and three or more in contact
  // (a crawl's three-foot phases), the horizontal position of the base (the single rigid body's
  // centre of mass) against the convex hull of those feet: the smallest signed distance to the
  // lines of the hull's edges, positive inside (m). Its minimum and 10th percentile; absent
  // (has_support_margin false) when no such sample exists (a trot, a pace, a bound). A crawl
  // that sways less has less of it: what a push toward a swinging leg meets (docs/design.md
  // §6.4).
  bool has_support_margin = false;
  double support_margin_min_m = 0.0, support_margin_p10_m = 0.0;
  // Every swing that lifts off and touches down within the plan, and the largest rise.
  std::vector<SwingApex> swings;
  double swing_rise_max_m = 0.0;
};

PlanQuality plan_quality(const Trajectory& plan);
// plan.json's "quality" object (swing apexes as {foot, lift_off_t, touch_down_t, rise_m}).
nlohmann::json quality_to_json(const PlanQuality& q, const std::vector<std::string>& feet);

}  // namespace terrastride::planner
