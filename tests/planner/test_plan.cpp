// End-to-end planning: solves to optimal, reaches the goal, and holds every constraint densely.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/joint_points.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/planner/planning_session.hpp"
#include "terrastride/planner/polytope_fit.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"
#include <Eigen/LU>

#include "terrastride/robot/geometry.hpp"
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

// Planner options with a goal x metres ahead (y 0, yaw 0), the rest default.
PlannerOptions options_to_goal(double x) {
  PlannerOptions o;
  o.has_goal = true;
  o.goal = Eigen::Vector3d(x, 0.0, 0.0);
  return o;
}

// Go2 with its knees' velocity limit cut from 15.7 to 8 rad/s, a 1 m trot in 1.4 s, `all`: the
// joint rows hold at their points, and a swinging knee passed its limit between them (1.009x at
// 1 ms samples). plan_motion's refinement finds it, adds rows there and solves again; with
// joint_refinement_rounds = 0 the plan is the first solve's and carries no record.
TEST(Plan, JointRefinementHoldsVelocitiesBetweenConstraintPoints) {
  auto r = robot::load_robot(robot::resolve_robot_path("go2"));
  for (auto& leg : r.legs) leg.velocity_limit[2] = 8.0;
  // The CLI's `--terrain flat`: the scene, and the smooth map of it the optimiser sees.
  const auto scene = terrain::make_scene("flat");
  const auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  PlannerOptions o = options_to_goal(1.0);
  o.gait = "trot";
  o.duration = 1.4;
  o.cycles = default_cycles(r, o.start, o.goal);
  o.constraints = {"all"};
  o.joint_refinement_rounds = 0;
  const PlanOutcome off = plan_motion(r, *smooth, *scene, o, 0.01);
  ASSERT_TRUE(off.success) << off.message;
  EXPECT_FALSE(off.trajectory.extra.contains("joint_refinement"));
  o.joint_refinement_rounds = 3;
  const PlanOutcome on = plan_motion(r, *smooth, *scene, o, 0.01);
  ASSERT_TRUE(on.success) << on.message;
  ASSERT_TRUE(on.trajectory.extra.contains("joint_refinement"));
  const nlohmann::json& refinement = on.trajectory.extra["joint_refinement"];
  EXPECT_GT(refinement["before"]["velocity_ratio"].get<double>(), 1.0);
  EXPECT_LE(refinement["after"]["velocity_ratio"].get<double>(), 1.0);
  EXPECT_TRUE(refinement["held"].get<bool>());
  EXPECT_GT(on.trajectory.solver.iterations, off.trajectory.solver.iterations);
  EXPECT_GT(on.trajectory.solver.n_constraints, off.trajectory.solver.n_constraints);
}

