// Plans judged by the post-hoc checks, end to end through the CLI. The paper's terrain experiment
// (section IV-B): onto the pallets, the point-foot plan drives shins into the edge (FCL capsules
// against the exact scene), "all" keeps every capsule clear, every foothold safe and every joint
// torque within its limit. The joint ranges: the baseline's
// range-of-motion box lets feet go where the joints cannot follow; "joints" keeps them in range.
// The paper's torque experiment (Bratta et al. 2020, section IV-A):
// `terrastride plan` solves, then judges its own plan with the post-hoc joint-torque check
// (tau = M q'' + c + g - J^T f from IK, every sample). With "polytope" (force polytopes in
// stance, the foot acceleration bound in swing) the worst ratio must stay within 1.05 of the
// limits; on a scenario where the baseline's plan exceeds them, the check must say so (teeth).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"

namespace fs = std::filesystem;
using terrastride::test_support::run_terrastride;

namespace {

struct TorqueFigures {
  std::string status;
  double ratio_max = 0.0;
  double violations = 0.0;
  double joint_limit_violations = 0.0;
  double shin_collisions = 0.0;
  double unsafe_footholds = 0.0;
};

TorqueFigures plan_and_check(const std::string& args, const std::string& name) {
  const fs::path out = fs::temp_directory_path() /
                       ("terrastride_torque_" + std::to_string(::getpid()) + "_" + name + ".json");
  const auto r = run_terrastride("plan " + args + " --json --out " + out.string());
  // 0: solved and every post-hoc check passed; 4: solved, and a check fails (these experiments
  // include plans made to fail them, e.g. baseline torques).
  EXPECT_TRUE(r.code == 0 || r.code == 4) << name << ": " << r.all();
  std::ifstream in(out);
  const auto plan = nlohmann::json::parse(in, nullptr, false);
  fs::remove(out);
  TorqueFigures t;
  if (plan.is_discarded() || !plan.contains("checks")) {
    ADD_FAILURE() << name << ": no plan.json with checks";
    return t;
  }
  t.status = plan["solver"]["status"].get<std::string>();
  t.ratio_max = plan["checks"].at("torque_ratio_max").get<double>();
  t.violations = plan["checks"].at("torque_violations").get<double>();
  t.joint_limit_violations = plan["checks"].at("joint_limit_violations").get<double>();
  t.shin_collisions = plan["checks"].at("shin_collisions").get<double>();
  t.unsafe_footholds = plan["checks"].at("unsafe_footholds").get<double>();
  std::printf(
      "%-20s %s, torque ratio max %.3f, %g violating samples, %g outside joint ranges, %g shin "
      "collisions, %g unsafe footholds\n",
      name.c_str(), t.status.c_str(), t.ratio_max, t.violations, t.joint_limit_violations,
      t.shin_collisions, t.unsafe_footholds);
  return t;
}

// Both plans optimal; with "polytope" the worst ratio within 1.05 of the limits and no violating
// sample. With `baseline_must_violate`, the point-foot plan must exceed the limits: the check has
// teeth on this scenario.
void expect_polytopes_hold_the_limits(const std::string& scenario, const std::string& tag,
                                      bool baseline_must_violate) {
  const TorqueFigures base = plan_and_check(scenario + " --constraints baseline", tag + "_baseline");
  const TorqueFigures poly = plan_and_check(scenario + " --constraints polytope", tag + "_polytope");
  EXPECT_EQ(base.status, "optimal");
  EXPECT_EQ(poly.status, "optimal");
  if (baseline_must_violate) {
    EXPECT_GT(base.ratio_max, 1.05) << "the baseline plan should exceed the torque limits";
    EXPECT_GT(base.violations, 0.0);
  }
  EXPECT_LE(poly.ratio_max, 1.05);
  EXPECT_EQ(poly.violations, 0.0);
}

}  // namespace

