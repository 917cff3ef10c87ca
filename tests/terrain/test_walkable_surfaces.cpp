// Walkable surfaces, not the top of every column: overhangs (ceilings, shelves, table tops seen
// from beneath) are kept apart as the overhead layer, from an OctoMap's free voxels and from the
// rays of clouds with sensor origins; a column whose only surface is an overhang has no walkable
// ground; a surface with less than the overhang free height beneath it (a pallet deck) is ground.
#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride {
namespace {

constexpr double kRes = 0.05;

// A 2 x 2 m OctoMap of 5 cm voxels, filled column by column: `column(x, y, tree)` marks the
// column's voxels (voxel centres at odd multiples of 2.5 cm).
octomap::OcTree make_tree(const std::function<void(double, double, octomap::OcTree&)>& column) {
  octomap::OcTree tree(kRes);
  for (double x = 0.025; x < 2.0; x += kRes)
    for (double y = 0.025; y < 2.0; y += kRes) column(x, y, tree);
  return tree;
}

void occupied(octomap::OcTree& t, double x, double y, double z) {
  t.updateNode(octomap::point3d(x, y, z), true);
}
// A top surface seen from above: occupied, with a free voxel over it.
void top_surface(octomap::OcTree& t, double x, double y, double z) {
  occupied(t, x, y, z);
  t.updateNode(octomap::point3d(x, y, z + kRes), false);
}
void free_from_to(octomap::OcTree& t, double x, double y, double z0, double z1) {
  for (double z = z0; z < z1 - 1e-6; z += kRes) t.updateNode(octomap::point3d(x, y, z), false);
}

terrain::MapBuild map_of(const octomap::OcTree& tree) {
  terrain::OctreeMapInput input;
  input.tree = std::make_unique<octomap::OcTree>(tree);
  input.support = perception::octree_support_cloud(*input.tree, "synthetic", &input.stats);
  terrain::MapBuildOptions options;
  options.grid.resolution = 0;
  options.foot_radii = {0.02};
  return terrain::build_terrain_map_from_octree(input, options);
}

size_t cell(const terrain::HeightGrid& g, double x, double y) {
  return g.geometry.index(static_cast<int>((x - g.geometry.origin.x()) / g.geometry.resolution),
                          static_cast<int>((y - g.geometry.origin.y()) / g.geometry.resolution));
}

TEST(WalkableOctomap, ShelfOverAFloorIsAnOverheadNotTheGround) {
  // A floor, and a shelf board at 0.6 m over x in [0.5, 1.0) seen from beneath (free voxels).
  const auto tree = make_tree([](double x, double y, octomap::OcTree& t) {
    top_surface(t, x, y, 0.025);
    if (x > 0.5 && x < 1.0) {
      free_from_to(t, x, y, 0.075, 0.625);
      occupied(t, x, y, 0.625);
    }
  });
  perception::OctreeSupportStats st;
  const auto cloud = perception::octree_support_cloud(tree, "shelf", &st);
  EXPECT_EQ(st.overhangs, 400u);
  EXPECT_EQ(st.overhang_only_columns, 0u);
  ASSERT_EQ(cloud.overhangs.size(), 400u);
  for (const auto& o : cloud.overhangs) EXPECT_NEAR(o.z(), 0.6, 1e-5);
  for (const auto& p : cloud.points) EXPECT_NEAR(p.z(), 0.025, 1e-5);

  const auto build = map_of(tree);
  const terrain::HeightGrid& g = build.map->grid();
  ASSERT_EQ(g.overhead.size(), g.geometry.size());
  EXPECT_EQ(g.overhang_cells, 400u);
  EXPECT_EQ(g.overhang_unobserved_cells, 0u);
  const size_t under = cell(g, 0.75, 1.0);
  EXPECT_EQ(g.observed[under], 1);
  EXPECT_NEAR(g.elevation[under], 0.025, 1e-5);
  EXPECT_NEAR(g.overhead[under], 0.6, 1e-5);
  EXPECT_TRUE(build.map->safe(0.75, 1.0, 0.02));
  const terrain::PointAnswer a = build.map->answer(0.75, 1.0, 0.02);
  EXPECT_TRUE(a.safe);
  EXPECT_NEAR(a.free_height, 0.575, 1e-5);
  EXPECT_FALSE(std::isfinite(g.overhead[cell(g, 1.5, 1.0)]));
}

TEST(WalkableOctomap, WallWhoseFootHasFreeVoxelsUnderTheFloorIsNoOverhang) {
  // A floor, and a wall over x in [1.0, 1.1) from 0.15 m below the floor's top to 1 m, with free
  // voxels under its foot, below the floor (rays through an unscanned floor), none beside it.
  const auto tree = make_tree([](double x, double y, octomap::OcTree& t) {
    if (x > 1.0 && x < 1.1) {
      free_from_to(t, x, y, -0.475, -0.125);
      for (double z = -0.125; z < 1.0; z += kRes) occupied(t, x, y, z);
    } else {
      top_surface(t, x, y, 0.025);
    }
  });
  perception::OctreeSupportStats st;
  const auto cloud = perception::octree_support_cloud(tree, "wall", &st);
  // The column rule alone reads the wall as an overhang 0.2 m below the floor's top...
  ASSERT_EQ(cloud.overhangs.size(), 80u);
  for (const auto& o : cloud.overhangs) EXPECT_NEAR(o.z(), -0.15, 1e-5);
  // ...which leaves no room beneath it over the floor beside it: no overhead, the wall's cells
  // still no ground, and the overhead field over the floor next to it unbounded.
  const auto build = map_of(tree);
  const terrain::HeightGrid& g = build.map->grid();
  EXPECT_EQ(g.overhang_cells, 0u);
  EXPECT_EQ(g.observed[cell(g, 1.05, 1.0)], 0);
  EXPECT_GT(build.map->overhead(0.95, 1.0), 10.0);
  EXPECT_GT(build.map->overhead(1.05, 1.0), 10.0);
}

TEST(WalkableOctomap, OverhangJustBelowTheFreeHeightOverTheNextGroundIsDropped) {
  // A ceiling seen only from beneath over x in [1.0, 1.2) whose floor was not scanned, its
  // underside 0.175 m over the floor beside it (less than the 0.2 m free height): no room to pass
  // under, no overhead; the same ceiling 0.1 m higher is kept. (Cells farther than two from any
  // observed ground have none to be judged against and keep their underside.)
  for (const double underside : {0.2, 0.3}) {
    const auto tree = make_tree([&](double x, double y, octomap::OcTree& t) {
      if (x > 1.0 && x < 1.2) {
        free_from_to(t, x, y, underside - 0.325, underside);
        occupied(t, x, y, underside + 0.025);
      } else {
        top_surface(t, x, y, 0.025);
      }
    });
    const auto build = map_of(tree);
    const terrain::HeightGrid& g = build.map->grid();
    if (underside < 0.25) {
      EXPECT_EQ(g.overhang_cells, 0u) << underside;
      EXPECT_GT(build.map->overhead(0.95, 1.0), 10.0);
    } else {
      ASSERT_EQ(g.overhead.size(), g.geometry.size());
      EXPECT_NEAR(g.overhead[cell(g, 1.1, 1.0)], underside, 1e-5);
      EXPECT_EQ(g.overhang_cells, 160u);
    }
  }
}

TEST(WalkableOctomap, CeilingOverUnobservedFloorIsNotGround) {
  // x < 1: a floor under a ceiling at 2.45-2.5 m; x >= 1: the ceiling alone, free space seen
  // beneath it down to 1 m (rays from a sensor elsewhere) and nothing known below.
  const auto tree = make_tree([](double x, double y, octomap::OcTree& t) {
    if (x < 1.0) {
      top_surface(t, x, y, 0.025);
      free_from_to(t, x, y, 0.075, 2.475);
    } else {
      free_from_to(t, x, y, 1.025, 2.475);
    }
    occupied(t, x, y, 2.475);
  });
  perception::OctreeSupportStats st;
  const auto cloud = perception::octree_support_cloud(tree, "ceiling", &st);
  EXPECT_EQ(st.overhang_only_columns, 800u);
  const auto build = map_of(tree);
  const terrain::HeightGrid& g = build.map->grid();
  const terrain::SafetyLayer& safe = build.map->layer(0.02);
  size_t high_observed = 0, high_safe = 0;
  for (size_t k = 0; k < g.geometry.size(); ++k) {
    high_observed += g.observed[k] && g.elevation[k] > 1.5;
    high_safe += safe.safe[k] && g.elevation[k] > 1.5;
  }
  EXPECT_EQ(high_observed, 0u);
  EXPECT_EQ(high_safe, 0u);
  EXPECT_EQ(g.overhang_cells, 1600u);
  EXPECT_EQ(g.overhang_unobserved_cells, 800u);
  // Over the unobserved floor: not observed, not interpolated, never safe; the ceiling overhead.
  const size_t k = cell(g, 1.5, 1.0);
  EXPECT_EQ(g.observed[k], 0);
  EXPECT_NEAR(g.overhead[k], 2.45, 1e-5);
  const terrain::PointAnswer a = build.map->answer(1.5, 1.0, 0.02);
  EXPECT_FALSE(a.safe);
  EXPECT_TRUE(a.overhang_only);
  EXPECT_NE(a.unsafe_because.find("no walkable ground"), std::string::npos) << a.unsafe_because;
  // The safe fraction counts the floor only.
  EXPECT_EQ(safe.observed_cells, 800u);
}

TEST(WalkableOctomap, PalletDeckWithLittleRoomBeneathIsGround) {
  // A deck 10 cm up (one free voxel beneath it): less than the overhang free height, so it is
  // the surface a foot stands on, not something to walk under.
  const auto tree = make_tree([](double x, double y, octomap::OcTree& t) {
    top_surface(t, x, y, 0.025);
    if (x > 0.5 && x < 1.0) top_surface(t, x, y, 0.125);
  });
  perception::OctreeSupportStats st;
  const auto cloud = perception::octree_support_cloud(tree, "deck", &st);
  EXPECT_EQ(st.overhangs, 0u);
  EXPECT_EQ(st.seen_beneath, 400u);
  const auto build = map_of(tree);
  const terrain::HeightGrid& g = build.map->grid();
  EXPECT_NEAR(g.elevation[cell(g, 0.75, 1.0)], 0.125, 1e-5);
  EXPECT_TRUE(g.overhead.empty());
}

TEST(WalkableOctomap, CupboardTopIsItsOwnLevelOfGround) {
  // A solid cupboard 2 m high: its top has no free space beneath, so it stays ground (a level the
  // planner's reach check tells apart from the floor's).
  const auto tree = make_tree([](double x, double y, octomap::OcTree& t) {
    top_surface(t, x, y, 0.025);
    if (x > 0.5 && x < 1.0 && y > 0.5 && y < 1.0) {
      for (double z = 0.075; z < 1.95; z += kRes) occupied(t, x, y, z);
      top_surface(t, x, y, 1.975);
    }
  });
  const auto build = map_of(tree);
  const terrain::HeightGrid& g = build.map->grid();
  EXPECT_NEAR(g.elevation[cell(g, 0.75, 0.75)], 1.975, 1e-5);
  EXPECT_EQ(g.observed[cell(g, 0.75, 0.75)], 1);
  EXPECT_TRUE(g.overhead.empty());
  // Observed, flat, and out of every leg's reach: an unreachable level, not safe ground.
  const terrain::PointAnswer a = build.map->answer(0.75, 0.75, 0.02);
  EXPECT_TRUE(a.unreachable);
  EXPECT_FALSE(a.safe);
  EXPECT_NE(a.unsafe_because.find("unreachable level"), std::string::npos) << a.unsafe_because;
  EXPECT_EQ(build.map->levels().unreachable_cells, 100u);  // the 10 x 10 cells of its top
  EXPECT_EQ(build.map->levels().unreachable_levels, 1u);
  EXPECT_TRUE(build.map->safe(0.25, 0.25, 0.02));
}

// ---- the foot disk and the level rule on rasterised scenes.
terrain::Scene scene_with(std::vector<terrain::Box> boxes) {
  return terrain::Scene("test", "test", 0.0, std::move(boxes), {-1.0, -1.0}, {1.0, 1.0});
}

terrain::SafetyOptions every_level() {
  terrain::SafetyOptions o;
  o.max_climb = std::numeric_limits<double>::infinity();
  return o;
}

// The cells a one-cell spike at the grid's centre makes unsafe, as offsets from it.
std::vector<std::pair<int, int>> spike_footprint(double res, double spike, double radius) {
  // A flat floor with one cell raised whole (min = max = elevation: a crest one cell wide).
  terrain::HeightGrid g = terrain::rasterize_scene(scene_with({}), res);
  const int ci = g.geometry.nx / 2, cj = g.geometry.ny / 2;
  const size_t c = g.geometry.index(ci, cj);
  g.elevation[c] = g.min[c] = g.max[c] = static_cast<float>(spike);
  const terrain::SafetyLayer l = terrain::compute_safety(g, radius, every_level());
  std::vector<std::pair<int, int>> out;
  for (int di = -8; di <= 8; ++di)
    for (int dj = -8; dj <= 8; ++dj)
      if (!l.safe[g.geometry.index(ci + di, cj + dj)]) out.emplace_back(di, dj);
  return out;
}

TEST(FootDisk, TwoCentimetreGridsKeepTheDiskOfRadiusPlusHalfACell) {
  // A spike makes unsafe exactly the cells whose disk (centres within r + res/2) holds it: on
  // 2 cm cells the disks of the map's radii are what they were before the disk's 3 x 3 minimum.
  for (const double r : {0.02, 0.05, 0.10}) {
    std::vector<std::pair<int, int>> expected;
    const double reach = r / 0.02 + 0.5 + 1e-9;
    for (int di = -8; di <= 8; ++di)
      for (int dj = -8; dj <= 8; ++dj)
        if (std::hypot(di, dj) <= reach) expected.emplace_back(di, dj);
    EXPECT_EQ(spike_footprint(0.02, 0.10, r), expected) << "radius " << r;
  }
}

TEST(FootDisk, CoarseCellsJudgeAFootOverTheEightNeighbours) {
  // On 8 cm cells a 2 cm foot's disk would be the cell alone: a one-cell wall crest 1.5 m up was
  // flat there, hence safe. Its disk now holds the 8 neighbours: the crest and the 3 x 3 around
  // it are unsafe.
  std::vector<std::pair<int, int>> three_by_three;
  for (int di = -1; di <= 1; ++di)
    for (int dj = -1; dj <= 1; ++dj) three_by_three.emplace_back(di, dj);
  EXPECT_EQ(spike_footprint(0.08, 1.5, 0.02), three_by_three);
  EXPECT_EQ(spike_footprint(0.08, 1.5, 0.05), three_by_three);
  // Radius 0 stays the cell itself: a point foot on a flat crest.
  EXPECT_TRUE(spike_footprint(0.08, 1.5, 0.0).empty());
}

TEST(Levels, CupboardBesideAFloorIsAnUnreachableLevel) {
  // A cupboard 1.8 m high, 0.6 x 0.4 m, on a 2 x 2 m floor: its flat top passes every foothold
  // test, and no step of at most max_climb (0.8 m) joins it to the floor.
  const terrain::Scene scene = scene_with({{{0.2, 0.2, 0.0}, {0.8, 0.6, 1.8}}});
  const auto map = terrain::TerrainMap::from_scene(scene, 0.02, {0.02});
  const auto all = terrain::TerrainMap::from_scene(scene, 0.02, {0.02}, every_level());
  EXPECT_TRUE(all->safe(0.5, 0.4, 0.02));  // without the level rule the top is safe ground
  EXPECT_FALSE(map->safe(0.5, 0.4, 0.02));
  const terrain::PointAnswer a = map->answer(0.5, 0.4, 0.02);
  EXPECT_TRUE(a.observed);
  EXPECT_TRUE(a.unreachable);
  EXPECT_NE(a.unsafe_because.find("0.8 m"), std::string::npos) << a.unsafe_because;
  const terrain::SafetyLayer& l = map->layer(0.02), &la = all->layer(0.02);
  const terrain::HeightGrid& g = map->grid();
  size_t top = 0, top_safe = 0;  // the top's cells, and those safe without the rule
  for (size_t k = 0; k < g.geometry.size(); ++k)
    if (g.elevation[k] > 1.0) {
      ++top;
      top_safe += la.safe[k];
    }
  EXPECT_GE(top, 30u * 20u);
  EXPECT_GT(top_safe, 25u * 15u);
  EXPECT_EQ(l.unreachable_cells, top);
  EXPECT_EQ(map->levels().unreachable_levels, 1u);
  EXPECT_EQ(l.observed_cells + l.unreachable_cells, la.observed_cells);
  EXPECT_EQ(l.safe_cells + top_safe, la.safe_cells);
  EXPECT_DOUBLE_EQ(l.safe_fraction(), double(l.safe_cells) / double(la.observed_cells - top));
  // The floor around it is the same either way.
  for (size_t k = 0; k < l.safe.size(); ++k)
    if (!map->levels().unreachable[k]) ASSERT_EQ(l.safe[k], la.safe[k]) << k;
  // A box 0.6 m high is a step a leg can take: the same level as the floor.
  const terrain::Scene low = scene_with({{{0.2, 0.2, 0.0}, {0.8, 0.6, 0.6}}});
  EXPECT_TRUE(terrain::TerrainMap::from_scene(low, 0.02, {0.02})->safe(0.5, 0.4, 0.02));
}

TEST(Levels, ShippedScenesKeepEverySafeCell) {
  // Pallets up to 60 cm, stairs, the EUR pallet, the trench, the overhang scenes: one level each,
  // so the masks are those without the rule.
  for (const std::string name : {"flat", "pallet_10", "pallet_15", "pallet_60", "eur_pallet",
                                 "stairs", "gap", "shelf_60", "half_shelf_50", "tread_40"}) {
    const auto scene = terrain::make_scene(name);
    const auto map = terrain::TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05});
    const auto all = terrain::TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05}, every_level());
    EXPECT_EQ(map->levels().unreachable_cells, 0u) << name;
    for (const double r : {0.02, 0.05}) {
      EXPECT_EQ(map->layer(r).safe, all->layer(r).safe) << name << " radius " << r;
      EXPECT_GT(map->layer(r).safe_cells, 0u) << name;
    }
  }
}