// Go2 with its knees' torque limit cut from 45.43 to 10 N m (its force polytopes fitted anew,
// beside a copy of its robot file) and the polytope rows at the force knots only
// (polytope_inner_points 0, polytope_softmax 0), the default 1 m crawl on flat, `all`: the rows
// hold at the knots and a stance knee passed its torque limit between them (1.026x at 1 ms).
// The refinement finds it, adds polytope rows at the worst instants and solves again; with
// joint_refinement_rounds = 0 the plan is the first solve's and carries no record.
TEST(Plan, JointRefinementHoldsTorquesBetweenConstraintPoints) {
  auto r = robot::load_robot(robot::resolve_robot_path("go2"));
  for (auto& leg : r.legs) leg.torque_limit[2] = 10.0;
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("terrastride_knee10_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  r.source_file = (dir / "go2_knee10.yaml").string();  // the polytopes are read beside it
  save_polytope_model(fit_robot_polytopes(r, PolytopeFitOptions{}, nullptr), r,
                      polytope_path_for(r));
  const auto scene = terrain::make_scene("flat");
  const auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  PlannerOptions o = options_to_goal(1.0);
  o.cycles = default_cycles(r, o.start, o.goal);
  o.constraints = {"all"};
  o.feasibility_settings = {{"polytope_inner_points", 0.0}, {"polytope_softmax", 0.0}};
  o.joint_refinement_rounds = 0;
  const PlanOutcome off = plan_motion(r, *smooth, *scene, o, 0.01);
  o.joint_refinement_rounds = 3;
  const PlanOutcome on = plan_motion(r, *smooth, *scene, o, 0.01);
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(off.success) << off.message;
  EXPECT_FALSE(off.trajectory.extra.contains("joint_refinement"));
  ASSERT_TRUE(on.success) << on.message;
  ASSERT_TRUE(on.trajectory.extra.contains("joint_refinement"));
  const nlohmann::json& refinement = on.trajectory.extra["joint_refinement"];
  EXPECT_GT(refinement["before"]["torque_ratio"].get<double>(), 1.0);
  EXPECT_LE(refinement["after"]["torque_ratio"].get<double>(), 1.0);
  EXPECT_TRUE(refinement["held"].get<bool>());
  EXPECT_FALSE(refinement.contains("ended"));
  EXPECT_EQ(joint_refinement_stop_clause(refinement), "");
  EXPECT_GT(on.trajectory.solver.n_constraints, off.trajectory.solver.n_constraints);
}

// The clause the CLI adds to a plan's post-hoc failure when the refinement gave up: how it ended
// and what the dense check still finds; nothing when it held or never ran.
TEST(Plan, JointRefinementStopClauseSaysHowItEnded) {
  EXPECT_EQ(joint_refinement_stop_clause(nullptr), "");
  nlohmann::json record = {{"rounds", nlohmann::json::array()},
                           {"after", {{"range_excess_rad", 0.0}, {"torque_ratio", 1.04}}},
                           {"held", false}};
  EXPECT_EQ(joint_refinement_stop_clause(record), "");  // ran to the end
  for (int k = 0; k < 3; ++k) record["rounds"].push_back({{"status", "optimal"}});
  record["ended"] = "rounds";
  EXPECT_EQ(joint_refinement_stop_clause(record),
            "refinement of the joint rows stopped after 3 rounds with joints still past their "
            "limits between the constraint points (torque 1.04x its limit)");
  record["ended"] = "time";
  record["after"]["velocity_ratio"] = 1.2;
  record["after"]["range_excess_rad"] = 0.01;
  EXPECT_EQ(joint_refinement_stop_clause(record),
            "refinement of the joint rows ran out of time after 3 rounds with joints still past "
            "their limits between the constraint points (velocity 1.2x its limit, torque 1.04x "
            "its limit, 0.01 rad beyond a range)");
  record["ended"] = "rows_hold";
  EXPECT_NE(joint_refinement_stop_clause(record).find("stopped after 3 rounds: the rows at the "
                                                      "worst instants hold already"),
            std::string::npos);
  record["ended"] = "failed";
  record["rounds"].back()["status"] = "infeasible";
  EXPECT_NE(joint_refinement_stop_clause(record).find(
                "stopped after 3 rounds: its re-solve ended infeasible, the previous solution kept"),
            std::string::npos);
}

TEST(Plan, FlatCrawlReachesGoal) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
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

namespace terrastride::planner {
namespace {

PlanOutcome plan_scene(const std::string& name, bool timing = false) {
  const auto r = hyq();
  auto scene = terrain::make_scene(name);
  auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 0.0;  // the gait's default: 3 crawl cycles of 3.6667 s (the CLI's default)
  o.optimize_timing = timing;
  return plan_motion(r, *smooth, *scene, o, 0.01);
}

class PalletPlan : public ::testing::TestWithParam<std::string> {};

TEST_P(PalletPlan, SolvesToOptimalReachesGoalAndHoldsDensely) {
  const PlanOutcome out = plan_scene(GetParam());
  ASSERT_TRUE(out.success) << out.message;
  EXPECT_EQ(out.trajectory.solver.status, "optimal");
  const auto& last = out.trajectory.samples.back();
  EXPECT_NEAR(last.base.position.x(), 1.0, 1e-6);
  // Every foot ends on the pallet top, and the base stands above it.
  for (const auto& f : last.feet) EXPECT_TRUE(f.contact);
  EXPECT_GT(last.base.position.z(), 0.58);
  expect_dense_targets(out.trajectory, hyq().mass);
  EXPECT_LE(out.trajectory.checks.at("stance_height_error_max_m"), 0.005);
}

INSTANTIATE_TEST_SUITE_P(Scenes, PalletPlan, ::testing::Values("pallet_10", "pallet_15"));

// The stairs (three 0.12 m risers, 0.30 m treads): at the goal the front feet stand on the top
// (0.36 m) and the hind feet on the first tread (0.12 m), 0.24 m lower -- more than the
// range-of-motion box's 2 x 0.10 m allows with a level base, so the goal pose pitches the base
// nose-up with the terrain. Fixed and optimised timing both solve.
class StairsPlan : public ::testing::TestWithParam<bool> {};

TEST_P(StairsPlan, SolvesToOptimalReachesGoalAndHoldsDensely) {
  const PlanOutcome out = plan_scene("stairs", GetParam());
  ASSERT_TRUE(out.success) << out.message;
  EXPECT_EQ(out.trajectory.solver.status, "optimal");
  const auto& last = out.trajectory.samples.back();
  EXPECT_NEAR(last.base.position.x(), 1.0, 1e-6);
  EXPECT_NEAR(last.base.position.y(), 0.0, 1e-6);
  for (const auto& f : last.feet) EXPECT_TRUE(f.contact);
  // Front feet on the top step, hind feet on a tread below it; the base pitched nose-up.
  EXPECT_NEAR(last.feet[0].position.z(), 0.36, 0.005);
  EXPECT_NEAR(last.feet[1].position.z(), 0.36, 0.005);
  EXPECT_LT(last.feet[2].position.z(), 0.30);
  EXPECT_LT(last.feet[3].position.z(), 0.30);
  EXPECT_LT(last.base.euler_zyx[1], -0.1);
  expect_dense_targets(out.trajectory, hyq().mass);
  EXPECT_LE(out.trajectory.checks.at("stance_height_error_max_m"), 0.005);
  if (out.trajectory.checks.count("unsafe_footholds")) {
    EXPECT_EQ(out.trajectory.checks.at("unsafe_footholds"), 0.0);
  }
}

INSTANTIATE_TEST_SUITE_P(Timing, StairsPlan, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& i) {
                           return std::string(i.param ? "Optimised" : "Fixed");
                         });

// Replanning from the previous plan shifted by 0.1 s (what a robot does every control period):
// the warm start converges in a fraction of the cold iterations, to a plan that still reaches
// the goal and holds densely.
TEST(Plan, WarmStartFromAShiftedPlanConvergesFast) {
  const auto r = hyq();
  auto scene = terrain::make_scene("pallet_10");
  auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  PlannerOptions o = options_to_goal(1.0);
  const PlanOutcome cold = plan_motion(r, *smooth, *scene, o, 0.01);
  ASSERT_TRUE(cold.success) << cold.message;
  WarmStart warm;
  warm.previous = &cold.trajectory;
  warm.shift = 0.1;
  const PlanOutcome next = plan_motion(r, *smooth, *scene, o, 0.01, warm);
  ASSERT_TRUE(next.success) << next.message;
  std::printf("cold %d iterations, warm %d\n", cold.trajectory.solver.iterations,
              next.trajectory.solver.iterations);
  // The shifted plan keeps the previous knots and constraint points (Layout::segment_points), so
  // the previous solution is verified feasible at iteration 0 and returned.
  EXPECT_EQ(next.trajectory.solver.iterations, 0);
  EXPECT_NEAR(next.trajectory.duration, cold.trajectory.duration - 0.1, 1e-6);
  EXPECT_NEAR(next.trajectory.samples.back().base.position.x(), 1.0, 1e-6);
  expect_dense_targets(next.trajectory, r.mass);
  // It is the previous plan's tail: the same base position 0.5 s on.
  EXPECT_NEAR((interpolate_plan(next.trajectory, 0.5).base.position -
               interpolate_plan(cold.trajectory, 0.6).base.position)
                  .norm(),
              0.0, 1e-6);

  // A robot is never exactly on its plan: from a measured state 1 cm beside it and 0.05 m/s
  // faster, the re-plan needs iterations, and must still solve, start there and hold densely
  // (a monotone barrier, used for warm starts before, ended infeasible on pallet_15).
  SrbdProblem::StartState measured = start_state_of(cold.trajectory, 0.1);
  measured.position.y() += 0.01;
  measured.linear_velocity.x() += 0.05;
  warm.start = &measured;
  const PlanOutcome off = plan_motion(r, *smooth, *scene, o, 0.01, warm);
  ASSERT_TRUE(off.success) << off.message;
  std::printf("from a measured state off the plan: %d iterations\n",
              off.trajectory.solver.iterations);
  EXPECT_GT(off.trajectory.solver.iterations, 0);
  EXPECT_NEAR((off.trajectory.samples.front().base.position - measured.position).norm(), 0.0, 1e-9);
  EXPECT_NEAR(off.trajectory.samples.back().base.position.x(), 1.0, 1e-6);
  expect_dense_targets(off.trajectory, r.mass);
}

// After a push the measured state may lie outside a joint's range and a foot's range-of-motion
// box (e.g. "joints by 0.192 on LF at t = 0.00 s"). Pinned at t = 0, those rows were
// constants no solve could change: the re-plan was infeasible by construction. Now they are left
// out and reported (plan.json "start_excess"), the rows after the start give room back to the
// bounds over start_return, and the re-plan succeeds and is back within the joint ranges and the
// boxes from there on. (With start_return=0, no room, this re-plan stalls after 398 iterations
// with range_of_motion 0.05 m violated at t = 0.00-0.08 s; 0.1 s: 9 iterations, 0.25: 7, 0.5 and
// 1 (the default): 6.)
TEST(Plan, ReplanFromAStartOutsideJointsAndBoxReturnsWithinThem) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 2.4;
  o.constraints = {"baseline", "joints"};
  const PlanOutcome cold = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(cold.success) << cold.message;
  SrbdProblem::StartState measured = start_state_of(cold.trajectory, 0.5);
  // Rolled, pushed sideways and down: LF's joints and RF's box exceeded; the feet stay.
  measured.euler_zyx[2] -= 0.3;
  measured.position.y() -= 0.05;
  measured.position.z() -= 0.1;
  WarmStart warm;
  warm.previous = &cold.trajectory;
  warm.shift = 0.5;
  warm.start = &measured;
  const PlanOutcome next = plan_motion(r, flat, flat, o, 0.01, warm);
  ASSERT_TRUE(next.success) << next.message;
  const auto& excess = next.trajectory.extra.at("start_excess");
  std::printf("start excess %s; %d iterations\n", excess.dump().c_str(),
              next.trajectory.solver.iterations);
  ASSERT_TRUE(excess.contains("joints"));
  ASSERT_TRUE(excess.contains("range_of_motion"));
  EXPECT_GT(excess["joints"].get<double>(), 0.01);
  EXPECT_GT(excess["range_of_motion"].get<double>(), 0.01);
  EXPECT_NEAR((next.trajectory.samples.front().base.position - measured.position).norm(), 0.0,
              1e-9);
  // From start_return on: every joint within its range less the margin, every foot in its box
  // (to the solver's tolerance); before it, at t = 0, outside (what was measured).
  const double span = FeasibilityOptions{}.start_return, margin = FeasibilityOptions{}.joint_margin;
  auto worst_at = [&](const TrajectorySample& s, double* joint, double* box) {
    const Eigen::Matrix3d R = robot::rotation_zyx<double>(s.base.euler_zyx);
    *joint = *box = -1.0;
    for (std::size_t f = 0; f < r.legs.size(); ++f) {
      const auto& leg = r.legs[f];
      const Eigen::Vector3d in_base = R.transpose() * (s.feet[f].position - s.base.position);
      const Eigen::Vector3d q = robot::leg_joint_angles<double>(leg, in_base);
      for (int j = 0; j < 3; ++j)
        *joint = std::max({*joint, q[j] - (leg.q_max[j] - margin), (leg.q_min[j] + margin) - q[j]});
      const Eigen::Vector3d off = in_base - leg.nominal_foot;
      for (int i = 0; i < 3; ++i) *box = std::max(*box, std::abs(off[i]) - leg.range_of_motion[i]);
    }
  };
  double joint0, box0;
  worst_at(next.trajectory.samples.front(), &joint0, &box0);
  EXPECT_GT(joint0, 0.01);
  EXPECT_GT(box0, 0.01);
  double joint_after = -1.0, box_after = -1.0;
  for (const auto& s : next.trajectory.samples) {
    if (s.t < span) continue;
    double j, b;
    worst_at(s, &j, &b);
    joint_after = std::max(joint_after, j);
    box_after = std::max(box_after, b);
  }
  std::printf("at t = 0: joint %.3f rad, box %.3f m past; from %.2f s on: %.4f rad, %.4f m\n",
              joint0, box0, span, joint_after, box_after);
  EXPECT_LE(joint_after, margin);  // within the range: the rows hold at knots, the margin between
  EXPECT_LE(box_after, 0.005);   // as expect_dense_targets
  EXPECT_NEAR(next.trajectory.samples.back().base.position.x(), 1.0, 1e-6);
}

// A session step pins its horizon end to the reference's base, and a stance the measured start
// fixes keeps the measured foothold up to that end (measured: after a left 300 N push on pallet_15
// LH had slipped 7 cm, and the pinned end lay 5.7 cm outside LH's box). The end's rows are then
// constants, left out (session.end_excess), but the rows just before it, whose base must arrive at
// the pinned pose and velocity, got no room: nine steps in a row failed there, range_of_motion
// 2.5 cm violated in the last segment. Now they get the end's excess as room, growing over
// start_return up to the end (start_return.hpp). Here LF, in stance from 1.24 s to 2.04 s of a
// 4.8 s crawl, has slipped 15 cm back at 1.5 s (still within its box there, 11 cm outside it at
// the step's end, 2.04 s): the step solves in 4 iterations; without room (start_return 0, as
// before this) it stalls after 37 iterations and fails again with the end's feet freed (97 in all).
TEST(Plan, SessionStepWithASlippedFootholdUpToItsPinnedEndSolves) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 4.8;
  o.constraints = {"baseline", "joints"};
  const PlanOutcome cold = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(cold.success) << cold.message;
  const double t = 1.5, horizon = 0.5;
  const int lf = 0;
  ASSERT_EQ(r.legs[lf].name, "LF");
  for (const double span : {1.0, 0.0}) {
    PlannerOptions so = o;
    so.feasibility_settings = {{"start_return", span}};
    PlanningSession session(r, flat, flat, so, cold.trajectory, horizon, 0.01);
    SrbdProblem::StartState measured = session.planned_state(t);
    measured.foot_position[lf].x() -= 0.15;
    const SessionStep step = session.step(measured, t);
    const auto& extra = step.outcome.trajectory.extra;
    std::printf("start_return %.1f: %s after %d iterations; %s\n", span,
                step.outcome.solve.status.c_str(), step.outcome.solve.iterations,
                extra["session"].dump().c_str());
    EXPECT_NEAR(step.end_time, 2.04, 1e-6);
    EXPECT_FALSE(extra.contains("start_excess")) << "the slipped foot is within its box at 1.5 s";
    ASSERT_TRUE(extra["session"].contains("end_excess"));
    EXPECT_GT(extra["session"]["end_excess"].value("range_of_motion", 0.0), 0.1);
    if (span > 0.0) {
      ASSERT_TRUE(step.outcome.success) << step.outcome.message;
      EXPECT_FALSE(step.feet_freed);
      // The stance kept its measured foothold to the end.
      EXPECT_NEAR((step.outcome.trajectory.samples.back().feet[lf].position -
                   measured.foot_position[lf]).norm(), 0.0, 1e-9);
    } else {
      EXPECT_FALSE(step.outcome.success) << "without room the step is infeasible by construction";
    }
  }
}

