// Stance footholds against the safety margin, and the combined checks' plan.json keys.
#include <gtest/gtest.h>

#include "terrastride/collision/checks.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "trajectories.hpp"

using namespace terrastride;
using namespace terrastride::collision;
using terrastride::collision::test::hyq;
using terrastride::collision::test::standing;

TEST(Footholds, FootOnAPalletEdgeIsUnsafe) {
  const auto model = hyq();
  const auto scene = terrain::make_scene("pallet_10");  // box x in [0.55, 1.75], 0.10 m high
  auto traj = standing(model, 0.02, 0.002);
  // LF right on the pallet's front edge, RF well clear of it (0.25 m before it).
  for (auto& s : traj.samples) {
    s.feet[0].position = Eigen::Vector3d(0.55, 0.29, 0.0);
    s.feet[1].position = Eigen::Vector3d(0.30, -0.29, 0.0);
  }
  const FootholdReport rep = check_footholds(traj, *scene, model.foot_radius);
  ASSERT_EQ(rep.footholds.size(), 4u);  // one stance per leg, no swing
  EXPECT_EQ(rep.unsafe, 1);
  ASSERT_GE(rep.worst, 0);
  EXPECT_EQ(rep.footholds[rep.worst].leg, 0);
  EXPECT_NEAR(rep.worst_margin, -model.foot_radius, 1e-9);  // on the edge: 0 - r
  for (const auto& fh : rep.footholds) {
    if (fh.leg == 1) {
      EXPECT_NEAR(fh.margin, 0.25 - model.foot_radius, 1e-9);
    }
  }
  // Just beyond one foot radius from the edge it becomes safe.
  for (auto& s : traj.samples) s.feet[0].position = Eigen::Vector3d(0.55 + 0.021, 0.29, 0.1);
  const FootholdReport ok = check_footholds(traj, *scene, model.foot_radius);
  EXPECT_EQ(ok.unsafe, 0);
  EXPECT_NEAR(ok.worst_margin, 0.001, 1e-9);
}

TEST(Footholds, StancePhasesAreSplitBySwingAndSlidingCounts) {
  const auto model = hyq();
  const auto scene = terrain::make_scene("pallet_10");
  auto traj = standing(model, 0.1, 0.01);  // 11 samples
  // LF: stance (0-3), swing (4-6), stance (7-10) during which it slides onto the edge.
  for (size_t k = 4; k <= 6; ++k) traj.samples[k].feet[0].contact = false;
  for (size_t k = 7; k <= 10; ++k)
    traj.samples[k].feet[0].position = Eigen::Vector3d(0.50 + 0.01 * (k - 7), 0.29, 0.0);
  const FootholdReport rep = check_footholds(traj, *scene, model.foot_radius);
  int lf = 0;
  for (const auto& fh : rep.footholds) {
    if (fh.leg != 0) continue;
    ++lf;
    if (fh.first_sample == 7) {
      EXPECT_EQ(fh.last_sample, 10);
      EXPECT_NEAR(fh.margin, 0.02 - model.foot_radius, 1e-9);  // worst at x = 0.53
      EXPECT_NEAR(fh.position.x(), 0.53, 1e-12);
    }
  }
  EXPECT_EQ(lf, 2);
  EXPECT_EQ(rep.footholds.size(), 5u);
}

TEST(Checks, StandingOnFlatSceneAllPass) {
  const auto model = hyq();
  const auto scene = terrain::make_scene("flat");
  const auto traj = standing(model, 0.2, 0.002);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  CheckTerrain terrain;
  terrain.field = scene.get();
  terrain.octree = voxelise_scene(*scene, lo, hi);
  const CheckReport rep = run_checks(model, traj, terrain);
  EXPECT_TRUE(rep.passed()) << rep.failures().front();
  const auto keys = rep.keys();
  for (const char* key : {"torque_ratio_max", "torque_violations", "shin_min_distance_m",
                          "shin_collisions", "unsafe_footholds"})
    EXPECT_TRUE(keys.count(key)) << key;
  EXPECT_EQ(keys.at("torque_violations"), 0);
  EXPECT_EQ(keys.at("shin_collisions"), 0);
  EXPECT_EQ(keys.at("unsafe_footholds"), 0);
  EXPECT_GT(keys.at("shin_min_distance_m"), 0.02);
  EXPECT_LT(keys.at("torque_ratio_max"), 1.0);
}

TEST(Checks, ChecksThatDidNotRunAreAbsent) {
  const auto model = hyq();
  const CheckReport rep = run_checks(model, standing(model, 0.02, 0.002), CheckTerrain{});
  const auto keys = rep.keys();
  EXPECT_TRUE(keys.count("torque_ratio_max"));
  EXPECT_FALSE(keys.count("shin_min_distance_m"));
  EXPECT_FALSE(keys.count("unsafe_footholds"));
}

TEST(Checks, SyntheticCrawlOntoThePallet) {
  // The synthetic crawl plants the front feet on the pallet's edge region: the checks run end to
  // end over a 2 s walk and find the footholds that land within r of the edge.
  const auto model = hyq();
  const auto scene = terrain::make_scene("pallet_10");
  const auto traj = test::synthetic_crawl(
      model, [&](double x, double y) { return scene->height(x, y); }, 2.0, 0.01, 3);
  Eigen::Vector2d lo, hi;
  trajectory_extent(model, traj, 0.1, &lo, &hi);
  CheckTerrain terrain;
  terrain.field = scene.get();
  terrain.octree = voxelise_scene(*scene, lo, hi);
  const CheckReport rep = run_checks(model, traj, terrain);
  ASSERT_TRUE(rep.footholds.has_value());
  EXPECT_EQ(rep.footholds->footholds.size(), 16u);  // 4 initial + 3 cycles x 4 legs
  // Front feet start at x = 0.31 and step by 1/3 m: 0.643 lies 0.093 m past the edge, safe.
  EXPECT_EQ(rep.footholds->unsafe, 0);
  EXPECT_TRUE(rep.clearance.has_value());
  EXPECT_EQ(rep.kinematics.unreachable_samples, 0);
}