TEST(Levels, MaxClimbMustBePositive) {
  terrain::SafetyOptions o;
  o.max_climb = 0.0;
  const terrain::Scene scene = scene_with({});
  EXPECT_THROW(terrain::TerrainMap::from_scene(scene, 0.02, {0.02}, o), perception::InputError);
}

// ---- clouds with sensor origins: the height grid's ray rule.
perception::PointCloud grid_points(double x0, double x1, double y0, double y1, double z,
                                   double step) {
  perception::PointCloud c;
  for (double x = x0 + 0.5 * step; x < x1; x += step)
    for (double y = y0 + 0.5 * step; y < y1; y += step)
      c.points.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
  return c;
}

terrain::HeightGrid grid_of(perception::PointCloud cloud, const Eigen::Vector3d& origin) {
  cloud.sensor_origin = origin;
  terrain::HeightGridOptions o;
  o.resolution = 0.04;
  return terrain::build_height_grid(std::vector<perception::PointCloud>{cloud}, o);
}

TEST(WalkableClouds, TableSeenFromTheSideKeepsTheFloorAndTheTableAsOverhead) {
  // The floor, and a table top 0.7 m up over x in [0, 1], seen from a sensor 1.5 m to its side.
  perception::PointCloud cloud = grid_points(-1.0, 2.0, 0.0, 1.0, 0.0, 0.01);
  const perception::PointCloud top = grid_points(0.0, 1.0, 0.2, 0.8, 0.7, 0.01);
  cloud.points.insert(cloud.points.end(), top.points.begin(), top.points.end());
  const terrain::HeightGrid g = grid_of(cloud, Eigen::Vector3d(-1.5, 0.5, 1.2));
  ASSERT_EQ(g.overhead.size(), g.geometry.size());
  const size_t under = cell(g, 0.5, 0.5);
  EXPECT_EQ(g.observed[under], 1);
  EXPECT_NEAR(g.elevation[under], 0.0, 1e-6);
  EXPECT_NEAR(g.overhead[under], 0.7, 1e-5);
  EXPECT_GE(g.overhang_cells, 300u);
  EXPECT_EQ(g.overhang_unobserved_cells, 0u);
  EXPECT_FALSE(std::isfinite(g.overhead[cell(g, 1.5, 0.5)]));
}

