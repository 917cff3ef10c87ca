// The map stage as a library call (map_build.hpp): what it builds in memory is what its folder
// holds, so the demo and the report from clouds, which keep the map in memory, judge the same map
// as `plan --terrain DIR` and `report --terrain DIR` do.
#include "terrastride/terrain/map_build.hpp"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <random>
#include <fstream>
#include <string>
#include <vector>

namespace {

using namespace terrastride;
using nlohmann::json;
namespace fs = std::filesystem;

std::vector<std::string> pallet_scan() {
  const std::string dir = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/";
  return {dir + "pallet_10.pcd", dir + "pallet_10.1.pcd", dir + "pallet_10.2.pcd"};
}

// terrain.json without the wall-clock figures.
json without_timings(json j) {
  j.erase("timings");
  return j;
}

class MapBuildTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride-map-build-" +
            std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

TEST_F(MapBuildTest, TheFolderHoldsTheMapBuiltInMemory) {
  terrain::MapInput input = terrain::read_map_clouds(pallet_scan(), std::nullopt);
  ASSERT_EQ(input.clouds.size(), 3u);
  const terrain::MapBuild build = terrain::build_terrain_map(input.clouds);
  ASSERT_TRUE(build.map);
  ASSERT_TRUE(build.octree);
  const std::string out = (dir_ / "map").string();
  const json written = terrain::write_terrain_dir(build, input.sources, out);
  EXPECT_TRUE(fs::exists(fs::path(out) / perception::kOutputMarker));
  EXPECT_TRUE(fs::exists(fs::path(out) / "octomap.bt"));

  // terrain.json as written, as returned, and as made in memory without writing.
  std::ifstream in(fs::path(out) / "terrain.json");
  const json on_disk = json::parse(in);
  EXPECT_EQ(without_timings(on_disk), without_timings(written));
  EXPECT_EQ(without_timings(terrain::terrain_json(build, input.sources)), without_timings(on_disk));
  EXPECT_EQ(on_disk["statistics"]["points_kept"].get<size_t>(), build.points_kept);
  ASSERT_EQ(on_disk["inputs"].size(), 3u);

  // The folder read back is the same field: the same grid, heights, gradients, margins.
  const auto loaded = terrain::load_terrain_dir(out);
  const terrain::TerrainMap& map = *build.map;
  EXPECT_EQ(loaded->grid().elevation, map.grid().elevation);
  EXPECT_EQ(loaded->grid().observed, map.grid().observed);
  EXPECT_EQ(loaded->radii(), map.radii());
  for (double r : map.radii()) EXPECT_EQ(loaded->layer(r).margin, map.layer(r).margin);
  const Eigen::Vector2d lo = map.min_corner(), hi = map.max_corner();
  for (int k = 0; k < 400; ++k) {
    const double x = lo.x() + (hi.x() - lo.x()) * ((k * 37) % 400) / 400.0;
    const double y = lo.y() + (hi.y() - lo.y()) * ((k * 91) % 400) / 400.0;
    const terrain::HeightSample a = map.sample(x, y), b = loaded->sample(x, y);
    EXPECT_EQ(a.height, b.height);
    EXPECT_EQ(a.gradient, b.gradient);
    EXPECT_EQ(map.safety_margin(x, y, 0.02).margin, loaded->safety_margin(x, y, 0.02).margin);
    EXPECT_EQ(map.observed(x, y), loaded->observed(x, y));
  }

  // The OctoMap as saved equals octomap.bt read back: the same leaves, each as occupied.
  octomap::OcTree from_file(0.1);
  ASSERT_TRUE(from_file.readBinary((fs::path(out) / "octomap.bt").string()));
  const auto saved = terrain::octree_as_saved(*build.octree);
  EXPECT_EQ(saved->getResolution(), from_file.getResolution());
  ASSERT_EQ(saved->size(), from_file.size());
  auto a = saved->begin_tree(), b = from_file.begin_tree();
  for (; a != saved->end_tree() && b != from_file.end_tree(); ++a, ++b) {
    ASSERT_EQ(a.getKey(), b.getKey());
    ASSERT_EQ(a.getDepth(), b.getDepth());
    ASSERT_EQ(a->getLogOdds(), b->getLogOdds());
  }
  EXPECT_TRUE(a == saved->end_tree() && b == from_file.end_tree());
}

TEST_F(MapBuildTest, OneCloudAtATimeAndWithoutOctoMapBuildsTheSameGrid) {
  terrain::MapInput input = terrain::read_map_clouds(pallet_scan(), std::nullopt);
  terrain::MapBuildOptions options;
  options.octomap.reset();
  const terrain::MapBuild all = terrain::build_terrain_map(input.clouds, options);
  EXPECT_FALSE(all.octree);

  // The first two clouds, then the third added to them (cleaned once, as a map that grows).
  const terrain::MapBuild first =
      terrain::build_terrain_map({input.clouds[0], input.clouds[1]}, options);
  terrain::MapBuildOptions grow = options;
  grow.cleaned_before = &first.clouds;
  std::vector<terrain::MapStage> stages;
  grow.on_stage = [&](terrain::MapStage stage, const terrain::MapBuild& so_far) {
    stages.push_back(stage);
    if (stage == terrain::MapStage::kGrid) EXPECT_EQ(so_far.kept.size(), 1u);
  };
  const terrain::MapBuild grown = terrain::build_terrain_map({input.clouds[2]}, grow);
  EXPECT_EQ(stages,
            (std::vector<terrain::MapStage>{terrain::MapStage::kClean, terrain::MapStage::kGrid}));
  ASSERT_EQ(grown.clouds.size(), 3u);
  EXPECT_EQ(grown.kept, std::vector<size_t>{all.kept[2]});
  EXPECT_EQ(grown.map->grid().elevation, all.map->grid().elevation);
  EXPECT_EQ(grown.map->grid().observed, all.map->grid().observed);

  // The same grid as the build with an OctoMap.
  const terrain::MapBuild with_octomap = terrain::build_terrain_map(input.clouds);
  EXPECT_EQ(with_octomap.map->grid().elevation, all.map->grid().elevation);
}

TEST_F(MapBuildTest, FailuresNameTheirStageAndAbandonTheBuild) {
  terrain::MapInput input = terrain::read_map_clouds(pallet_scan(), std::nullopt);
  const auto stage_of = [&](const terrain::MapBuildOptions& options) {
    try {
      terrain::build_terrain_map(input.clouds, options);
    } catch (const terrain::MapBuildError& e) {
      return e.stage();
    }
    ADD_FAILURE() << "no error";
    return terrain::MapStage::kOctoMap;
  };
  terrain::MapBuildOptions bad_cleaning;
  bad_cleaning.cleaning->outlier_stddev = 0;
  EXPECT_EQ(stage_of(bad_cleaning), terrain::MapStage::kClean);
  terrain::MapBuildOptions nothing_left;
  nothing_left.cleaning->crop_min = Eigen::Vector3f(100, 100, 100);
  EXPECT_EQ(stage_of(nothing_left), terrain::MapStage::kClean);
  terrain::MapBuildOptions bad_grid;
  bad_grid.grid.resolution = 0.0001;
  EXPECT_EQ(stage_of(bad_grid), terrain::MapStage::kGrid);
  terrain::MapBuildOptions bad_octomap;
  bad_octomap.octomap->resolution = 100;
  EXPECT_EQ(stage_of(bad_octomap), terrain::MapStage::kOctoMap);

  // A caller abandoning the build while the OctoMap is under way gets its own exception back.
  terrain::MapBuildOptions cancelled;
  cancelled.on_stage = [](terrain::MapStage stage, const terrain::MapBuild&) {
    if (stage == terrain::MapStage::kGrid) throw std::runtime_error("cancelled");
  };
  EXPECT_THROW(terrain::build_terrain_map(input.clouds, cancelled), std::runtime_error);
}

// Points on cell boundaries (a 0.1 m lattice on a 2 cm grid) find the same cell in a map kept in
// memory and in the same map read back from its folder: `terrastride query` on a folder and the
// socket's map.update of the same cloud answer `observed` alike.
TEST_F(MapBuildTest, TheFolderAnswersLikeTheMapInMemoryOnCellBoundaries) {
  const std::string cloud = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/pallet_10.pcd";
  terrain::MapInput input = terrain::read_map_clouds({cloud}, std::nullopt);
  const terrain::MapBuild build = terrain::build_terrain_map(input.clouds);
  const std::string out = (dir_ / "map").string();
  terrain::write_terrain_dir(build, input.sources, out);
  const auto loaded = terrain::load_terrain_dir(out);
  // As the socket builds it: no OctoMap, the robot's radius only.
  terrain::MapBuildOptions socket;
  socket.octomap.reset();
  socket.foot_radii = {0.02};
  const terrain::MapBuild in_memory = terrain::build_terrain_map(input.clouds, socket);
  int points = 0;
  for (int i = -5; i <= 13; ++i)
    for (int j = -6; j <= 6; ++j) {
      const double x = 0.1 * i, y = 0.1 * j;
      ++points;
      EXPECT_EQ(build.map->observed(x, y), loaded->observed(x, y)) << x << ", " << y;
      EXPECT_EQ(in_memory.map->observed(x, y), loaded->observed(x, y)) << x << ", " << y;
      EXPECT_EQ(build.map->safe(x, y, 0.02), loaded->safe(x, y, 0.02)) << x << ", " << y;
    }
  EXPECT_EQ(points, 247);
}

TEST_F(MapBuildTest, ReadingNamesTheFile) {
  try {
    terrain::read_map_clouds({(dir_ / "missing.pcd").string()}, std::nullopt);
    FAIL() << "no error";
  } catch (const perception::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.pcd"), std::string::npos) << e.what();
  }
}

// The files are read in parallel (one per core), but the clouds and their statistics come back in
// the order given, each as a read of that file alone returns it, and of several bad files the
// first in that order is the one named, as a loop would.
TEST_F(MapBuildTest, ParallelReadingKeepsTheOrderAndNamesTheFirstBadFile) {
  const std::vector<std::string> files = pallet_scan();
  const std::vector<std::string> order = {files[2], files[0], files[1], files[0]};
  const terrain::MapInput input = terrain::read_map_clouds(order, std::nullopt);
  ASSERT_EQ(input.clouds.size(), order.size());
  ASSERT_EQ(input.sources.files.size(), order.size());
  for (size_t k = 0; k < order.size(); ++k) {
    const terrain::MapInput alone = terrain::read_map_clouds({order[k]}, std::nullopt);
    EXPECT_EQ(input.sources.files[k].path, order[k]);
    EXPECT_EQ(input.sources.files[k].points, alone.sources.files[0].points);
    ASSERT_EQ(input.clouds[k].points.size(), alone.clouds[0].points.size()) << order[k];
    EXPECT_EQ(input.clouds[k].source, alone.clouds[0].source);
    for (size_t i = 0; i < input.clouds[k].points.size(); ++i)
      ASSERT_EQ(input.clouds[k].points[i], alone.clouds[0].points[i]) << order[k] << " point " << i;
  }
  // Files 1 and 3 do not exist; file 1's name is the error's whichever thread fails first.
  const std::vector<std::string> bad = {files[0], (dir_ / "first_missing.pcd").string(), files[1],
                                        (dir_ / "second_missing.pcd").string()};
  for (int attempt = 0; attempt < 5; ++attempt) {
    try {
      terrain::read_map_clouds(bad, std::nullopt);
      FAIL() << "no error";
    } catch (const perception::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("first_missing.pcd"), std::string::npos) << e.what();
    }
  }
}

}  // namespace

