// The pipeline's commands share their steps as library calls: the report of clouds is
// the report of their `map` folder, and the demo's plan is the one `plan` makes on the demo's
// terrain folder. Neither re-enters the command line, so these are what keeps them in step.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

json read_json(const fs::path& p) {
  std::ifstream in(p);
  return json::parse(in);
}

// Without wall-clock figures (keys naming "wall", "timings", and the listed ones).
json without(json j, const std::vector<std::string>& keys = {}) {
  if (j.is_object()) {
    json out = json::object();
    for (auto& [k, v] : j.items()) {
      if (k.find("wall") != std::string::npos || k == "timings" || k == "generated_utc" ||
          k == "build_s" || k == "report_build_s" ||
          std::find(keys.begin(), keys.end(), k) != keys.end())
        continue;
      out[k] = without(v, keys);
    }
    return out;
  }
  if (j.is_array()) {
    json out = json::array();
    for (auto& v : j) out.push_back(without(v, keys));
    return out;
  }
  return j;
}

std::string pallet_scan() {
  std::string files;
  for (const char* name : {"pallet_10.pcd", "pallet_10.1.pcd", "pallet_10.2.pcd"})
    files += " " + shell_quote(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/" + name);
  return files;
}

class PipelineTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride-pipeline-" +
            std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  std::string at(const std::string& name) const { return shell_quote((dir_ / name).string()); }
  fs::path dir_;
};

TEST_F(PipelineTest, TheReportOfCloudsIsTheReportOfTheirMapFolder) {
  ASSERT_EQ(run_terrastride("map" + pallet_scan() + " --out " + at("map")).code, 0);
  const auto from_map = run_terrastride("report --terrain " + at("map") + " --out " + at("a.html"));
  ASSERT_EQ(from_map.code, 0) << from_map.err;
  const auto from_clouds =
      run_terrastride("report --terrain" + pallet_scan() + " --out " + at("b.html"));
  ASSERT_EQ(from_clouds.code, 0) << from_clouds.err;
  const json a = read_json(dir_ / "a.json"), b = read_json(dir_ / "b.json");
  // What differs is what the terrain was given as.
  EXPECT_EQ(a["terrain"]["kind"], "map");
  EXPECT_EQ(b["terrain"]["kind"], "clouds");
  EXPECT_EQ(without(a["terrain"], {"kind", "source"}), without(b["terrain"], {"kind", "source"}));
  EXPECT_EQ(a["summary"], b["summary"]);
  EXPECT_EQ(a["problems"], b["problems"]);
}

TEST_F(PipelineTest, TheDemoPlansAsPlanDoesOnTheDemosTerrainFolder) {
  const fs::path out = dir_ / "demo";
  // A generous solver time limit: the test machine may be busy with other builds.
  const auto demo =
      run_terrastride("demo --out " + shell_quote(out.string()) + " --max-time 60 --json");
  ASSERT_TRUE(demo.code == 0 || demo.code == 3 || demo.code == 4) << demo.code << "\n" << demo.err;
  // The demo simulates its plan and records the verdict as `plan --simulate` does.
  const auto plan = run_terrastride("plan --terrain " + shell_quote((out / "terrain").string()) +
                                    " --constraints all --max-time 60 --simulate --out " +
                                    at("plan.json"));
  ASSERT_TRUE(plan.code == 0 || plan.code == 3 || plan.code == 4) << plan.code << "\n" << plan.err;
  json by_demo = read_json(out / "plan.json"), by_plan = read_json(dir_ / "plan.json");
  // The demo's plan names the terrain folder it is found in, as `plan --terrain DIR` does: never
  // the temporary folder the demo wrote it in.
  EXPECT_EQ(by_demo["terrain"], (out / "terrain").string());
  EXPECT_EQ(by_demo["post_hoc"]["terrain"], by_plan["post_hoc"]["terrain"]);
  EXPECT_EQ(by_demo.dump().find(".tmp-"), std::string::npos);
  for (json* p : {&by_demo, &by_plan}) {
    p->erase("terrain");
    (*p)["post_hoc"].erase("terrain");
    // The simulation's speed (CPU time, real-time factor) is the machine's, not the plan's; the
    // heightfield is described by the folder's path.
    for (const char* k : {"cpu_s", "realtime_factor", "terrain"})
      (*p)["post_hoc"]["simulation"].erase(k);
  }
  EXPECT_TRUE(by_demo["post_hoc"]["simulation"].contains("verdict"));
  EXPECT_EQ(without(by_demo), without(by_plan));
}

// A demo whose plan is optimal but fails a post-hoc check exits as `plan` does on it: 4, naming
// the failed checks (not 3, "not optimal").
TEST_F(PipelineTest, TheDemoExitsFourWhenItsPlanFailsAPostHocCheck) {
  const fs::path out = dir_ / "demo_baseline";
  const auto demo = run_terrastride("demo --out " + shell_quote(out.string()) +
                                    " --constraints baseline --max-time 60");
  ASSERT_EQ(demo.code, 4) << demo.all();
  EXPECT_NE(demo.err.find("post-hoc check"), std::string::npos) << demo.err;
  EXPECT_EQ(demo.err.find("not optimal"), std::string::npos) << demo.err;
  const json plan = read_json(out / "plan.json");
  EXPECT_EQ(plan["solver"]["status"], "optimal");
  EXPECT_FALSE(plan["post_hoc"]["failures"].empty());
  EXPECT_EQ(plan["terrain"], (out / "terrain").string());
}

}  // namespace
