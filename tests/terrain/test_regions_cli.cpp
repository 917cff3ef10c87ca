// `terrastride regions` on a real building floor: it names the corridor and a start from which
// `terrastride plan` succeeds, without the user reading any layer.
#include <gtest/gtest.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"

using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

TEST(RegionsCli, BuildingFloorListsTheCorridorAndItsSuggestedPlanSucceeds) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const std::string bt = terrastride::perception::test::scan("octomap/geb079.bt");
  const auto listed = run_terrastride("regions --terrain " + shell_quote(bt) + " --json");
  ASSERT_EQ(listed.code, 0) << listed.all();
  const nlohmann::json j = nlohmann::json::parse(listed.out);
  ASSERT_FALSE(j.at("regions").empty());
  const nlohmann::json& r = j.at("regions").at(0);
  // The largest region is the corridor: long, narrow, on the floor.
  EXPECT_GE(r.at("length_m").get<double>(), 2.5 * r.at("width_m").get<double>());
  EXPECT_LT(std::abs(r.at("ground_z").at(1).get<double>()), 0.5);
  ASSERT_FALSE(r.at("goals").empty());
  const auto pose = [](const nlohmann::json& p) {
    return std::to_string(p.at("x").get<double>()) + "," + std::to_string(p.at("y").get<double>()) +
           "," + std::to_string(p.at("yaw").get<double>());
  };
  const std::filesystem::path out =
      std::filesystem::temp_directory_path() / ("terrastride_regions_plan_" +
                                                std::to_string(::getpid()) + ".json");
  const auto planned = run_terrastride(
      "plan --terrain " + shell_quote(bt) + " --start " + pose(r.at("start")) + " --goal " +
      pose(r.at("goals").at(0).at("pose")) + " --constraints all --out " + shell_quote(out));
  EXPECT_EQ(planned.code, 0) << planned.all();
  std::filesystem::remove(out);
  // The text form says the same for people, with the command to paste.
  const auto text = run_terrastride("regions --terrain " + shell_quote(bt) + " --max-regions 3");
  ASSERT_EQ(text.code, 0) << text.all();
  EXPECT_NE(text.out.find("corridor-like"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("terrastride plan --terrain"), std::string::npos) << text.out;
  // Bad input: an unknown terrain and an unknown robot are named.
  const auto bad = run_terrastride("regions --terrain no_such_scene_or_dir");
  EXPECT_NE(bad.code, 0);
  EXPECT_NE(bad.all().find("no_such_scene_or_dir"), std::string::npos) << bad.all();
  const auto bad_robot = run_terrastride("regions --terrain flat --robot no_such_robot");
  EXPECT_NE(bad_robot.code, 0);
  EXPECT_NE(bad_robot.all().find("--robot"), std::string::npos) << bad_robot.all();
}