// ---- hard cases of the up direction (design.md §5.1).
namespace {

// A 2 x 2 m floor 1.2 m ahead of a camera's body frame pitched 90 deg down: forward (x) is down.
std::vector<Eigen::Vector3f> floor_straight_ahead() {
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) pts.emplace_back(1.2f, -1.0f + 0.02f * i, -1.0f + 0.02f * j);
  return pts;
}

TEST(HardUpCases, SensorLookingStraightDownIsLevelledByAuto) {
  terrain::CloudPoseOptions o;
  o.up = terrain::UpMode::kAuto;
  terrain::CloudPlacement pl;
  const perception::PointCloud cloud =
      terrain::place_map_points(floor_straight_ahead(), "down", o, &pl);
  EXPECT_TRUE(pl.levelled);
  ASSERT_TRUE(pl.plane.has_value());
  ASSERT_TRUE(pl.plane->found);
  EXPECT_NEAR(pl.plane->tilt_deg, 90.0, 0.5);
  EXPECT_NEAR(pl.plane->sensor_height, 1.2, 0.01);
  // Levelled about the sensor: the floor 1.2 m below it, flat.
  for (const Eigen::Vector3f& p : cloud.points) ASSERT_NEAR(p.z(), -1.2f, 1e-3f) << p.transpose();
  // Checked instead, the same cloud is refused, naming the tilt.
  o.up = terrain::UpMode::kCheck;
  try {
    terrain::place_map_points(floor_straight_ahead(), "down", o, &pl);
    ADD_FAILURE() << "a camera looking straight down passed the up check";
  } catch (const perception::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("90.0 deg"), std::string::npos) << e.what();
  }
}

