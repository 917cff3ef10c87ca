// Walkable surfaces on the shared real OctoMaps (skipped without ../shared): geb079's ceilings over
// rooms whose floor was never scanned are overhangs, not safe ground, and a plan there is refused
// while the corridor crawl still plans; freiburg1_360's floor and table tops are separate levels.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <algorithm>
#include <nlohmann/json.hpp>
#include <string>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"
#include "terrastride/planner/level_reach.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride {
namespace {

terrain::MapBuild map_octomap(const std::string& name) {
  terrain::OctreeMapInput input = terrain::read_map_octomap(perception::test::scan("octomap/" + name));
  terrain::MapBuildOptions options;
  options.grid.resolution = 0;
  options.foot_radii = {0.02};
  return terrain::build_terrain_map_from_octree(input, options);
}

// `terrastride map` of the building's OctoMap (../shared's geb079.bt) into the folder `out`.
test_support::CommandResult map_geb079(const std::string& out) {
  return test_support::run_terrastride("map " + perception::test::scan("octomap/geb079.bt") +
                                       " --out " + out);
}

struct Levels {
  size_t observed = 0, safe = 0, observed_high = 0, safe_high = 0;
};

// Observed and safe cells, and those `above` m or more over `floor`.
Levels levels(const terrain::TerrainMap& map, double floor, double above) {
  const terrain::HeightGrid& g = map.grid();
  const terrain::SafetyLayer& l = map.layer(0.02);
  Levels v;
  for (size_t k = 0; k < g.geometry.size(); ++k) {
    const bool high = g.elevation[k] - floor >= above;
    v.observed += g.observed[k] != 0;
    v.safe += l.safe[k] != 0;
    v.observed_high += g.observed[k] != 0 && high;
    v.safe_high += l.safe[k] != 0 && high;
  }
  return v;
}

TEST(WalkableScans, Geb079CeilingsAreOverhangsNotGround) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const terrain::MapBuild build = map_octomap("geb079.bt");
  const terrain::TerrainMap& map = *build.map;
  const double floor = map.grid().elevation[map.cell_index(6.2, -0.36)];  // the corridor's
  EXPECT_NEAR(floor, -0.04, 0.01);
  const Levels v = levels(map, floor, 1.5);
  // Before: 5602 of 21432 observed cells and 2702 of 15629 safe ones 1.5 m or more above the
  // corridor floor. What is left observed up there are tops seen from above (partitions,
  // cupboards, wall crests): none is safe ground, since a foot's disk reaches the 8 neighbours
  // on these 8 cm cells (a one-cell crest is an edge) and levels no step joins to the floor's
  // are unreachable.
  EXPECT_LT(v.observed_high, v.observed / 20) << v.observed_high << " of " << v.observed;
  EXPECT_EQ(v.safe_high, 0u) << v.safe_high << " of " << v.safe;
  const terrain::SafetyLayer& layer = map.layer(0.02);
  EXPECT_EQ(layer.observed_cells + layer.unreachable_cells, v.observed);
  EXPECT_EQ(layer.unreachable_cells, map.levels().unreachable_cells);
  EXPECT_GT(layer.unreachable_cells, 0u);
  EXPECT_GT(map.grid().overhang_cells, 20000u);
  EXPECT_GT(map.grid().overhang_unobserved_cells, 10000u);
  EXPECT_TRUE(map.safe(6.2, -0.36, 0.02));
  // A ceiling over a room never scanned: no walkable ground, refused with its height.
  const terrain::PointAnswer a = map.answer(0.51, -4.15, 0.02);
  EXPECT_FALSE(a.safe);
  EXPECT_TRUE(a.overhang_only);
  EXPECT_NEAR(a.overhead, 2.64, 0.05);
  const auto hyq = robot::load_robot(robot::resolve_robot_path("hyq"));
  try {
    planner::check_level_reach(map, hyq, {6.2, -0.36, 0}, {0.2, -4.44, 0});
    ADD_FAILURE() << "a goal on the ceiling was accepted";
  } catch (const planner::RequestError& e) {
    EXPECT_EQ(e.field(), "goal");
    EXPECT_NE(std::string(e.what()).find("no walkable ground"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(planner::check_level_reach(map, hyq, {6.2, -0.36, 0}, {7.2, -0.36, 0}));
}

TEST(WalkableScans, Geb079CorridorCrawlStillPlansAndCeilingStartIsRefused) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  perception::test::ScratchDir dir;
  const std::string out = dir.file("geb079");
  auto r = map_geb079(out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("overhangs (overhead clearance layer)"), std::string::npos) << r.out;
  r = test_support::run_terrastride("plan --terrain " + out +
                                    " --start 6.2,-0.36,0 --goal 7.2,-0.36,0 --constraints all "
                                    "--out " + dir.file("crawl.json"));
  EXPECT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.out.find("optimal"), std::string::npos) << r.out;
  r = test_support::run_terrastride("plan --terrain " + out +
                                    " --start 0.2,-4.44,0 --goal 1,-4.44,0 --out " +
                                    dir.file("ceiling.json"));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("--start: [0.2, -4.44, 0]"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("no walkable ground"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(dir.file("ceiling.json")));
}

// geb079's corridor walls reach 0.12 m below its floor with free voxels under them: the column
// rule reads each as an overhang, which has no room beneath it over the floor beside it, so it is
// no overhead (it had put one 0.02 m above the corridor floor at (9.83, -1.01) through the
// overhead field's window, and the trunk pre-check refused a plan along the corridor there).
TEST(WalkableScans, Geb079WallsAreNoOverhangs) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const terrain::MapBuild build = map_octomap("geb079.bt");
  const terrain::TerrainMap& map = *build.map;
  const terrain::HeightGrid& g = map.grid();
  // What is left over the corridor floor there is a real underside 0.9 m up (0.92 m of room).
  EXPECT_GT(map.overhead(9.83, -1.01), 0.8);
  EXPECT_FALSE(std::isfinite(g.overhead[map.cell_index(9.83, -1.17)]));
  // Another wall's foot, 0.2 m over the floor of the room at x = -5.6, within the trunk's reach at
  // the goal of the crawl below (whose last knot's trunk rows it had left infeasible).
  EXPECT_FALSE(std::isfinite(g.overhead[map.cell_index(-6.0, 1.1)]));
  // Every underside left beside the floor (the lowest observed ground within two cells at the
  // corridor's level) has the free height over it.
  const float floor = g.elevation[map.cell_index(6.2, -0.36)];
  const int r = 2;
  for (int i = 0; i < g.geometry.nx; ++i)
    for (int j = 0; j < g.geometry.ny; ++j) {
      const float o = g.overhead[g.geometry.index(i, j)];
      if (!std::isfinite(o)) continue;
      float ground = std::numeric_limits<float>::infinity();
      for (int a = std::max(0, i - r); a <= std::min(g.geometry.nx - 1, i + r); ++a)
        for (int b = std::max(0, j - r); b <= std::min(g.geometry.ny - 1, j + r); ++b) {
          const size_t n = g.geometry.index(a, b);
          if (g.observed[n] == 1) ground = std::min(ground, g.elevation[n]);
        }
      if (ground < floor + 0.1f)
        ASSERT_GE(o, ground + perception::kOverhangFreeHeight - 1e-4) << "cell " << i << ", " << j;
    }
}

// `regions` suggests only what `plan` accepts before its solve: every region of the building
// floor gets a command, and no suggested pair meets the trunk refusal.
TEST(WalkableScans, Geb079RegionsSuggestOnlyPairsThePlannerAccepts) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  perception::test::ScratchDir dir;
  const std::string out = dir.file("geb079");
  auto r = map_geb079(out);
  ASSERT_EQ(r.code, 0) << r.err;
  r = test_support::run_terrastride("regions --terrain " + out + " --json");
  ASSERT_EQ(r.code, 0) << r.all();
  const nlohmann::json listing = nlohmann::json::parse(r.out);
  ASSERT_GE(listing["regions"].size(), 5u);
  size_t with_command = 0;
  for (const auto& region : listing["regions"]) {
    with_command += !region["plan_command"].get<std::string>().empty();
    // A refused pair says why; a trunk refusal names a real underside, with the free height
    // beneath it (a wall's foot under the floor had been one 0.02 m up).
    for (const auto& d : region["plan_pairs_refused_before_solve"]) {
      const std::string why = d["refused"].get<std::string>();
      const size_t at = why.find(" m above the walkable surface");
      if (why.rfind("trunk:", 0) != 0 || at == std::string::npos) continue;
      const double room = std::stod(why.substr(why.rfind(' ', at - 1) + 1));
      EXPECT_GE(room, perception::kOverhangFreeHeight) << why;
    }
  }
  EXPECT_GE(with_command + 1, listing["regions"].size());
  // The crawl along the room at x = -5.6 (a region's suggestion) plans: it had ended infeasible
  // after 129 iterations, its trunk 0.011 m into a wall's foot read as an overhang.
  r = test_support::run_terrastride("plan --terrain " + out +
                                    " --start -5.56,-0.44,1.571 --goal -5.56,0.44,1.571 "
                                    "--constraints all --out " + dir.file("room.json"));
  EXPECT_EQ(r.code, 0) << r.all();
  // The text names the region no pair of which passes.
  r = test_support::run_terrastride("regions --terrain " + out);
  ASSERT_EQ(r.code, 0) << r.all();
  if (with_command < listing["regions"].size())
    EXPECT_NE(r.out.find("no suggested start and goal pass plan's checks"), std::string::npos)
        << r.out;
}