// The paper's flat 2.4 s crawl switches contacts on the 0.01 s sample grid, and its swings are
// under way at most re-plan starts: re-planned from its own state at any of these times, the
// previous plan is re-verified without iterating (before: infeasible at 0.1, 0.3 and 0.55 s, the
// lifting foot's last force read from the sample after lift-off and the swing clearance
// restarted at the crop point).
TEST(Plan, WarmStartOnTheFastCrawlReverifiesThePreviousPlan) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 2.4;
  const PlanOutcome cold = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(cold.success) << cold.message;
  for (double shift : {0.1, 0.2, 0.3, 0.55, 1.0}) {
    WarmStart warm;
    warm.previous = &cold.trajectory;
    warm.shift = shift;
    const PlanOutcome next = plan_motion(r, flat, flat, o, 0.01, warm);
    ASSERT_TRUE(next.success) << shift << ": " << next.message;
    EXPECT_EQ(next.trajectory.solver.iterations, 0) << shift;
    expect_dense_targets(next.trajectory, r.mass);
  }
  // Re-planning from a re-plan (the swing clearance's lift-off time carried through plan.json's
  // timeline as swing_elapsed).
  WarmStart first;
  first.previous = &cold.trajectory;
  first.shift = 0.1;
  const PlanOutcome a = plan_motion(r, flat, flat, o, 0.01, first);
  ASSERT_TRUE(a.success);
  WarmStart second;
  second.previous = &a.trajectory;
  second.shift = 0.05;
  const PlanOutcome b = plan_motion(r, flat, flat, o, 0.01, second);
  ASSERT_TRUE(b.success) << b.message;
  EXPECT_EQ(b.trajectory.solver.iterations, 0);
}

