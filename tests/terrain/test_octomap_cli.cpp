// `terrastride map X.bt` and `plan --terrain X.bt` (issue #19): an OctoMap is a map input, not the
// circle "run map X.bt" / "unknown point cloud extension".
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;

std::string fixture() {
  return std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/octomap/pallet_10.bt";
}

TEST(OctomapCli, MapsAnOctomapFile) {
  const fs::path out = fs::temp_directory_path() / ("terrastride_octomap_cli_" +
                                                    std::to_string(::getpid()));
  fs::remove_all(out);
  const auto r = terrastride::test_support::run_terrastride("map " + fixture() + " --out " +
                                                            out.string() + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto summary = nlohmann::json::parse(r.out);
  EXPECT_DOUBLE_EQ(summary["resolution"].get<double>(), 0.05);  // the tree's voxel size
  EXPECT_GT(summary["octomap_input"]["occupied_voxels"].get<size_t>(), 1000u);
  EXPECT_TRUE(fs::exists(out / "octomap.bt"));
  EXPECT_TRUE(fs::exists(out / "layers" / "elevation.npy"));
  fs::remove_all(out);
}

TEST(OctomapCli, RefusesAnOctomapMixedWithClouds) {
  const auto r = terrastride::test_support::run_terrastride(
      "map " + fixture() + " " + std::string(TERRASTRIDE_SOURCE_DIR) +
      "/data/scans/flat.pcd --out /tmp/terrastride_octomap_cli_never");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("give it alone"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists("/tmp/terrastride_octomap_cli_never"));
}

TEST(OctomapCli, PlanOnAnOctomapFile) {
  // The start and goal lie on the scanned floor in front of the pallet.
  const auto r = terrastride::test_support::run_terrastride(
      "plan --terrain " + fixture() + " --start 0.05,0,0 --goal 0.3,0,0 --out /dev/null");
  EXPECT_EQ(r.err.find("terrastride map"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("unknown point cloud"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("--terrain"), std::string::npos) << r.err;
  // A plan was solved on the OctoMap's map (exit 4 is a plan written that fails a post-hoc check:
  // the planner's own affair, e.g. a joint at its limit, not the terrain input's).
  EXPECT_TRUE(r.code == 0 || r.code == 4) << r.err;
  if (r.code == 4) EXPECT_NE(r.err.find("post-hoc check"), std::string::npos) << r.err;
}

}  // namespace