// The paper's scenario: 1 m in 2.4 s on flat ground, HyQ crawl. Whether the baseline's plan
// exceeds the limits depends on which feasible point the solver stops at: from the earlier
// initial guess (linear ramps, equal forces) it did (worst ratio 1.99, 27 samples); since the
// dynamically balanced guess it stays below 1 (0.98, then 0.77 with the angular band). Nothing in
// the baseline formulation holds the limits, so the teeth are shown on the pace below.
TEST(TorqueExperiment, FastFlatCrawl) {
  expect_polytopes_hold_the_limits("--terrain flat --duration 2.4 --goal 1,0,0", "crawl", false);
}

// The monoped (one HyQ leg on a slider) hopping 1 m. Baseline: worst ratio 1.25 from the earlier
// guess, 0.49 from the balanced one.
TEST(TorqueExperiment, MonopedHop) {
  expect_polytopes_hold_the_limits("--robot monoped --gait hop --terrain flat --goal 1,0,0", "hop",
                                   false);
}

// HyQ pacing 1 m on flat ground (the gait's default duration): the two legs of one side in stance
// together, so the baseline plan loads them hard (measured: worst ratio 1.48, 44 violating
// samples); "polytope" holds the limits (0.91). The trot showed this until the angular band
// changed where the solver stops (baseline 1.77 before, 0.60 after): which feasible point a
// formulation without torque limits stops at is not something a test can pin down, so if this
// one loses its teeth, find the scenario that has them rather than loosening the assertion.
TEST(TorqueExperiment, PaceChecksHaveTeeth) {
  expect_polytopes_hold_the_limits("--terrain flat --gait pace --goal 1,0,0", "pace", true);
}

// Onto the 15 cm pallet: the baseline plan needs HFE beyond its range at some samples (measured: 49
// samples); with "joints" no sample of the plan leaves a joint range.
TEST(JointLimits, PalletCrawlStaysInRange) {
  const std::string scenario = "--terrain pallet_15 --duration 11 --goal 1,0,0 --max-time 120";
  const TorqueFigures base = plan_and_check(scenario + " --constraints baseline", "p15_baseline");
  const TorqueFigures joints =
      plan_and_check(scenario + " --constraints baseline,joints", "p15_joints");
  EXPECT_EQ(joints.status, "optimal");
  EXPECT_GT(base.joint_limit_violations, 0.0);
  EXPECT_EQ(joints.joint_limit_violations, 0.0);
}

// "all" optimal with no capsule collision, no unsafe foothold and the torques within 1.05 of the
// limits. With `baseline_must_collide`, the point-foot plan must drive a shin into the edge.
void expect_all_constraints_clear_the_pallet(const std::string& terrain, bool baseline_must_collide) {
  const std::string scenario = "--terrain " + terrain + " --duration 11 --goal 1,0,0 --max-time 120";
  const TorqueFigures base = plan_and_check(scenario + " --constraints baseline", terrain + "_baseline");
  const TorqueFigures all = plan_and_check(scenario + " --constraints all", terrain + "_all");
  EXPECT_EQ(base.status, "optimal");
  if (baseline_must_collide) {
    EXPECT_GT(base.shin_collisions, 0.0) << "the point-foot plan should hit the edge";
  }
  EXPECT_EQ(all.status, "optimal");
  EXPECT_EQ(all.shin_collisions, 0.0);
  EXPECT_EQ(all.unsafe_footholds, 0.0);
  EXPECT_LE(all.ratio_max, 1.05);
}

// On the 10 cm pallet the baseline's plan happens to clear the edge (measured: 0 capsule
// collisions, 25 samples outside a joint range); on the 15 cm pallet it does not (230 samples).
TEST(PalletExperiment, AllConstraintsClearThe10cmPallet) {
  expect_all_constraints_clear_the_pallet("pallet_10", false);
}

TEST(PalletExperiment, AllConstraintsClearThe15cmPallet) {
  expect_all_constraints_clear_the_pallet("pallet_15", true);
}