// The gap scene with its 1 m goal (docs/design.md §11): the hind feet's nominal end footholds lie
// on the planar floor of the 0.30 m trench, out of the legs' reach; the initial guess now moves
// them to ground the leg can reach (before: infeasible after 73 iterations).
TEST(Plan, GapSceneWithTheOneMetreGoalSolves) {
  const auto r = hyq();
  auto scene = terrain::make_scene("gap");
  auto smooth = terrain::TerrainMap::from_scene(*scene, 0.02, {});
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 11.0;
  o.max_time = 60.0;
  const PlanOutcome out = plan_motion(r, *smooth, *scene, o, 0.01);
  ASSERT_TRUE(out.success) << out.message;
  EXPECT_EQ(out.trajectory.solver.status, "optimal");
  EXPECT_NEAR(out.trajectory.samples.back().base.position.x(), 1.0, 1e-6);
  expect_dense_targets(out.trajectory, r.mass);
  // No stance foot ends in the trench (x in [0.50, 0.70], floor 0.30 m down).
  for (const auto& f : out.trajectory.samples.back().feet) EXPECT_GT(f.position.z(), -0.05);
}

// The constraint points of a re-plan's first segment stay where the previous plan had them.
TEST(Layout, CroppedFirstSegmentKeepsThePreviousConstraintPoints) {
  Layout L;
  L.num_segments = 3;
  auto near = [](const std::vector<double>& a, const std::vector<double>& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i)
      if (std::abs(a[i] - b[i]) > 1e-12) return false;
    return true;
  };
  EXPECT_TRUE(near(L.segment_points(0, 4, false), {0.0, 0.25, 0.5, 0.75}));
  EXPECT_TRUE(near(L.segment_points(0, 2, true), {0.0, 0.5, 1.0}));
  // 30 % of the previous segment had elapsed: its points at 0.5 and 1 remain, at (s - 0.3) / 0.7
  // of the new one, after the new start.
  L.first_segment_cropped = 0.3;
  EXPECT_TRUE(near(L.segment_points(0, 2, true), {0.0, 0.2 / 0.7, 1.0}));
  EXPECT_TRUE(near(L.segment_points(0, 4, false), {0.0, 0.2 / 0.7, 0.45 / 0.7}));
  EXPECT_TRUE(near(L.segment_points(1, 2, false), {0.0, 0.5}));  // only the first segment
}

