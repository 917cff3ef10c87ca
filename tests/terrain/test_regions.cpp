// Where a robot may stand and go (terrain::list_safe_regions): regions on the scenes, their
// starts and goals, connectivity through a doorway, and bad footprints.
#include <gtest/gtest.h>

#include <cmath>

#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/terrain/regions.hpp"
#include "terrastride/terrain/scenes.hpp"

using namespace terrastride::terrain;

namespace {

// HyQ's nominal stance: feet at (+-0.31, +-0.29) m in the base frame, 2 cm feet.
RegionOptions hyq_like() {
  RegionOptions o;
  o.footprint.feet = {{0.31, 0.29}, {0.31, -0.29}, {-0.31, 0.29}, {-0.31, -0.29}};
  o.footprint.foot_radius = 0.02;
  return o;
}

bool stance_fits(const TerrainMap& map, const RegionPose& p, const StanceFootprint& f) {
  const double c = std::cos(p.yaw), s = std::sin(p.yaw);
  for (const auto& foot : f.feet)
    if (!map.safe(p.xy.x() + c * foot.x() - s * foot.y(), p.xy.y() + s * foot.x() + c * foot.y(),
                  f.foot_radius))
      return false;
  return true;
}

// A flat 4 m x 2 m grid split by a wall at x in [1.9, 2.1) with a door |y| < door/2.
std::unique_ptr<TerrainMap> two_rooms(double door) {
  HeightGrid grid;
  GridGeometry& g = grid.geometry;
  g.origin = {0.0, -1.0};
  g.resolution = 0.02;
  g.nx = 200;
  g.ny = 100;
  const size_t n = g.size();
  grid.elevation.assign(n, 0.0f);
  grid.variance.assign(n, 0);
  grid.count.assign(n, 5);
  grid.support.assign(n, 5);
  grid.observed.assign(n, 1);
  for (int i = 0; i < g.nx; ++i)
    for (int j = 0; j < g.ny; ++j) {
      const Eigen::Vector2d c = g.center(i, j);
      if (c.x() >= 1.9 && c.x() < 2.1 && std::abs(c.y()) >= door / 2)
        grid.elevation[g.index(i, j)] = 2.0f;
    }
  grid.min = grid.max = grid.elevation;
  return std::make_unique<TerrainMap>(std::move(grid), std::vector<double>{0.02});
}

}  // namespace

TEST(Regions, FlatSceneIsOneRegionWithAStartAndAGoalAhead) {
  auto map = TerrainMap::from_scene(*make_scene("flat"), 0.02, {0.02});
  const RegionListing l = list_safe_regions(*map, hyq_like());
  ASSERT_EQ(l.regions.size(), 1u);
  const SafeRegion& r = l.regions.front();
  EXPECT_EQ(r.id, 1);
  EXPECT_TRUE(stance_fits(*map, r.start, hyq_like().footprint));
  EXPECT_NEAR(r.start.height, 0.0, 1e-9);
  ASSERT_FALSE(r.goals.empty());
  for (const RegionGoal& g : r.goals) EXPECT_TRUE(stance_fits(*map, g.pose, hyq_like().footprint));
  // The first goal lies 1 m ahead along the start's heading.
  const Eigen::Vector2d d = r.goals.front().pose.xy - r.start.xy;
  EXPECT_NEAR(d.norm(), 1.0, 0.03);
  EXPECT_NEAR(r.goals.front().path_length, d.norm(), 0.03);
}

TEST(Regions, PalletTopIsARegionApartFromTheGroundAndSliversAreLeftOut) {
  auto map = TerrainMap::from_scene(*make_scene("pallet_15"), 0.02, {0.02});
  RegionOptions o = hyq_like();
  const RegionListing l = list_safe_regions(*map, o);
  ASSERT_GE(l.regions.size(), 2u);
  bool top = false;
  for (const SafeRegion& r : l.regions) {
    EXPECT_GE(r.area_m2, o.min_area);
    EXPECT_TRUE(stance_fits(*map, r.start, o.footprint));
    EXPECT_NEAR(r.height_min, r.height_max, 1e-6);  // no region spans the pallet's edge
    top = top || std::abs(r.height_min - 0.15) < 1e-6;
  }
  EXPECT_TRUE(top);
  EXPECT_GT(l.regions_too_small, 0u);  // the strips beside the pallet
  for (size_t k = 1; k < l.regions.size(); ++k)
    EXPECT_GE(l.regions[k - 1].cells, l.regions[k].cells);
  o.max_regions = 1;
  const RegionListing one = list_safe_regions(*map, o);
  EXPECT_EQ(one.regions.size(), 1u);
  EXPECT_EQ(one.regions_total, l.regions_total);
}

TEST(Regions, ADoorwayJoinsTwoRoomsOnlyWhenTheStanceFitsThroughIt) {
  // HyQ's stance is 0.58 m wide (plus the feet's margins): a 0.5 m door keeps the rooms apart, a
  // 1 m door joins them.
  const RegionListing narrow = list_safe_regions(*two_rooms(0.5), hyq_like());
  ASSERT_EQ(narrow.regions.size(), 2u) << describe_regions(narrow);
  const RegionListing wide = list_safe_regions(*two_rooms(1.0), hyq_like());
  ASSERT_EQ(wide.regions.size(), 1u);
  EXPECT_GT(wide.regions.front().length_m, 3.0);
  // The farthest goal is in the other room, reached through the door: longer than a straight line
  // only when the start and the goal are not in line with the door.
  const SafeRegion& r = wide.regions.front();
  double farthest = 0;
  for (const RegionGoal& g : r.goals) farthest = std::max(farthest, g.path_length);
  EXPECT_GT(farthest, 1.5);
}

TEST(Regions, EmptyOrNonFiniteFootprintsAreRefused) {
  auto map = TerrainMap::from_scene(*make_scene("flat"), 0.02, {0.02});
  RegionOptions o;
  EXPECT_THROW(list_safe_regions(*map, o), terrastride::perception::InputError);
  o = hyq_like();
  o.footprint.feet[2].x() = std::nan("");
  EXPECT_THROW(list_safe_regions(*map, o), terrastride::perception::InputError);
  o = hyq_like();
  o.yaws.clear();
  EXPECT_THROW(list_safe_regions(*map, o), terrastride::perception::InputError);
  // A stance wider than the map: no region, said plainly.
  o = hyq_like();
  for (auto& f : o.footprint.feet) f *= 20.0;
  const RegionListing none = list_safe_regions(*map, o);
  EXPECT_TRUE(none.regions.empty());
  EXPECT_NE(describe_regions(none).find("no region"), std::string::npos);
}
