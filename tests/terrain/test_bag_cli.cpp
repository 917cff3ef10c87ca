// `terrastride map RUN.mcap|.db3|.bag|RUN_DIR` end to end: --list, a map with its bag summary,
// and the errors a user meets first.
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;
using terrastride::test_support::run_terrastride;

std::string fixture(const std::string& name) {
  return std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/bags/" + name;
}

TEST(BagCli, ListsABag) {
  const auto r = run_terrastride("map " + fixture("scan_zstd.mcap") + " --list --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["format"], "mcap");
  EXPECT_EQ(j["topics"].size(), 5u);
  EXPECT_EQ(j["frames"].size(), 4u);
  const auto text = run_terrastride("map " + fixture("scan.bag") + " --list");
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_NE(text.out.find("/points  sensor_msgs/PointCloud2  9 messages"), std::string::npos)
      << text.out;
  EXPECT_NE(text.out.find("odom -> base_link (41 samples)"), std::string::npos) << text.out;
}

TEST(BagCli, MapsABag) {
  const fs::path out =
      fs::temp_directory_path() / ("terrastride_bag_cli_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const auto r = run_terrastride("map " + fixture("scan.db3") +
                                 " --topic /points --topic /points_rear --frame odom --out " +
                                 out.string() + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["bags"][0]["topics"]["/points"]["used"], 9);
  EXPECT_EQ(j["bags"][0]["topics"]["/points"]["non_finite"], 252);
  EXPECT_EQ(j["bags"][0]["stream"]["max_cell_points"], 256);
  EXPECT_EQ(j["bags"][0]["stream"]["points_cleaned"], j["points_kept"]);
  EXPECT_TRUE(fs::exists(out / "octomap.bt"));
  fs::remove_all(out);
}

// A split rosbag2 recording: the folder (metadata.yaml and three .mcap files) is the input.
TEST(BagCli, MapsARosbag2Folder) {
  const auto list = run_terrastride("map " + fixture("split") + " --list --json");
  ASSERT_EQ(list.code, 0) << list.err;
  EXPECT_EQ(nlohmann::json::parse(list.out)["topics"].size(), 5u);
  const fs::path out =
      fs::temp_directory_path() / ("terrastride_bag_cli_split_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const auto r = run_terrastride("map " + fixture("split") + " --topic /points --frame odom --out " +
                                 out.string() + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["bags"][0]["format"], "mcap");
  EXPECT_EQ(j["bags"][0]["topics"]["/points"]["used"], 9);
  EXPECT_TRUE(fs::exists(out / "terrain.json"));
  fs::remove_all(out);
  const auto empty = run_terrastride("map " + fs::temp_directory_path().string() +
                                     " --topic /points --frame odom --out " + out.string());
  EXPECT_NE(empty.code, 0);
}

TEST(BagCli, ErrorsNameWhatIsMissing) {
  const std::string out = " --out /tmp/terrastride_bag_cli_never";
  auto r = run_terrastride("map " + fixture("scan_lz4.mcap") + " --frame odom" + out);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--topic"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--list"), std::string::npos) << r.err;
  r = run_terrastride("map " + fixture("scan_lz4.mcap") + " --topic /points" + out);
  EXPECT_NE(r.err.find("--frame"), std::string::npos) << r.err;
  r = run_terrastride("map " + fixture("scan_lz4.mcap") + " --topic /camera/points --frame odom" +
                      out);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("no transform from frame 'camera' to 'odom'"), std::string::npos) << r.err;
  r = run_terrastride("map " + std::string(TERRASTRIDE_SOURCE_DIR) +
                      "/data/scans/flat.pcd --topic /points --frame odom" + out);
  EXPECT_NE(r.err.find("apply to bags"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists("/tmp/terrastride_bag_cli_never"));
}

}  // namespace