// The path-shape rows are preferences: a cold solve they make fail is solved once
// more without them, and the plan says so. A swing apex of 1 mm above its ends contradicts the
// 5 cm swing clearance (infeasible by construction); the crawl itself is feasible.
TEST(Plan, AColdSolveTheShapeRowsMakeFailIsSolvedAgainWithoutThem) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(0.4);
  o.constraints = {"swing_apex"};
  o.feasibility_settings = {{"swing_apex_rise", 0.001}};
  const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(out.success) << out.message;
  ASSERT_TRUE(out.trajectory.extra.contains("path_shape_fallback"));
  const auto& fb = out.trajectory.extra["path_shape_fallback"];
  EXPECT_EQ(fb["dropped"], nlohmann::json::array({"swing_apex"}));
  EXPECT_NE(fb["shaped_status"], "optimal");
  EXPECT_GT(fb["shaped_max_violation"].get<double>(), 0.01);  // 5 cm against 1 mm
  const int shaped = fb["shaped_iterations"].get<int>();
  EXPECT_GT(shaped, 0);
  EXPECT_GT(out.trajectory.solver.iterations, shaped);  // both solves counted
  // Without the rows the swings rise as the clearance needs, far above 1 mm.
  const auto& q = out.trajectory.extra["quality"];
  ASSERT_TRUE(q.contains("swing_rise_max_m")) << q.dump();
  EXPECT_GT(q["swing_rise_max_m"].get<double>(), 0.03);
  // A solve the rows do not trouble is solved once, without the block.
  o.feasibility_settings = {{"swing_apex_rise", 0.1}};
  const PlanOutcome shaped_ok = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(shaped_ok.success) << shaped_ok.message;
  EXPECT_FALSE(shaped_ok.trajectory.extra.contains("path_shape_fallback"));
}

