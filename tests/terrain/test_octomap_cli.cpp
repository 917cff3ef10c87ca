// `terrastride map X.bt` and `plan --terrain X.bt`: an OctoMap is a map input, not the
// circle "run map X.bt" / "unknown point cloud extension".
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

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
  // The start and goal lie on the scanned floor in front of the pallet (at x = 0.05 the RF foot
  // would stand beside a cell the map did not observe, which its 3 x 3 disk on these 5 cm cells
  // does not take).
  const auto r = terrastride::test_support::run_terrastride(
      "plan --terrain " + fixture() +
      " --start 0.1,0,0 --goal 0.3,0,0 --constraints baseline --out /dev/null");
  EXPECT_EQ(r.err.find("terrastride map"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("unknown point cloud"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("--terrain"), std::string::npos) << r.err;
  // A plan was solved on the OctoMap's map (exit 4 is a plan written that fails a post-hoc check:
  // the planner's own affair, e.g. a joint at its limit, not the terrain input's).
  EXPECT_TRUE(r.code == 0 || r.code == 4) << r.err;
  if (r.code == 4) {
    EXPECT_NE(r.err.find("post-hoc check"), std::string::npos) << r.err;
  }
}

// `simulate --terrain X.bt` runs on the map the OctoMap gives, as `simulate --terrain DIR` runs on
// the folder `map X.bt` writes: one terrain opening for every command.
TEST(OctomapCli, SimulateOnAnOctomapFileIsTheRunOnItsMap) {
  const fs::path dir = fs::temp_directory_path() / ("terrastride_octomap_sim_" +
                                                    std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto run = [](const std::string& args) {
    return terrastride::test_support::run_terrastride(args);
  };
  const std::string plan = (dir / "plan.json").string();
  auto r = run("plan --terrain " + fixture() + " --start 0.1,0,0 --goal 0.3,0,0 --out " + plan);
  ASSERT_TRUE(r.code == 0 || r.code == 4) << r.err;
  r = run("map " + fixture() + " --out " + (dir / "map").string());
  ASSERT_EQ(r.code, 0) << r.err;
  r = run("simulate " + plan + " --terrain " + fixture() + " --json --out " +
          (dir / "sim_bt.json").string());
  ASSERT_NE(r.code, 1) << r.err;
  const auto on_file = nlohmann::json::parse(r.out);
  r = run("simulate " + plan + " --terrain " + (dir / "map").string() + " --json --out " +
          (dir / "sim_dir.json").string());
  ASSERT_NE(r.code, 1) << r.err;
  const auto on_folder = nlohmann::json::parse(r.out);
  EXPECT_EQ(on_file["verdict"], on_folder["verdict"]);
  EXPECT_EQ(on_file["position_error_rms_m"], on_folder["position_error_rms_m"]);
  EXPECT_EQ(on_file["heightfield_filled_cells"], on_folder["heightfield_filled_cells"]);
  EXPECT_EQ(on_file["steps"], on_folder["steps"]);
  // A cloud is not a terrain to simulate on: the error says how to make one.
  r = run("simulate " + plan + " --terrain " + std::string(TERRASTRIDE_SOURCE_DIR) +
          "/data/scans/flat.pcd --out " + (dir / "never.json").string());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("terrastride map"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "never.json"));
  fs::remove_all(dir);
}

// A corrupt OctoMap, given as the map input or as a terrain folder's octomap.bt, is exit 1 with an
// error naming the file: a body of 0xFF bytes made OctoMap's recursive reader overflow the stack
// (exit 139) in `map`, and in `plan`, `check`, `report` and `export` with `--terrain DIR`.
TEST(OctomapCli, CorruptOctomapsAreExitOneNamingTheFile) {
  const fs::path dir = fs::temp_directory_path() / ("terrastride_octomap_corrupt_" +
                                                    std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto run = [](const std::string& args) {
    return terrastride::test_support::run_terrastride(args);
  };
  auto r = run("map " + fixture() + " --out " + (dir / "map").string());
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(dir / "map" / "octomap.bt", std::ios::binary);
  const std::string good((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string head = good.substr(0, good.find("\ndata\n") + 6);
  std::string random(2000, '\0');
  for (size_t k = 0; k < random.size(); ++k) random[k] = static_cast<char>((k * 2654435761u) >> 13);
  r = run("plan --terrain flat --duration 2.4 --goal 0.3,0,0 --constraints baseline --out " +
          (dir / "plan.json").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string plan = (dir / "plan.json").string();
  for (const auto& [name, bytes] : std::vector<std::pair<std::string, std::string>>{
           // 4 MB: OctoMap recursed once per 2 bytes until the stack overflowed (exit 139).
           {"ff", head + std::string(1 << 22, '\xff')},
           {"random", head + random},
           {"cut", good.substr(0, good.size() - 10)},
           {"trailing", good + "trailing bytes"}}) {  // was read as if whole
    SCOPED_TRACE(name);
    const fs::path bt = dir / (name + ".bt");
    std::ofstream(bt, std::ios::binary) << bytes;
    r = run("map " + bt.string() + " --out " + (dir / (name + "_map")).string());
    EXPECT_EQ(r.code, 1) << r.err;
    EXPECT_NE(r.err.find(bt.string()), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir / (name + "_map")));
    // The same bytes as a terrain folder's octomap.bt.
    const fs::path terrain = dir / (name + "_terrain");
    fs::copy(dir / "map", terrain, fs::copy_options::recursive);
    std::ofstream(terrain / "octomap.bt", std::ios::binary) << bytes;
    const std::string t = " --terrain " + terrain.string();
    for (const std::string& command :
         {"plan" + t + " --start 0.1,0,0 --goal 0.3,0,0 --out " + (dir / "never.json").string(),
          "check " + plan + t,
          "report" + t + " --out " + (dir / "never.html").string(),
          "export" + t + " --out " + (dir / "never.mcap").string()}) {
      r = run(command);
      EXPECT_EQ(r.code, 1) << command << "\n" << r.err;
      EXPECT_NE(r.err.find((terrain / "octomap.bt").string()), std::string::npos)
          << command << "\n" << r.err;
    }
  }
  EXPECT_FALSE(fs::exists(dir / "never.json"));
  EXPECT_FALSE(fs::exists(dir / "never.html"));
  EXPECT_FALSE(fs::exists(dir / "never.mcap"));
  fs::remove_all(dir);
}

}  // namespace