TEST(WalkableScans, Freiburg360FloorAndTableTopsAreSeparateLevels) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const terrain::MapBuild build = map_octomap("freiburg1_360.bt");
  const terrain::TerrainMap& map = *build.map;
  const terrain::HeightGrid& g = map.grid();
  const terrain::SafetyLayer& l = map.layer(0.02);
  size_t floor_safe = 0, table_level = 0, table_overhead = 0, ceiling_safe = 0;
  for (size_t k = 0; k < g.geometry.size(); ++k) {
    const float z = g.elevation[k];
    floor_safe += l.safe[k] && std::abs(z) < 0.1;
    table_level += g.observed[k] && z > 0.65 && z < 0.95;
    // A table top seen from beneath, with the floor walkable under it.
    table_overhead += g.observed[k] && std::abs(z) < 0.1 && g.overhead.size() == g.geometry.size() &&
                      g.overhead[k] > 0.5 && g.overhead[k] < 0.9;
    ceiling_safe += l.safe[k] && z > 2.2;
  }
  // Before: the floor 18,380 safe cells, the ceiling 3,038 safe cells above 2.2 m.
  EXPECT_GT(floor_safe, 18000u);
  EXPECT_GT(table_level, 5000u);     // table tops seen from above only: a level of their own
  EXPECT_GT(table_overhead, 2000u);  // seen from beneath: overhangs with their clearance
  EXPECT_LT(ceiling_safe, 50u);
}

}  // namespace
}  // namespace terrastride
