// Plans a robot engineer accepts, on a short flat crawl solved end to end: at rest at
// both ends (zero accelerations, forces balancing gravity), forces that ramp with "all", and the
// objective's stop (feasible and good enough) still stopping early.
#include <gtest/gtest.h>

#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/quality.hpp"
#include "test_robots.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

PlannerOptions crawl(const std::vector<std::string>& sets) {
  PlannerOptions o;
  o.gait = "crawl";
  o.cycles = 1;
  o.duration = 4.0;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(0.3, 0.0, 0.0);
  o.constraints = sets;
  return o;
}

TEST(NaturalMotion, RestsAtBothEndsWithForcesBalancingGravity) {
  const auto r = hyq();
  FlatField flat;
  const auto out = plan_motion(r, flat, flat, crawl({"baseline"}), 0.01);
  ASSERT_TRUE(out.success) << out.message;
  const auto& S = out.trajectory.samples;
  for (const auto* s : {&S.front(), &S.back()}) {
    EXPECT_LT(s->base.linear_acceleration.norm(), 1e-3) << "t " << s->t;
    EXPECT_LT(s->base.angular_acceleration.norm(), 1e-3) << "t " << s->t;
    EXPECT_LT(s->base.linear_velocity.norm(), 1e-6) << "t " << s->t;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const auto& f : s->feet) sum += f.force;
    EXPECT_NEAR(sum.z(), r.mass * 9.81, 0.05) << "t " << s->t;
    EXPECT_NEAR(sum.head<2>().norm(), 0.0, 0.05) << "t " << s->t;
  }
  EXPECT_EQ(out.trajectory.extra["solver_termination"], "feasible_point");
}

// With "force_ramp" no foot lifts off or touches down under load, and no force changes by more
// than its rate bound; the dense checks report the largest rate.
TEST(NaturalMotion, ForcesRampWithForceRamp) {
  const auto r = hyq();
  FlatField flat;
  auto without = crawl({"baseline"});
  without.objective = ObjectiveWeights::none();
  const auto a = plan_motion(r, flat, flat, without, 0.01);
  const auto b = plan_motion(r, flat, flat, crawl({"force_ramp"}), 0.01);
  ASSERT_TRUE(a.success && b.success);
  const double step_a = plan_quality(a.trajectory).force_step_max_N;
  const double step_b = plan_quality(b.trajectory).force_step_max_N;
  EXPECT_GT(step_a, 50.0);   // the zero-objective plan steps
  EXPECT_LE(step_b, 20.0 + 1e-3);  // 2000 N/s, 20 N per 10 ms
  EXPECT_LE(b.trajectory.checks.at("force_rate_max_N_per_s"), 2000.0 * (1 + 1e-3));
  EXPECT_GT(a.trajectory.checks.at("force_rate_max_N_per_s"), 5000.0);
}

// With the tuned objective the improvement phase returns a feasible plan whose objective is
// below the feasibility phase's point's, at rest at both ends still.
TEST(NaturalMotion, ObjectiveImprovesAFeasiblePlan) {
  const auto r = hyq();
  FlatField flat;
  auto o = crawl({"baseline"});
  o.objective = ObjectiveWeights{};
  const auto out = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(out.success) << out.message;
  const auto& phases = out.trajectory.extra["solver_phases"];
  EXPECT_GT(phases["objective_iterations"].get<int>(), 0);
  EXPECT_LT(out.trajectory.extra["objective"].get<double>(),
            0.9 * phases["objective_at_feasible_point"].get<double>());
  EXPECT_LE(out.solve.max_violation, o.feasibility_stop_tolerance);
  EXPECT_LT(out.trajectory.samples.back().base.linear_acceleration.norm(), 1e-3);
}

// The path-shape families (monotone_progress, lateral_corridor, swing_apex) bound the splines'
// control points, so their bounds hold on the dense samples of the solved plan, not only at the
// knots; the same plan without them breaks the same (tight) bounds. A diagonal, turning goal, so
// the corridor follows the start-to-goal line.
TEST(NaturalMotion, PathShapeBoundsHoldOnTheDenseSamples) {
  const auto r = hyq();
  TanhStep step(0.1, 0.6, 0.02);  // the front feet step up onto it
  auto o = crawl({"baseline", "monotone_progress", "lateral_corridor", "swing_apex"});
  o.goal = Eigen::Vector3d(0.4, 0.1, 0.2);
  constexpr double kCorridor = 0.005, kRise = 0.07;
  const auto without = plan_motion(r, step, step, o, 0.01);
  o.feasibility_settings = {
      {"monotone_progress", 1.0}, {"lateral_corridor", kCorridor}, {"swing_apex_rise", kRise}};
  const auto with = plan_motion(r, step, step, o, 0.01);
  ASSERT_TRUE(without.success) << without.message;
  ASSERT_TRUE(with.success) << with.message;
  const PlanQuality a = plan_quality(without.trajectory), b = plan_quality(with.trajectory);
  EXPECT_LE(b.backward_max_m, 1e-6);
  EXPECT_LE(b.lateral_sway_m, kCorridor + 1e-6);
  EXPECT_LE(b.swing_rise_max_m, kRise + 1e-6);
  EXPECT_GT(a.backward_max_m + std::max(0.0, a.lateral_sway_m - kCorridor) +
                std::max(0.0, a.swing_rise_max_m - kRise),
            1e-3)
      << "back " << a.backward_max_m << " sway " << a.lateral_sway_m << " rise "
      << a.swing_rise_max_m;
  EXPECT_GE(b.swings.size(), 4u);
}

}  // namespace
}  // namespace terrastride::planner