TEST(WalkableClouds, DeckSeenFromTheSideIsGround) {
  // A deck 10 cm over the floor, seen from the side: rays reach the floor beneath it, but 10 cm
  // is no room to walk under: the deck is the ground.
  perception::PointCloud cloud = grid_points(-1.0, 2.0, 0.0, 1.0, 0.0, 0.01);
  const perception::PointCloud deck = grid_points(0.0, 1.0, 0.2, 0.8, 0.1, 0.01);
  cloud.points.insert(cloud.points.end(), deck.points.begin(), deck.points.end());
  const terrain::HeightGrid g = grid_of(cloud, Eigen::Vector3d(-1.5, 0.5, 1.2));
  EXPECT_NEAR(g.elevation[cell(g, 0.5, 0.5)], 0.1, 1e-6);
  EXPECT_TRUE(g.overhead.empty());
}

TEST(WalkableClouds, CeilingSeenOnlyFromBeneathIsNotGround) {
  // A room scanned from its middle, 1 m up: the ceiling at 2.5 m everywhere, the floor only where
  // x < 0 (the rest hidden). Over x > 0 the ceiling was seen from beneath only.
  perception::PointCloud cloud = grid_points(-2.0, 0.0, -1.0, 1.0, 0.0, 0.01);
  const perception::PointCloud ceiling = grid_points(-2.0, 2.0, -1.0, 1.0, 2.5, 0.01);
  cloud.points.insert(cloud.points.end(), ceiling.points.begin(), ceiling.points.end());
  const terrain::HeightGrid g = grid_of(cloud, Eigen::Vector3d(0.0, 0.0, 1.0));
  ASSERT_EQ(g.overhead.size(), g.geometry.size());
  size_t high_observed = 0;
  for (size_t k = 0; k < g.geometry.size(); ++k) high_observed += g.observed[k] && g.elevation[k] > 1.5;
  EXPECT_EQ(high_observed, 0u);
  const size_t over_floor = cell(g, -1.0, 0.5), over_nothing = cell(g, 1.0, 0.5);
  EXPECT_EQ(g.observed[over_floor], 1);
  EXPECT_NEAR(g.overhead[over_floor], 2.5, 1e-5);
  EXPECT_EQ(g.observed[over_nothing], 0);
  EXPECT_NEAR(g.overhead[over_nothing], 2.5, 1e-5);
  EXPECT_GT(g.overhang_unobserved_cells, 1000u);
}

TEST(WalkableClouds, NoOverhangNoOverheadLayer) {
  // A plane seen from above: nothing changes for maps without overhangs.
  const terrain::HeightGrid g =
      grid_of(grid_points(-1.0, 1.0, -1.0, 1.0, 0.0, 0.01), Eigen::Vector3d(0.0, 0.0, 1.5));
  EXPECT_TRUE(g.overhead.empty());
  EXPECT_EQ(g.overhang_cells, 0u);
}

TEST(WalkableClouds, BadOverhangFreeHeightIsAnError) {
  terrain::HeightGridOptions o;
  o.overhang_free_height = -1.0;
  const std::vector<perception::PointCloud> clouds{grid_points(0, 1, 0, 1, 0, 0.05)};
  EXPECT_THROW(terrain::build_height_grid(clouds, o), perception::InputError);
  octomap::OcTree tree(kRes);
  tree.updateNode(octomap::point3d(0.1f, 0.1f, 0.1f), true);
  EXPECT_THROW(perception::octree_support_cloud(tree, "t", nullptr, 1000, std::nan("")),
               perception::InputError);
}

}  // namespace
}  // namespace terrastride
