// OctoMap files as map input: read_octomap_file's refusals, octree_support_cloud's
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
// 0.5 m whose underside the sensor saw (free voxels between it and the floor); every top surface
// seen from above (free voxels over it).
template <typename Tree = octomap::OcTree>
Tree floor_block_table() {
  Tree tree(0.05);
  for (double x = 0.025; x < 1.0; x += 0.05)
    for (double y = 0.025; y < 1.0; y += 0.05) {
      tree.updateNode(octomap::point3d(x, y, 0.025), true);
      const bool block = x < 0.3 && y < 0.3;
      const bool table = x > 0.6 && y > 0.6;
      double top = 0.05;
      if (block) {
        for (double z = 0.075; z < 0.2; z += 0.05) tree.updateNode(octomap::point3d(x, y, z), true);
        top = 0.2;
      }
      if (table) {
        for (double z = 0.075; z < 0.45; z += 0.05)
          tree.updateNode(octomap::point3d(x, y, z), false);
        tree.updateNode(octomap::point3d(x, y, 0.475), true);
        top = 0.5;
      }
      tree.updateNode(octomap::point3d(x, y, top + 0.025), false);
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

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream whole;
  whole << in.rdbuf();
  return whole.str();
}

// The header of an OctoMap file: its bytes up to and including the "data" line.
std::string header_of(const std::string& bytes) {
  const size_t data = bytes.find("\ndata\n");
  EXPECT_NE(data, std::string::npos);
  return bytes.substr(0, data + 6);
}

// OctoMap's readers recurse for as long as the node bits say children follow, past the tree's 16
// levels and past the end of the file: a body of 0xFF bytes overflowed the stack (SIGSEGV), in
// `terrastride map X.bt` and wherever a terrain folder's octomap.bt is read. Each corrupt body
// is now an InputError naming the file (and the byte).
TEST(OctomapInput, CorruptBinaryBodiesAreRefusedNamingTheFile) {
  ScratchDir dir;
  const std::string good = slurp(fixture("pallet_10.bt"));
  const std::string head = header_of(good);
  const auto refused = [&](const std::string& name, const std::string& bytes,
                           std::initializer_list<std::string> needles) {
    perception::test::write_text(dir.file(name), bytes);
    expect_input_error([&] { perception::read_octomap_file(dir.file(name)); }, needles);
  };
  refused("ff.bt", head + std::string(4096, '\xff'),
          {"ff.bt", "corrupt OctoMap data at byte", "depth 16 has children"});
  refused("ff_short.bt", head + std::string(8, '\xff'), {"ff_short.bt", "truncated"});
  refused("trailing.bt", good + "junk", {"trailing.bt", "4 bytes after the end of the tree"});
  std::string resized = good;
  const size_t size_at = resized.find("size ");
  resized.insert(size_at + 5, "1");  // "size 1NNNN": more nodes than the body holds
  refused("resized.bt", resized, {"resized.bt", "the header says 1"});
  std::string unsized = good;
  unsized.replace(size_at, 4, "siz_");
  refused("unsized.bt", unsized, {"unsized.bt", "'size' line"});
  // A 0xFF body of any length, and random bytes after a valid header (seeded), always fail
  // cleanly.
  for (const size_t n : {1, 2, 3, 31, 32, 33, 1 << 22})
    refused("ff" + std::to_string(n) + ".bt", head + std::string(n, '\xff'), {"ff"});
  std::srand(7);
  for (int k = 0; k < 50; ++k) {
    std::string body(static_cast<size_t>(1 + std::rand() % 5000), '\0');
    for (char& c : body) c = static_cast<char>(std::rand());
    const std::string name = "random" + std::to_string(k) + ".bt";
    perception::test::write_text(dir.file(name), head + body);
    try {
      perception::read_octomap_file(dir.file(name));
    } catch (const perception::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
  // Single bytes of the valid body changed: read, or refused naming the file.
  const size_t body_at = head.size();
  for (size_t k = 0; k < 200; ++k) {
    std::string bytes = good;
    bytes[body_at + (k * 7919) % (good.size() - body_at)] ^= static_cast<char>(1 + k % 255);
    try {
      perception::read_octomap_bytes("flip.bt", bytes, true);
    } catch (const perception::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("flip.bt"), std::string::npos) << e.what();
    }
  }
}

// The full format (.ot) recurses the same way, on one byte of child bits after each node's data.
TEST(OctomapInput, CorruptFullBodiesAreRefusedNamingTheFile) {
  ScratchDir dir;
  const octomap::OcTree tree = floor_block_table();
  ASSERT_TRUE(tree.write(dir.file("t.ot")));
  const auto color = floor_block_table<octomap::ColorOcTree>();
  ASSERT_TRUE(color.write(dir.file("c.ot")));
  for (const std::string name : {"t.ot", "c.ot"}) {
    const std::string good = slurp(dir.file(name));
    const std::string head = header_of(good);
    const auto refused = [&](const std::string& bad, const std::string& bytes,
                             std::initializer_list<std::string> needles) {
      perception::test::write_text(dir.file(bad), bytes);
      expect_input_error([&] { perception::read_octomap_file(dir.file(bad)); }, needles);
    };
    refused("ff_" + name, head + std::string(4096, '\xff'), {"ff_" + name, "corrupt"});
    refused("cut_" + name, good.substr(0, good.size() - 3), {"cut_" + name, "truncated"});
    refused("trailing_" + name, good + "x", {"trailing_" + name, "1 bytes after the end"});
    // A node value that is not a number: the first node's float set to NaN.
    std::string nan = good;
    for (size_t k = 0; k < 4; ++k) nan[head.size() + k] = "\x00\x00\xc0\x7f"[k];
    refused("nan_" + name, nan, {"nan_" + name, "not a finite number"});
    std::srand(11);
    for (int k = 0; k < 30; ++k) {
      std::string body(static_cast<size_t>(1 + std::rand() % 3000), '\0');
      for (char& c : body) c = static_cast<char>(std::rand());
      try {
        perception::read_octomap_bytes("random.ot", head + body, false);
      } catch (const perception::InputError& e) {
        EXPECT_NE(std::string(e.what()).find("random.ot"), std::string::npos) << e.what();
      }
    }
  }
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

// An OctoMap states its resolution: mapped at it, every cell it saw is measured, so no "sparse
// cloud" advice (an 8 cm map used to be told "--resolution 0.19"); a finer grid is told the
// OctoMap's own resolution.
TEST(OctomapInput, ResolutionAdviceIsTheOctomapsOwn) {
  ScratchDir dir;
  octomap::OcTree tree(0.08);
  for (double x = 0.04; x < 2.0; x += 0.08)
    for (double y = 0.04; y < 2.0; y += 0.08) {
      tree.updateNode(octomap::point3d(x, y, 0.04), true);
      if (x > 1.0) tree.updateNode(octomap::point3d(x, y, 0.12), true);  // an 8 cm step
    }
  ASSERT_TRUE(tree.writeBinaryConst(dir.file("coarse.bt")));
  const auto notes_at = [&](double resolution) {
    terrain::OctreeMapInput input = terrain::read_map_octomap(dir.file("coarse.bt"));
    terrain::MapBuildOptions options;
    options.grid.resolution = resolution;
    return terrain::build_terrain_map_from_octree(input, options).map->grid().notes;
  };
  for (const auto& note : notes_at(0)) {  // the tree's 8 cm
    EXPECT_EQ(note.find("sparse cloud"), std::string::npos) << note;
    EXPECT_EQ(note.find("--resolution"), std::string::npos) << note;
  }
  bool advised = false;
  for (const auto& note : notes_at(0.02)) {
    EXPECT_EQ(note.find("sparse cloud"), std::string::npos) << note;
    advised |= note.find("--resolution 0.08 (the OctoMap's)") != std::string::npos;
  }
  EXPECT_TRUE(advised);
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
