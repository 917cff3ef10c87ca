// FeasibilityOptions from NAME=VALUE settings (constraints/feasibility_settings.cpp).
#include <cmath>

#include "family_test.hpp"

namespace terrastride::planner {
namespace {

using namespace testing;

// NAME=VALUE settings reach the sets: a tighter swing bound scales the rows, a joint margin
// moves the bounds; bad settings are refused naming themselves.
TEST(FeasibilitySettings, ReachTheSetsAndBadOnesAreNamed) {
  const auto r = hyq();
  FlatField flat;
  PlannerOptions a, b;
  a.constraints = b.constraints = {"swing", "joints"};
  b.feasibility_settings = {
      {"swing_acceleration", 50.0}, {"joint_margin", 0.1}, {"joints_softmax", 0.0}};
  PlannerOptions merged = a;
  merged.feasibility_settings = {{"joints_softmax", 0.01}};
  SrbdProblem pa(r, flat, crawl_timeline(r), a), pb(r, flat, crawl_timeline(r), b);
  ASSERT_EQ(pa.num_constraints(), pb.num_constraints());
  std::vector<double> ga(pa.num_constraints()), gb(pb.num_constraints());
  pa.eval_constraints(pa.initial_guess().data(), ga.data());
  pb.eval_constraints(pb.initial_guess().data(), gb.data());
  int row = 0, swing_rows = 0;
  for (const auto& piece : pa.pieces()) {
    if (piece->kind == "swing") {
      for (int k = 0; k < piece->rows(); ++k, ++swing_rows)
        EXPECT_NEAR(gb[row + k], 2.0 * ga[row + k], 1e-12);  // a / 50 against a / 100
    }
    row += piece->rows();
  }
  EXPECT_GT(swing_rows, 0);
  const FeasibilityOptions fo = feasibility_options(b.feasibility_settings);
  EXPECT_EQ(fo.swing_acceleration, 50.0);
  EXPECT_EQ(fo.joint_margin, 0.1);
  EXPECT_EQ(fo.joints_softmax, 0.0);
  EXPECT_EQ(FeasibilityOptions{}.joints_softmax, 0.0);
  // joints_softmax > 0: a row per knot and swing segment instead of three per knot and point.
  const SrbdProblem pm(r, flat, crawl_timeline(r), merged);
  EXPECT_LT(pm.num_constraints(), pa.num_constraints());
  for (std::size_t i = 0; i < pb.pieces().size(); ++i)
    if (pb.pieces()[i]->kind == "joints") {
      EXPECT_DOUBLE_EQ(pb.pieces()[i]->lb[1], r.legs[0].q_min[1] + 0.1);
      break;
    }
  for (const auto& bad : std::vector<std::pair<std::string, double>>{
           {"nope", 1.0}, {"shin_points", 0.0}, {"swing_acceleration", std::nan("")}}) {
    try {
      feasibility_options({bad});
      ADD_FAILURE() << bad.first;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(bad.first), std::string::npos) << e.what();
    }
  }
  // The leg clearance families' settings (shin_ik, thigh).
  const FeasibilityOptions leg = feasibility_options(
      {{"leg_probe_margin", -1.0}, {"leg_clearance_points", 2.0}, {"thigh_points", 6.0},
       {"leg_capsule_margin", 0.004}});
  EXPECT_EQ(leg.leg_capsule_margin, 0.004);
  EXPECT_EQ(leg.leg_probe_margin, -1.0);
  EXPECT_EQ(leg.leg_clearance_points, 2);
  EXPECT_EQ(leg.thigh_points, 6);
  EXPECT_EQ(feasibility_options({{"trunk_margin", 0.05}}).trunk_margin, 0.05);
  // The path-shape families' settings: off by default, validated.
  const FeasibilityOptions shape = feasibility_options(
      {{"monotone_progress", 1.0}, {"lateral_corridor", 0.02}, {"swing_apex_rise", 0.1}});
  EXPECT_EQ(shape.monotone_progress, 1);
  EXPECT_EQ(shape.lateral_corridor, 0.02);
  EXPECT_EQ(shape.swing_apex_rise, 0.1);
  EXPECT_EQ(FeasibilityOptions{}.replan_path_shape, 0);  // re-plans carry no path-shape rows
  EXPECT_EQ(feasibility_options({{"replan_path_shape", 1.0}}).replan_path_shape, 1);
  for (const auto& bad : std::vector<std::pair<std::string, double>>{
           {"monotone_progress", 0.5}, {"monotone_progress", 2.0}, {"lateral_corridor", -0.01},
           {"swing_apex_rise", -0.1}, {"replan_path_shape", 0.5}, {"replan_path_shape", 2.0},
           {"start_return", -0.1}, {"start_return", 2.5}}) {
    try {
      feasibility_options({bad});
      ADD_FAILURE() << bad.first << " = " << bad.second;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(bad.first), std::string::npos) << e.what();
    }
  }
  // force_rate_max (force_ramp) the 17th; monotone_progress, lateral_corridor, swing_apex_rise;
  // joints_softmax; replan_path_shape; start_return; joint_velocity
  EXPECT_EQ(feasibility_options({{"start_return", 0.5}}).start_return, 0.5);
  EXPECT_EQ(feasibility_options({{"joint_velocity", 0.0}}).joint_velocity, 0.0);
  EXPECT_EQ(feasibility_options({}).joint_velocity, 1.0);
  EXPECT_EQ(feasibility_option_names().size(), 24u);
}

}  // namespace
}  // namespace terrastride::planner