// The flat 2.4 s `all` crawl from rest: with LF's lift-off at 0.22 s, LF shed its half
// of the weight at nearly the force rate bound onto the right feet alone while LH swung, which threw
// the base 26.6 cm to the left; the path-shape rows could not hold it (150 iterations, then the
// fallback). With its second lift-off at W / force_rate_max (0.41 s) it is shaped in one solve and
// sways little without the rows too.
TEST(Plan, TheFastCrawlFromRestGetsALeadInAndIsShaped) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 2.4;
  o.constraints = {"all"};
  // The path-shape families off (on by default): the lead-in alone.
  o.feasibility_settings = {
      {"monotone_progress", 0.0}, {"lateral_corridor", 0.0}, {"swing_apex_rise", 0.0}};
  const PlanOutcome plain = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(plain.success) << plain.message;
  ASSERT_TRUE(plain.trajectory.extra.contains("rest_lead_in"));
  EXPECT_GT(plain.trajectory.extra["rest_lead_in"]["lead_in"].get<double>(), 0.25);
  EXPECT_NEAR(plain.trajectory.samples.back().t, 2.4, 1e-9);
  EXPECT_LT(plain.trajectory.extra["quality"]["lateral_sway_m"].get<double>(), 0.1);
  o.feasibility_settings = {
      {"monotone_progress", 1.0}, {"lateral_corridor", 0.02}, {"swing_apex_rise", 0.1}};
  const PlanOutcome shaped = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(shaped.success) << shaped.message;
  EXPECT_FALSE(shaped.trajectory.extra.contains("path_shape_fallback"))
      << shaped.trajectory.extra["path_shape_fallback"].dump();
  const auto& q = shaped.trajectory.extra["quality"];
  EXPECT_LT(q["lateral_sway_m"].get<double>(), 0.021);
  EXPECT_LT(q["backward_max_m"].get<double>(), 1e-3);
  EXPECT_LE(q["force_step_max_N_per_10ms"].get<double>(), 20.0 + 1e-3);
  // Without force ramps the schedule is the gait's.
  o.constraints = {"baseline"};
  o.feasibility_settings.clear();
  const PlanOutcome baseline = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(baseline.success) << baseline.message;
  EXPECT_FALSE(baseline.trajectory.extra.contains("rest_lead_in"));
}

