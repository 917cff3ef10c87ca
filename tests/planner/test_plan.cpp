// End-to-end planning: solves to optimal, reaches the goal, and holds every constraint densely.
#include <gtest/gtest.h>

#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "test_terrains.hpp"

namespace terrastride::planner {
namespace {

robot::RobotModel hyq() { return robot::load_robot(robot::resolve_robot_path("hyq")); }

void expect_dense_targets(const Trajectory& t, double mass) {
  const auto& c = t.checks;
  EXPECT_LE(c.at("dynamics_linear_max_N"), 0.02 * mass * 9.81);
  if (c.count("dynamics_angular_max_Nm")) {
    EXPECT_LE(c.at("dynamics_angular_max_Nm"), 10.0);
  }
  EXPECT_LE(c.at("penetration_max_m"), 0.005);
  EXPECT_LE(c.at("friction_violation_max_N"), 1.0);
  EXPECT_LE(c.at("slip_max_m"), 0.001);
  EXPECT_LE(c.at("range_of_motion_excess_max_m"), 0.005);
}

TEST(Plan, FlatCrawlReachesGoal) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(1.0, 0.0, 0.0);
  o.duration = 2.4;
  const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(out.success) << out.message;
  EXPECT_EQ(out.trajectory.solver.status, "optimal");
  const auto& last = out.trajectory.samples.back();
  EXPECT_NEAR(last.t, 2.4, 1e-9);
  EXPECT_NEAR(last.base.position.x(), 1.0, 1e-6);
  EXPECT_NEAR(last.base.position.y(), 0.0, 1e-6);
  for (const auto& kv : out.trajectory.checks) std::printf("%s = %g\n", kv.first.c_str(), kv.second);
  std::printf("iterations %d wall %.3f s vars %d cons %d\n", out.trajectory.solver.iterations,
              out.trajectory.solver.wall_s, out.trajectory.solver.n_variables,
              out.trajectory.solver.n_constraints);
  expect_dense_targets(out.trajectory, r.mass);
}

}  // namespace
}  // namespace terrastride::planner
