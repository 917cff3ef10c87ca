// OctoMap files as map input (issue #19): read_octomap_file's refusals, octree_support_cloud's
// surfaces, and the map of a committed OctoMap compared with the exact scene it was scanned from.
#include <gtest/gtest.h>
#include <octomap/ColorOcTree.h>
#include <octomap/CountingOcTree.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "perception/test_util.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/scenes.hpp"

namespace terrastride {
namespace {

using perception::test::expect_input_error;
using perception::test::ScratchDir;

std::string fixture(const std::string& name) {
  return std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/octomap/" + name;
}

// A floor at z = 0 (5 cm voxels over 1 x 1 m), a 20 cm block standing on it, and a table top at
// 0.5 m whose underside the sensor saw (free voxels between it and the floor).
template <typename Tree = octomap::OcTree>
Tree floor_block_table() {
  Tree tree(0.05);
  for (double x = 0.025; x < 1.0; x += 0.05)
    for (double y = 0.025; y < 1.0; y += 0.05) {
      tree.updateNode(octomap::point3d(x, y, 0.025), true);
      const bool block = x < 0.3 && y < 0.3;
      const bool table = x > 0.6 && y > 0.6;
      if (block)
        for (double z = 0.075; z < 0.2; z += 0.05) tree.updateNode(octomap::point3d(x, y, z), true);
      if (table) {
        for (double z = 0.075; z < 0.45; z += 0.05)
          tree.updateNode(octomap::point3d(x, y, z), false);
        tree.updateNode(octomap::point3d(x, y, 0.475), true);
      }
    }
  return tree;
}

TEST(OctomapInput, SupportIsTheTopOfEachRunNotWhatWasSeenFromBeneath) {
  const octomap::OcTree tree = floor_block_table();
  perception::OctreeSupportStats st;
  const perception::PointCloud c = perception::octree_support_cloud(tree, "synthetic", &st);
  EXPECT_EQ(st.columns, 400u);
  // Table columns hold two runs (floor, table top); the top is seen from beneath.
  EXPECT_EQ(st.runs, 400u + 64u);
  EXPECT_EQ(st.seen_beneath, 64u);
  ASSERT_EQ(c.points.size(), 400u);
  EXPECT_FALSE(c.sensor_origin);
  for (const auto& p : c.points) {
    const bool block = p.x() < 0.3 && p.y() < 0.3;
    EXPECT_NEAR(p.z(), block ? 0.175 : 0.025, 1e-5) << p.transpose();
  }
}

TEST(OctomapInput, ReadsBinaryAndFullFormatsAlike) {
  ScratchDir dir;
  const octomap::OcTree tree = floor_block_table();
  ASSERT_TRUE(tree.writeBinaryConst(dir.file("t.bt")));
  ASSERT_TRUE(tree.write(dir.file("t.ot")));
  // A ColorOcTree .ot (octomap_server's coloured maps): its occupancy is read.
  const auto color = floor_block_table<octomap::ColorOcTree>();
  ASSERT_TRUE(color.write(dir.file("c.ot")));
  for (const std::string name : {"t.bt", "t.ot", "c.ot"}) {
    const auto read = perception::read_octomap_file(dir.file(name));
    ASSERT_TRUE(read) << name;
    EXPECT_DOUBLE_EQ(read->getResolution(), 0.05);
    const auto c = perception::octree_support_cloud(*read, name);
    EXPECT_EQ(c.points.size(), 400u) << name;
  }
}

TEST(OctomapInput, RefusesOtherTreesAndBrokenFiles) {
  ScratchDir dir;
  // A CountingOcTree counts hits, it holds no occupancy (its files name the type OcTreeBase).
  octomap::CountingOcTree counting(0.05);
  counting.updateNode(octomap::point3d(0.1f, 0.1f, 0.1f));
  {
    std::ofstream out(dir.file("counting.ot"), std::ios::binary);
    counting.write(out);
  }
  expect_input_error([&] { perception::read_octomap_file(dir.file("counting.ot")); },
                     {"counting.ot", "OcTreeBase", "not an occupancy tree"});
  perception::test::write_text(dir.file("text.bt"), "hello\nworld\n");
  expect_input_error([&] { perception::read_octomap_file(dir.file("text.bt")); },
                     {"text.bt", "not an OctoMap"});
  perception::test::write_text(dir.file("empty.bt"), "");
  expect_input_error([&] { perception::read_octomap_file(dir.file("empty.bt")); },
                     {"empty.bt", "empty"});
  expect_input_error([&] { perception::read_octomap_file(dir.file("missing.bt")); },
                     {"missing.bt", "not found"});
  // The committed fixture cut in half: the header promises more nodes than the body holds.
  std::ifstream in(fixture("pallet_10.bt"), std::ios::binary);
  std::stringstream whole;
  whole << in.rdbuf();
  const std::string bytes = whole.str();
  perception::test::write_text(dir.file("cut.bt"), bytes.substr(0, bytes.size() / 2));
  expect_input_error([&] { perception::read_octomap_file(dir.file("cut.bt")); },
                     {"cut.bt", "truncated"});
  // A header cut before "data".
  perception::test::write_text(dir.file("head.bt"), bytes.substr(0, 60));
  expect_input_error([&] { perception::read_octomap_file(dir.file("head.bt")); },
                     {"head.bt", "data"});
  // A tree without occupied voxels.
  octomap::OcTree free_only(0.05);
  free_only.updateNode(octomap::point3d(0.1f, 0.1f, 0.1f), false);
  ASSERT_TRUE(free_only.writeBinaryConst(dir.file("free.bt")));
  const auto tree = perception::read_octomap_file(dir.file("free.bt"));
  expect_input_error([&] { perception::octree_support_cloud(*tree, "free.bt"); },
                     {"free.bt", "no occupied voxel"});
}

// pallet_10.bt is the OctoMap `terrastride map` built from data/scans/pallet_10.pcd
// (tests/fixtures/octomap/generate.sh). Mapped from the OctoMap alone, the grid's measured cells
// lie within one voxel of the exact scene.
TEST(OctomapInput, MapOfAnOctomapMatchesItsScene) {
  terrain::OctreeMapInput input = terrain::read_map_octomap(fixture("pallet_10.bt"));
  const double res = input.tree->getResolution();
  terrain::MapBuildOptions options;
  options.grid.resolution = 0;
  const terrain::MapBuild build = terrain::build_terrain_map_from_octree(input, options);
  ASSERT_TRUE(build.octree);
  EXPECT_DOUBLE_EQ(build.map->grid().geometry.resolution, res);
  const auto scene = terrain::make_scene("pallet_10");
  const terrain::HeightGrid& g = build.map->grid();
  size_t measured = 0, within = 0;
  for (int i = 0; i < g.geometry.nx; ++i)
    for (int j = 0; j < g.geometry.ny; ++j) {
      const size_t k = g.geometry.index(i, j);
      if (g.observed[k] != 1) continue;
      const Eigen::Vector2d c = g.geometry.center(i, j);
      ++measured;
      // A cell straddling the pallet's edge may hold either surface: compare with the scene
      // anywhere in the cell.
      double best = 1e9;
      for (double dx : {-0.5, 0.0, 0.5})
        for (double dy : {-0.5, 0.0, 0.5})
          best = std::min(best, std::abs(g.elevation[k] -
                                         scene->sample(c.x() + dx * res, c.y() + dy * res).height));
      within += best <= res;
    }
  ASSERT_GT(measured, 100u);
  EXPECT_GE(static_cast<double>(within) / measured, 0.97) << within << " of " << measured;
}

TEST(OctomapInput, SharedOctomapsMapWithSensibleSafeFractions) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  for (const std::string name : {"freiburg1_360.bt", "geb079.bt"}) {
    terrain::OctreeMapInput input =
        terrain::read_map_octomap(perception::test::scan("octomap/" + name));
    EXPECT_GT(input.stats.seen_beneath, 0u) << name;  // indoor scans: ceilings, table tops
    terrain::MapBuildOptions options;
    options.grid.resolution = 0;
    const terrain::MapBuild build = terrain::build_terrain_map_from_octree(input, options);
    const double safe = build.map->layer(0.02).safe_fraction();
    EXPECT_GT(safe, 0.3) << name;
    EXPECT_LT(safe, 0.95) << name;
  }
}

}  // namespace
}  // namespace terrastride
