// Quality figures of a plan (quality.hpp), from its samples.
#include "terrastride/planner/quality.hpp"

#include <algorithm>
#include <cmath>

#include "convex_hull.hpp"

namespace terrastride::planner {

namespace {

// Signed distance of c to the convex hull of `points` (3 or more, in the horizontal plane): the
// smallest distance to the lines of the hull's edges, positive inside.
double support_margin(const Eigen::Vector2d& c, std::vector<Eigen::Vector2d> points) {
  const std::vector<Eigen::Vector2d> hull = convex_hull_2d(std::move(points));
  if (hull.size() < 3) return -INFINITY;  // collinear feet: no area to stand in
  double margin = INFINITY;
  for (std::size_t i = 0; i < hull.size(); ++i) {
    const Eigen::Vector2d& a = hull[i];
    const Eigen::Vector2d& b = hull[(i + 1) % hull.size()];
    margin = std::min(margin, cross_2d(a, b, c) / (b - a).norm());
  }
  return margin;
}

}  // namespace

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
  // Static support margin over the samples with a foot in the air and three or more down (all
  // feet down is a larger polygon that never binds, and a trot's lead-in and lead-out would
  // otherwise be all it measured).
  std::vector<double> margins;
  for (const auto& s : S) {
    std::vector<Eigen::Vector2d> down;
    for (const auto& f : s.feet)
      if (f.contact) down.push_back(f.position.head<2>());
    if (down.size() >= 3 && down.size() < s.feet.size())
      margins.push_back(support_margin(s.base.position.head<2>(), down));
  }
  if (!margins.empty()) {
    std::sort(margins.begin(), margins.end());
    q.has_support_margin = true;
    q.support_margin_min_m = margins.front();
    q.support_margin_p10_m = margins[(margins.size() - 1) / 10];
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
  // A collinear stance's -inf is written as null (JSON has no infinity).
  if (q.has_support_margin) {
    auto finite_or_null = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
    j["support_margin_min_m"] = finite_or_null(q.support_margin_min_m);
    j["support_margin_p10_m"] = finite_or_null(q.support_margin_p10_m);
  }
  return j;
}

}  // namespace terrastride::planner