TEST(Plan, ImpossibleGoalEndsNonOptimalWithoutCrash) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(10.0);
  o.duration = 1.0;
  o.cycles = 1;
  o.max_time = 10.0;
  const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
  EXPECT_FALSE(out.success);
  EXPECT_NE(out.trajectory.solver.status, "optimal");
  EXPECT_FALSE(out.message.empty());
  EXPECT_GT(out.solve.max_violation, 1e-3);
}

// 1 m in 1.6 s of crawl with force polytopes is more than HyQ's legs can do: without the stall
// test it ran the 3000 iterations Ipopt allows (62 s), its violation least (5e-3) at iteration
// 560. It must end "stalled", well before that, with a message that says so.
TEST(Plan, UnreachableRequestStallsInsteadOfRunningToTheIterationLimit) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 1.6;
  o.constraints = {"polytope"};
  o.stall_iterations = 50;
  o.max_time = 60.0;  // a safety net only: the assertion is on the status
  const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
  EXPECT_FALSE(out.success);
  EXPECT_EQ(out.trajectory.solver.status, "stalled") << out.message;
  EXPECT_LT(out.trajectory.solver.iterations, 1000);
  EXPECT_NE(out.message.find("no 1 % reduction"), std::string::npos) << out.message;
  std::printf("stalled after %d iterations, %.1f s: %s\n", out.trajectory.solver.iterations,
              out.trajectory.solver.wall_s, out.message.c_str());
}

