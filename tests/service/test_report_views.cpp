// The report's map and 3-D views as a person opens them in headless Chromium: on a map much larger
// than the plan they open on the plan's surroundings, with the whole map one button away; on a
// map about the plan's size they show the whole map.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::shell_quote;

class ReportViews : public ::testing::Test {
 protected:
  void SetUp() override {
    if (std::system("command -v chromium >/dev/null 2>&1 && command -v node >/dev/null 2>&1") != 0)
      FAIL() << "chromium and node are needed (scripts/setup.sh installs both)";
    dir_ = fs::temp_directory_path() /
           ("terrastride-report-views-" +
            std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) + "-" +
            std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  std::string path(const std::string& name) const { return shell_quote((dir_ / name).string()); }

  // The page's self-check as report_check.js prints it (exit code in *code).
  json open_in_browser(const std::string& html, int* code) const {
    const std::string script =
        (fs::path(TERRASTRIDE_SOURCE_DIR) / "tests" / "service" / "report_check.js").string();
    const auto r = terrastride::test_support::run_command("node " + shell_quote(script) + " " +
                                                          path(html));
    *code = r.code;
    try {
      return json::parse(r.out);
    } catch (const std::exception&) {
      return json{{"unparsable", r.all()}};
    }
  }

  // A flat floor from x = x0 to x1 and y = -1.5 to 1.5, points every 5 cm, mapped at 5 cm.
  void map_floor(double x0, double x1, const std::string& out) const {
    std::ofstream xyz(dir_ / "floor.xyz");
    for (double x = x0; x <= x1 + 1e-9; x += 0.05)
      for (double y = -1.5; y <= 1.5 + 1e-9; y += 0.05) xyz << x << ' ' << y << " 0\n";
    xyz.close();
    const auto r = terrastride::test_support::run_terrastride(
        "map " + path("floor.xyz") + " --up z --resolution 0.05 --out " + path(out));
    ASSERT_EQ(r.code, 0) << r.all();
  }

  // A standing plan's report on `terrain` (a plan of 1 s that stays where it starts).
  void report(const std::string& terrain, const std::string& html) const {
    auto r = terrastride::test_support::run_terrastride(
        "plan --terrain " + path(terrain) + " --constraints baseline --goal 0.3,0,0 --out " +
        path("plan.json"));
    ASSERT_TRUE(r.code == 0 || r.code == 4) << r.all();
    r = terrastride::test_support::run_terrastride("report --terrain " + path(terrain) +
                                                   " --plan " + path("plan.json") + " --out " +
                                                   path(html));
    ASSERT_EQ(r.code, 0) << r.all();
  }

  fs::path dir_;
};

TEST_F(ReportViews, ALargeMapOpensOnThePlansSurroundingsWithTheWholeMapOneClickAway) {
  ASSERT_NO_FATAL_FAILURE(map_floor(-2.0, 16.0, "big"));
  ASSERT_NO_FATAL_FAILURE(report("big", "big.html"));
  int code = -1;
  const json check = open_in_browser("big.html", &code);
  ASSERT_EQ(code, 0) << check.dump(1);
  const json& view = check["self_check"]["view"];
  ASSERT_TRUE(view.is_object()) << check.dump(1);
  EXPECT_TRUE(view["zoomed"].get<bool>()) << view.dump();
  const auto plan = view["plan"].get<std::vector<double>>();
  const auto whole = view["whole"].get<std::vector<double>>();
  // The plan's region lies inside the map, holds the plan (which starts at the origin) and is a
  // small part of an 18 m map.
  EXPECT_GE(plan[0], whole[0]);
  EXPECT_LE(plan[1], whole[1]);
  EXPECT_LT(plan[0], 0.0);
  EXPECT_GT(plan[1], 0.3);
  EXPECT_LT(plan[1] - plan[0], (whole[1] - whole[0]) / 3.0);
  EXPECT_GT(whole[1] - whole[0], 17.0);
  // Every chart drew data, the hidden whole-map surface included.
  for (const json& c : check["charts"]) EXPECT_GT(c["points"].get<int>(), 0) << c.dump();
}

TEST_F(ReportViews, AMapTheSizeOfThePlanShowsTheWholeMap) {
  ASSERT_NO_FATAL_FAILURE(map_floor(-1.0, 2.0, "small"));
  ASSERT_NO_FATAL_FAILURE(report("small", "small.html"));
  int code = -1;
  const json check = open_in_browser("small.html", &code);
  ASSERT_EQ(code, 0) << check.dump(1);
  EXPECT_FALSE(check["self_check"]["view"]["zoomed"].get<bool>()) << check.dump(1);
}

}  // namespace
