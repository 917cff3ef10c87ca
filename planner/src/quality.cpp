// Quality figures of a plan (quality.hpp), from its samples.
#include "terrastride/planner/quality.hpp"

#include <algorithm>
#include <cmath>

namespace terrastride::planner {

PlanQuality plan_quality(const Trajectory& plan) {
  PlanQuality q;
  const auto& S = plan.samples;
  if (S.empty()) return q;
  const std::size_t n = S.size();
  const Eigen::Vector2d p0 = S.front().base.position.head<2>();
  const Eigen::Vector2d p1 = S.back().base.position.head<2>();
  const double straight = (p1 - p0).norm();
  double length = 0.0;
  for (std::size_t k = 1; k < n; ++k)
    length += (S[k].base.position.head<2>() - S[k - 1].base.position.head<2>()).norm();
  if (straight > 0.01) {
    q.path_ratio = length / straight;
    const Eigen::Vector2d along = (p1 - p0) / straight;
    const Eigen::Vector2d across(-along.y(), along.x());
    double furthest = 0.0;
    for (const auto& s : S) {
      const Eigen::Vector2d d = s.base.position.head<2>() - p0;
      const double progress = along.dot(d);
      furthest = std::max(furthest, progress);
      q.backward_max_m = std::max(q.backward_max_m, furthest - progress);
      q.lateral_sway_m = std::max(q.lateral_sway_m, std::abs(across.dot(d)));
    }
  } else {
    for (const auto& s : S)
      q.lateral_sway_m = std::max(q.lateral_sway_m, (s.base.position.head<2>() - p0).norm());
  }
  // Body height over the feet in contact.
  double hmin = INFINITY, hmax = -INFINITY;
  for (const auto& s : S) {
    double sum = 0.0;
    int c = 0;
    for (const auto& f : s.feet)
      if (f.contact) {
        sum += f.position.z();
        ++c;
      }
    if (c == 0) continue;
    const double h = s.base.position.z() - sum / c;
    hmin = std::min(hmin, h);
    hmax = std::max(hmax, h);
  }
  if (hmax >= hmin) q.body_height_variation_m = hmax - hmin;
  // Jerk by differences of the sampled accelerations.
  std::vector<double> jerk;
  for (std::size_t k = 1; k < n; ++k) {
    const double dt = S[k].t - S[k - 1].t;
    if (dt <= 0.0) continue;
    jerk.push_back((S[k].base.linear_acceleration - S[k - 1].base.linear_acceleration).norm() / dt);
  }
  if (!jerk.empty()) {
    std::sort(jerk.begin(), jerk.end());
    const std::size_t i = std::min(jerk.size() - 1,
                                   static_cast<std::size_t>(std::ceil(0.99 * jerk.size())) - 1);
    q.jerk_p99 = jerk[i];
  }
  // Force steps per 10 ms.
  for (std::size_t k = 1; k < n; ++k) {
    const double dt = S[k].t - S[k - 1].t;
    if (dt <= 0.0 || S[k].feet.size() != S[k - 1].feet.size()) continue;
    for (std::size_t f = 0; f < S[k].feet.size(); ++f) {
      auto force = [](const FootState& s) {
        return s.contact ? s.force : Eigen::Vector3d::Zero().eval();
      };
      const double step = (force(S[k].feet[f]) - force(S[k - 1].feet[f])).norm() * 0.01 / dt;
      q.force_step_max_N = std::max(q.force_step_max_N, step);
    }
  }
  q.start_acceleration = S.front().base.linear_acceleration.norm();
  q.end_acceleration = S.back().base.linear_acceleration.norm();
  q.start_angular_acceleration = S.front().base.angular_acceleration.norm();
  q.end_angular_acceleration = S.back().base.angular_acceleration.norm();
  // Swings: from the last contact sample to the next one.
  const std::size_t nf = S.front().feet.size();
  for (std::size_t f = 0; f < nf; ++f) {
    std::size_t k = 1;
    while (k < n) {
      if (S[k].feet.size() != nf || S[k - 1].feet.size() != nf) return q;
      if (S[k - 1].feet[f].contact && !S[k].feet[f].contact) {
        const std::size_t lift = k - 1;
        std::size_t j = k;
        double top = -INFINITY;
        while (j < n && !S[j].feet[f].contact) top = std::max(top, S[j++].feet[f].position.z());
        if (j == n) break;  // still swinging at the end
        SwingApex a;
        a.foot = static_cast<int>(f);
        a.lift_off_t = S[lift].t;
        a.touch_down_t = S[j].t;
        a.rise_m = std::max(0.0, top - std::max(S[lift].feet[f].position.z(),
                                                S[j].feet[f].position.z()));
        q.swings.push_back(a);
        q.swing_rise_max_m = std::max(q.swing_rise_max_m, a.rise_m);
        k = j + 1;
      } else {
        ++k;
      }
    }
  }
  return q;
}

nlohmann::json quality_to_json(const PlanQuality& q, const std::vector<std::string>& feet) {
  nlohmann::json swings = nlohmann::json::array();
  for (const auto& a : q.swings)
    swings.push_back({{"foot", a.foot >= 0 && a.foot < static_cast<int>(feet.size())
                                   ? feet[a.foot]
                                   : std::to_string(a.foot)},
                      {"lift_off_t", a.lift_off_t},
                      {"touch_down_t", a.touch_down_t},
                      {"rise_m", a.rise_m}});
  nlohmann::json j = {{"backward_max_m", q.backward_max_m},
                      {"lateral_sway_m", q.lateral_sway_m},
                      {"body_height_variation_m", q.body_height_variation_m},
                      {"jerk_p99_m_s3", q.jerk_p99},
                      {"force_step_max_N_per_10ms", q.force_step_max_N},
                      {"start_acceleration_m_s2", q.start_acceleration},
                      {"end_acceleration_m_s2", q.end_acceleration},
                      {"start_angular_acceleration_rad_s2", q.start_angular_acceleration},
                      {"end_angular_acceleration_rad_s2", q.end_angular_acceleration},
                      {"swing_rise_max_m", q.swing_rise_max_m},
                      {"swings", swings}};
  if (q.path_ratio > 0) j["path_ratio"] = q.path_ratio;
  return j;
}

}  // namespace terrastride::planner