TEST(Plan, MaxTimeIsHonouredOnRepeatedSolves) {
  const auto r = hyq();
  testing::FlatField flat;
  PlannerOptions o = options_to_goal(1.0);
  o.duration = 11.0;
  o.max_time = 0.05;  // far too short for this problem
  for (int i = 0; i < 2; ++i) {
    const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
    EXPECT_EQ(out.trajectory.solver.status, "time_limit");
  }
}

TEST(Plan, MonopedHops) {
  const auto r = robot::load_robot(robot::resolve_robot_path("monoped"));
  testing::FlatField flat;
  PlannerOptions o;
  o.gait = "hop";
  o.cycles = 2;
  const PlanOutcome out = plan_motion(r, flat, flat, o, 0.01);
  ASSERT_TRUE(out.success) << out.message;
  // In flight the foot is off the ground and the force is zero; x and y never move.
  bool flew = false;
  for (const auto& s : out.trajectory.samples) {
    EXPECT_NEAR(s.base.position.x(), 0.0, 1e-9);
    if (!s.feet[0].contact) {
      flew = true;
      EXPECT_EQ(s.feet[0].force.norm(), 0.0);
    }
  }
  EXPECT_TRUE(flew);
  expect_dense_targets(out.trajectory, r.mass);
}

TEST(PlanCli, ImpossibleGoalExitsNonZeroAndWritesNothing) {
  const std::string bin = TERRASTRIDE_BINARY;
  if (!std::filesystem::exists(bin)) GTEST_SKIP() << "no terrastride binary at " << bin;
  const std::string out = ::testing::TempDir() + "/impossible_plan.json";
  std::filesystem::remove(out);
  const std::string cmd = bin + " plan --terrain flat --cycles 1 --duration 1 --goal 10,0,0 " +
                          "--max-time 10 --out " + out + " > /dev/null 2>&1";
  const int rc = std::system(cmd.c_str());
  EXPECT_NE(rc, 0);
  EXPECT_FALSE(std::filesystem::exists(out));
}

}  // namespace
}  // namespace terrastride::planner
