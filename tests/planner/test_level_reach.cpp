// check_level_reach: a start or goal the robot cannot reach from the start's level (a cupboard
// top, a ceiling over ground never scanned) is refused naming the point, its height and the
// start's; the shipped scenes and a robot standing under a stair pass.
#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <functional>
#include <string>

#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/planner/level_reach.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "test_robots.hpp"

namespace terrastride::planner {
namespace {

constexpr double kRes = 0.05;

// A 5 x 2 m OctoMap of 5 cm voxels with a floor at z = 0.05, plus what `column` adds.
std::unique_ptr<terrain::TerrainMap> octomap_map(
    const std::function<void(double, double, octomap::OcTree&)>& column, bool floor_everywhere,
    double floor_until = 5.0) {
  auto tree = std::make_unique<octomap::OcTree>(kRes);
  for (double x = 0.025; x < 5.0; x += kRes)
    for (double y = 0.025; y < 2.0; y += kRes) {
      if (floor_everywhere || x < floor_until) {  // seen from above: a free voxel over it
        tree->updateNode(octomap::point3d(x, y, 0.025), true);
        tree->updateNode(octomap::point3d(x, y, 0.075), false);
      }
      column(x, y, *tree);
    }
  terrain::OctreeMapInput input;
  input.support = perception::octree_support_cloud(*tree, "synthetic", &input.stats);
  input.tree = std::move(tree);
  terrain::MapBuildOptions options;
  options.grid.resolution = 0;
  options.foot_radii = {0.02};
  return std::move(terrain::build_terrain_map_from_octree(input, options).map);
}

void expect_refused(const std::function<void()>& f, const std::string& field,
                    std::initializer_list<std::string> needles) {
  try {
    f();
    ADD_FAILURE() << "expected a RequestError for " << field;
  } catch (const RequestError& e) {
    EXPECT_EQ(e.field(), field) << e.what();
    for (const auto& n : needles)
      EXPECT_NE(std::string(e.what()).find(n), std::string::npos) << e.what() << " lacks " << n;
  }
}

TEST(LevelReach, LegReachIsTheStretchedLeg) {
  EXPECT_NEAR(leg_reach(testing::hyq()), 0.08 + 0.35 + 0.341, 1e-9);
}

TEST(LevelReach, ShippedScenesPassAsScenesAndAsGrids) {
  const auto robot = testing::hyq();
  for (const std::string name : {"flat", "pallet_10", "pallet_15", "pallet_30", "pallet_60",
                                 "eur_pallet", "stairs", "gap"}) {
    const auto scene = terrain::make_scene(name);
    EXPECT_NO_THROW(check_level_reach(*scene, robot, {0, 0, 0}, {1.0, 0, 0})) << name;
    EXPECT_NO_THROW(check_level_reach(*scene, robot, {0, 0, 0}, {1.5, 0, 0})) << name;
    const auto grid = terrain::TerrainMap::from_scene(*scene, 0.02, {0.02});
    EXPECT_NO_THROW(check_level_reach(*grid, robot, {0, 0, 0}, {1.0, 0, 0})) << name;
  }
}

TEST(LevelReach, CupboardTopIsRefusedFloorIsNot) {
  // A solid cupboard 2 m high over x in [2.5, 3.3), y in [0.6, 1.4).
  const auto map = octomap_map(
      [](double x, double y, octomap::OcTree& t) {
        if (x > 2.5 && x < 3.3 && y > 0.6 && y < 1.4) {
          for (double z = 0.075; z < 2.0; z += kRes) t.updateNode(octomap::point3d(x, y, z), true);
          t.updateNode(octomap::point3d(x, y, 2.025), false);
        }
      },
      true);
  const auto robot = testing::hyq();
  EXPECT_NO_THROW(check_level_reach(*map, robot, {1.0, 1.0, 0}, {1.8, 1.0, 0}));
  expect_refused([&] { check_level_reach(*map, robot, {1.0, 1.0, 0}, {2.9, 1.0, 0}); }, "goal",
                 {"[2.9, 1, 0]", "z 1.98 m", "start's ground at z 0.03 m", "0.77 m"});
  // Standing on it is refused the same way (its feet on the top, the goal on the floor).
  expect_refused([&] { check_level_reach(*map, robot, {2.9, 1.0, 0}, {1.0, 1.0, 0}); }, "goal",
                 {"z 0.03 m", "start's ground at z 1.98 m"});
}

TEST(LevelReach, CeilingOverGroundNeverScannedIsRefused) {
  // Floor for x < 2.5; beyond, only a ceiling at 2.5 m seen from beneath.
  const auto map = octomap_map(
      [](double x, double y, octomap::OcTree& t) {
        for (double z = x < 2.5 ? 0.075 : 1.025; z < 2.45; z += kRes)
          t.updateNode(octomap::point3d(x, y, z), false);
        t.updateNode(octomap::point3d(x, y, 2.475), true);
      },
      false, 2.5);
  const auto robot = testing::hyq();
  EXPECT_NO_THROW(check_level_reach(*map, robot, {1.0, 1.0, 0}, {1.8, 1.0, 0}));
  expect_refused([&] { check_level_reach(*map, robot, {1.0, 1.0, 0}, {3.8, 1.0, 0}); }, "goal",
                 {"[3.8, 1, 0]", "no walkable ground", "underside at z 2.45 m",
                  "start's ground at z 0.03 m"});
  expect_refused([&] { check_level_reach(*map, robot, {3.8, 1.0, 0}, {1.0, 1.0, 0}); }, "start",
                 {"no walkable ground"});
}

TEST(LevelReach, RobotStandingUnderAStair) {
  // Open treads rising along x from x = 2 (0.3 m deep, 0.2 m rise), seen from beneath: the floor
  // under them is ground with the treads overhead; a start under the stair plans on.
  const auto map = octomap_map(
      [](double x, double y, octomap::OcTree& t) {
        if (x < 2.0 || x >= 3.5) return;
        const int k = static_cast<int>((x - 2.0) / 0.3);
        const double top = 0.2 * (k + 1);
        for (double z = 0.075; z < top - kRes; z += kRes)
          t.updateNode(octomap::point3d(x, y, z), false);
        t.updateNode(octomap::point3d(x, y, top - 0.5 * kRes), true);
      },
      true);
  const auto robot = testing::hyq();
  const terrain::PointAnswer under = map->answer(3.0, 1.0, 0.02);
  EXPECT_TRUE(under.safe) << under.unsafe_because;
  EXPECT_NEAR(under.ground.height, 0.025, 1e-3);
  EXPECT_NEAR(under.overhead, 0.8 - kRes, 1e-5);  // tread 3's underside
  EXPECT_NO_THROW(check_level_reach(*map, robot, {3.0, 1.0, 0}, {4.2, 1.0, 0}));
  EXPECT_NO_THROW(check_level_reach(*map, robot, {1.0, 1.0, 0}, {3.0, 1.0, 0}));
}

}  // namespace
}  // namespace terrastride::planner