TEST(HardUpCases, NaNsAndNoFloorAreAClearRefusalNotACrash) {
  const fs::path dir = fs::temp_directory_path() / ("terrastride_hard_up_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  // Scattered returns in a 1 m cube (foliage: no plane holds 15 % of them) and NaN points.
  const std::string scatter = (dir / "scatter.xyz").string();
  {
    std::ofstream xyz(scatter);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int k = 0; k < 3000; ++k) {
      xyz << u(rng) << " " << u(rng) << " " << u(rng) << "\n";
      if (k % 3 == 0) xyz << "nan nan nan\n";
    }
  }
  terrain::CloudPoseOptions o;
  o.up = terrain::UpMode::kAuto;
  try {
    terrain::read_map_clouds({scatter}, o);
    ADD_FAILURE() << "--up auto levelled a cloud without a dominant plane";
  } catch (const perception::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("scatter.xyz"), std::string::npos) << what;
    EXPECT_NE(what.find("plane"), std::string::npos) << what;
  }
  // Checked, it is mapped as it is, unchecked, with the reason kept.
  o.up = terrain::UpMode::kCheck;
  const terrain::MapInput in = terrain::read_map_clouds({scatter}, o);
  ASSERT_EQ(in.clouds.size(), 1u);
  EXPECT_EQ(in.clouds[0].points.size(), 3000u);  // the NaNs dropped
  ASSERT_EQ(in.sources.files.size(), 1u);
  ASSERT_TRUE(in.sources.files[0].placement.has_value());
  const auto& plane = in.sources.files[0].placement->plane;
  ASSERT_TRUE(plane.has_value());
  EXPECT_FALSE(plane->found);
  EXPECT_FALSE(plane->problem.empty());
  // NaNs only: the reader's error, naming the file.
  const std::string nans = (dir / "nans.xyz").string();
  std::ofstream(nans) << "nan nan nan\nnan nan nan\n";
  EXPECT_THROW(terrain::read_map_clouds({nans}, o), perception::InputError);
  fs::remove_all(dir);
}

}  // namespace
