// plan.json's quality figures (planner/quality.hpp) on made-up trajectories whose
// answers are known by construction.
#include <gtest/gtest.h>

#include <cmath>

#include "terrastride/planner/quality.hpp"

namespace terrastride::planner {
namespace {

// Two feet, 10 ms samples over 2 s. The base goes 1 m along x with a 3 cm sideways bump and a
// 2 cm retreat; foot 1 swings from t = 0.5 to 1.0 s with an apex 7 cm above its higher end.
Trajectory made_up() {
  Trajectory t;
  t.feet = {"A", "B"};
  t.sample_dt = 0.01;
  for (int k = 0; k <= 200; ++k) {
    TrajectorySample s;
    s.t = 0.01 * k;
    const double u = s.t / 2.0;
    double x = u;
    if (s.t > 1.0 && s.t <= 1.2) x = 0.5 - 0.1 * (s.t - 1.0);  // backs up 2 cm
    if (s.t > 1.2) x = 0.48 + (s.t - 1.2) * (0.52 / 0.8);
    const double y = 0.03 * std::exp(-std::pow((s.t - 0.6) / 0.05, 2));
    s.base.position = Eigen::Vector3d(x, y, 0.6 + (s.t > 1.5 ? 0.01 : 0.0));
    s.base.linear_acceleration = Eigen::Vector3d(k == 0 ? 0.3 : 0.0, 0.0, 0.0);
    FootState a, b;
    a.contact = true;
    a.force = Eigen::Vector3d(0, 0, 400);
    b.contact = !(s.t > 0.5 && s.t < 1.0);
    b.force = b.contact ? Eigen::Vector3d(0, 0, 400) : Eigen::Vector3d::Zero();
    b.position = Eigen::Vector3d(0, 0, s.t >= 1.0 ? 0.05 : 0.0);
    if (!b.contact) b.position.z() = 0.12 * std::sin(M_PI * (s.t - 0.5) / 0.5);
    s.feet = {a, b};
    t.samples.push_back(s);
  }
  return t;
}

TEST(PlanQuality, FiguresOfAKnownTrajectory) {
  const Trajectory t = made_up();
  const PlanQuality q = plan_quality(t);
  EXPECT_NEAR(q.backward_max_m, 0.02, 1e-9);
  EXPECT_NEAR(q.lateral_sway_m, 0.03, 2e-4);
  // The rise is measured above the higher end (the touch-down at 5 cm): the apex reached at the
  // samples is 12 cm.
  ASSERT_EQ(q.swings.size(), 1u);
  EXPECT_EQ(q.swings[0].foot, 1);
  EXPECT_NEAR(q.swings[0].lift_off_t, 0.5, 1e-9);
  EXPECT_NEAR(q.swings[0].touch_down_t, 1.0, 1e-9);
  EXPECT_NEAR(q.swings[0].rise_m, 0.12 - 0.05, 1e-9);
  EXPECT_NEAR(q.swing_rise_max_m, 0.07, 1e-9);
  // Lift-off under load: 400 N within one 10 ms sample.
  EXPECT_NEAR(q.force_step_max_N, 400.0, 1e-9);
  EXPECT_NEAR(q.start_acceleration, 0.3, 1e-12);
  EXPECT_EQ(q.end_acceleration, 0.0);
  // Base 60 cm above the feet before the swing and in it (foot A alone), 57.5 cm above the mean
  // of A and B after it (B touched down 5 cm higher), 58.5 cm once the base rises 1 cm.
  EXPECT_NEAR(q.body_height_variation_m, 0.6 - 0.575, 1e-9);
  // The path: 1 m forward plus the retreat twice (there and back) plus the bump twice, roughly.
  EXPECT_GT(q.path_ratio, 1.04);
  EXPECT_LT(q.path_ratio, 1.12);
  // Jerk: the 0.3 m/s^2 start drops to 0 in one sample (30 m/s^3), the only nonzero difference,
  // below the 99th percentile of 200 differences.
  EXPECT_EQ(q.jerk_p99, 0.0);
  const auto j = quality_to_json(q, t.feet);
  EXPECT_EQ(j["swings"][0]["foot"], "B");
  EXPECT_TRUE(j.contains("path_ratio"));
}

// Per 10 ms whatever the sampling: the same ramp sampled every 2 ms gives the same step.
TEST(PlanQuality, ForceStepIsPerTenMilliseconds) {
  for (double dt : {0.002, 0.01, 0.02}) {
    Trajectory t;
    t.feet = {"A"};
    for (int k = 0; k * dt <= 1.0 + 1e-9; ++k) {
      TrajectorySample s;
      s.t = k * dt;
      FootState a;
      a.contact = true;
      a.force = Eigen::Vector3d(0, 0, 1000.0 * s.t);  // 10 N per 10 ms
      s.feet = {a};
      t.samples.push_back(s);
    }
    EXPECT_NEAR(plan_quality(t).force_step_max_N, 10.0, 1e-9) << dt;
  }
}

// The static support margin of known stances: three feet at (0, 0), (1, 0), (0, 1) and the base
// at (0.2, 0.3) is 0.2 from the edge x = 0 (and 0.3 from y = 0, 0.354 from x + y = 1); at
// (0.7, 0.6) it is outside the hypotenuse by 0.3 / sqrt 2. Four feet on a square add nothing
// that binds; two feet down (a trot) leave it absent; a foot in the air does not count.
TEST(PlanQuality, SupportMarginOfKnownStances) {
  auto sample = [](Eigen::Vector2d base, std::vector<Eigen::Vector2d> feet, int airborne) {
    TrajectorySample s;
    s.base.position = Eigen::Vector3d(base.x(), base.y(), 0.5);
    for (std::size_t i = 0; i < feet.size(); ++i) {
      FootState f;
      f.position = Eigen::Vector3d(feet[i].x(), feet[i].y(), 0.0);
      f.contact = static_cast<int>(i) != airborne;
      s.feet.push_back(f);
    }
    return s;
  };
  const std::vector<Eigen::Vector2d> square = {{0, 0}, {1, 0}, {0, 1}, {1, 1}};
  Trajectory t;
  t.feet = {"A", "B", "C", "D"};
  for (int k = 0; k < 10; ++k) {
    TrajectorySample s = sample({0.2, 0.3}, square, 3);  // D in the air: the triangle
    s.t = 0.01 * k;
    t.samples.push_back(s);
  }
  PlanQuality q = plan_quality(t);
  ASSERT_TRUE(q.has_support_margin);
  EXPECT_NEAR(q.support_margin_min_m, 0.2, 1e-12);
  EXPECT_NEAR(q.support_margin_p10_m, 0.2, 1e-12);
  // One sample outside the hypotenuse, nine inside: the minimum is negative, the 10th
  // percentile (the first of ten) is the outside one too; with a tenth inside sample more, the
  // percentile moves to the inside value.
  t.samples[4] = sample({0.7, 0.6}, square, 3);
  q = plan_quality(t);
  EXPECT_NEAR(q.support_margin_min_m, -0.3 / std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(q.support_margin_p10_m, -0.3 / std::sqrt(2.0), 1e-12);
  t.samples.push_back(sample({0.2, 0.3}, square, 3));
  EXPECT_NEAR(plan_quality(t).support_margin_p10_m, 0.2, 1e-12);
  // The JSON block carries both figures.
  const auto j = quality_to_json(plan_quality(t), t.feet);
  EXPECT_NEAR(j.at("support_margin_min_m").get<double>(), -0.3 / std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(j.at("support_margin_p10_m").get<double>(), 0.2, 1e-12);
  // Four of five feet down while the fifth swings: the square, 0.2 from its nearest side.
  std::vector<Eigen::Vector2d> five = square;
  five.push_back({2, 2});
  Trajectory pentapod;
  pentapod.feet = {"A", "B", "C", "D", "E"};
  for (int k = 0; k < 5; ++k) pentapod.samples.push_back(sample({0.2, 0.5}, five, 4));
  EXPECT_NEAR(plan_quality(pentapod).support_margin_min_m, 0.2, 1e-12);
  // A trot: its lead-in and lead-out stand on four feet, its pairs on two. Neither counts (all
  // feet down never binds, two feet have no area), so the figures are absent, not the lead-in's.
  Trajectory trot;
  trot.feet = t.feet;
  for (int k = 0; k < 30; ++k) {
    TrajectorySample s = sample({0.5, 0.5}, square, -1);
    if (k >= 5 && k < 25) {
      s.feet[(k / 5) % 2 == 0 ? 1 : 0].contact = false;  // one diagonal pair in the air
      s.feet[(k / 5) % 2 == 0 ? 2 : 3].contact = false;
    }
    trot.samples.push_back(s);
  }
  EXPECT_FALSE(plan_quality(trot).has_support_margin);
  EXPECT_FALSE(quality_to_json(plan_quality(trot), {"A", "B"}).contains("support_margin_min_m"));
}

}  // namespace
}  // namespace terrastride::planner
