// A newcomer's first hour (README.md) through the terrastride binary, in a scratch folder as a user
// runs it: the commands terrastride prints for pasting (`regions`' plan commands, `plan`'s next
// steps) run as printed through the shell, on the shipped scenes and on real scans (a noisy floor,
// a building floor); a large map's report says on the command line that it opens on the plan.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::CommandResult;
using terrastride::test_support::run_command;
using terrastride::test_support::shell_quote;

class FirstHour : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride-first-hour-" +
            std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) + "-" +
            std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }

  // `terrastride ARGS` run from the scratch folder.
  CommandResult terrastride(const std::string& args) const {
    return run_command("cd " + shell_quote(dir_.string()) + " && " + TERRASTRIDE_BINARY + " " +
                       args);
  }
  // A line terrastride printed, pasted into a shell in the scratch folder.
  CommandResult paste(const std::string& line) const {
    return run_command("cd " + shell_quote(dir_.string()) + " && " + line);
  }

  static bool shared_scans_present() {
    return fs::is_directory(fs::path(TERRASTRIDE_SHARED_DIR) / "scans");
  }
  static std::string scan(const std::string& relative) {
    return (fs::path(TERRASTRIDE_SHARED_DIR) / "scans" / relative).string();
  }

  fs::path dir_;
};

// The lines of `text` that start with `prefix`, without it.
std::vector<std::string> lines_after(const std::string& text, const std::string& prefix) {
  std::vector<std::string> found;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    if (line.rfind(prefix, 0) == 0) found.push_back(line.substr(prefix.size()));
  return found;
}

#define REQUIRE_SHARED_SCANS()                    \
  if (!shared_scans_present())                    \
  GTEST_SKIP() << "no " << TERRASTRIDE_SHARED_DIR \
               << "/scans (the shared scans folder is not beside this clone)"

// `plan --terrain flat` exits 0 and says so in one line, then names the commands that judge the
// plan; pasted as printed, both run and pass.
TEST_F(FirstHour, APlanThatPassesSaysSoAndItsNextStepsRunAsPrinted) {
  const CommandResult planned = terrastride("plan --terrain flat --out p.json");
  ASSERT_EQ(planned.code, 0) << planned.all();
  EXPECT_NE(planned.out.find("\nPASS: optimal, every post-hoc check clean"), std::string::npos)
      << planned.out;
  const std::vector<std::string> check = lines_after(planned.out, "next: ");
  ASSERT_EQ(check.size(), 1u) << planned.out;
  EXPECT_NE(check[0].find(" check p.json --terrain flat"), std::string::npos) << check[0];
  const std::vector<std::string> simulate = lines_after(planned.out, "      ");
  ASSERT_EQ(simulate.size(), 1u) << planned.out;
  EXPECT_NE(simulate[0].find(" simulate p.json --terrain flat --out sim.json"), std::string::npos)
      << simulate[0];
  const CommandResult checked = paste(check[0]);
  EXPECT_EQ(checked.code, 0) << checked.all();
  EXPECT_NE(checked.out.find("PASS: all checks passed"), std::string::npos) << checked.out;
  const CommandResult simulated = paste(simulate[0]);
  EXPECT_EQ(simulated.code, 0) << simulated.all();
  EXPECT_TRUE(fs::exists(dir_ / "sim.json"));
  // A plan that fails a check prints no PASS line and no next steps (exit 4).
  const CommandResult baseline =
      terrastride("plan --terrain pallet_15 --constraints baseline --out b.json");
  EXPECT_EQ(baseline.code, 4) << baseline.all();
  EXPECT_EQ(baseline.out.find("PASS"), std::string::npos) << baseline.out;
  EXPECT_EQ(baseline.out.find("next: "), std::string::npos) << baseline.out;
}

// With this binary first on PATH, a printed command names it bare, as the user typed it; with
// another `terrastride` first on PATH, the absolute path of this one (the other is not run).
TEST_F(FirstHour, PrintedCommandsNameTheBinaryAsTheShellFindsIt) {
  const std::string bin_dir = fs::path(TERRASTRIDE_BINARY).parent_path().string();
  CommandResult r = paste("PATH=" + shell_quote(bin_dir) +
                          ":\"$PATH\" terrastride regions --terrain flat --max-regions 1");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.out.find("\nregion 1: terrastride plan --terrain flat "), std::string::npos) << r.out;
  fs::create_directories(dir_ / "other");
  fs::create_symlink("/bin/true", dir_ / "other" / "terrastride");
  r = paste("PATH=" + shell_quote((dir_ / "other").string()) + ":\"$PATH\" " + TERRASTRIDE_BINARY +
            " regions --terrain flat --max-regions 1");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.out.find("\nregion 1: " + fs::canonical(TERRASTRIDE_BINARY).string() + " plan "),
            std::string::npos)
      << r.out;
}

// The building floor: `regions` names the corridor, and its first plan command, pasted as
// printed, plans from a terrain path with a space in it (quoted in the command).
TEST_F(FirstHour, RegionsPlanCommandPastedAsPrintedPlansOnTheBuildingFloor) {
  REQUIRE_SHARED_SCANS();
  fs::create_directories(dir_ / "my maps");
  fs::create_symlink(scan("octomap/geb079.bt"), dir_ / "my maps" / "geb079.bt");
  const CommandResult listed = terrastride("regions --terrain 'my maps/geb079.bt' --max-regions 2");
  ASSERT_EQ(listed.code, 0) << listed.all();
  EXPECT_NE(listed.out.find("region 1: "), std::string::npos) << listed.out;
  EXPECT_NE(listed.out.find("(corridor-like)"), std::string::npos) << listed.out;
  EXPECT_NE(listed.out.find("yaw in radians"), std::string::npos) << listed.out;
  std::smatch m;
  ASSERT_TRUE(std::regex_search(listed.out, m, std::regex("\nregion 1: (.* plan --terrain .*)\n")))
      << listed.out;
  const std::string command = m[1];
  EXPECT_NE(command.find("--terrain 'my maps/geb079.bt'"), std::string::npos) << command;
  const CommandResult planned = paste(command);
  EXPECT_EQ(planned.code, 0) << command << "\n" << planned.all();
  EXPECT_TRUE(fs::exists(dir_ / "plan.json"));
  // --json carries the same command.
  const CommandResult as_json =
      terrastride("regions --terrain 'my maps/geb079.bt' --max-regions 2 --json");
  ASSERT_EQ(as_json.code, 0) << as_json.all();
  EXPECT_EQ(json::parse(as_json.out)["regions"][0]["plan_command"], command);
}

// The real noisy floor (σ ≈ 26 mm): refused as it is with the flag that fixes it, mapped with that
// flag; the first region's plan command, pasted, plans a 1 m crawl that checks and simulates.
TEST_F(FirstHour, NoisyFloorMapsPlansChecksAndSimulates) {
  REQUIRE_SHARED_SCANS();
  const std::string cloud = shell_quote(scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"));
  const CommandResult refused = terrastride("map " + cloud + " --out floor");
  EXPECT_EQ(refused.code, 1) << refused.all();
  EXPECT_NE(refused.err.find("--viewpoint origin"), std::string::npos) << refused.err;
  // Its last resort, z taken as up, keeps the VIEWPOINT's rotation: written, and said unusable.
  const CommandResult as_is = terrastride("map " + cloud + " --up z --out as_is");
  ASSERT_EQ(as_is.code, 0) << as_is.all();
  EXPECT_NE(as_is.out.find("warning: no observed cell is safe"), std::string::npos) << as_is.out;
  // report takes only --origin of map's pose flags: its refusal says how to use the others.
  const CommandResult report_refused = terrastride("report --terrain " + cloud + " --out r.html");
  EXPECT_EQ(report_refused.code, 1) << report_refused.all();
  EXPECT_NE(report_refused.err.find("report takes only --origin"), std::string::npos)
      << report_refused.err;
  EXPECT_NE(
      report_refused.err.find(" map " + scan("anybotics_samples/grid_map_pcl_input_cloud.pcd") +
                              " --out grid_map_pcl_input_cloud-map` with the flag added"),
      std::string::npos)
      << report_refused.err;
  const CommandResult mapped = terrastride("map " + cloud + " --viewpoint origin --out floor");
  ASSERT_EQ(mapped.code, 0) << mapped.all();
  EXPECT_EQ(mapped.out.find("warning:"), std::string::npos) << mapped.out;
  // The map names the next step; pasted, it lists the floor's regions.
  const std::vector<std::string> next = lines_after(mapped.out, "next: ");
  ASSERT_EQ(next.size(), 1u) << mapped.out;
  EXPECT_NE(next[0].find(" regions --terrain floor"), std::string::npos) << next[0];
  const CommandResult listed = paste(next[0]);
  ASSERT_EQ(listed.code, 0) << listed.all();
  std::smatch m;
  ASSERT_TRUE(std::regex_search(listed.out, m, std::regex("\nregion 1: (.* plan --terrain .*)\n")))
      << listed.out;
  const CommandResult planned = paste(m[1]);
  ASSERT_EQ(planned.code, 0) << planned.all();
  EXPECT_NE(planned.out.find("\nPASS: optimal"), std::string::npos) << planned.out;
  const std::vector<std::string> check = lines_after(planned.out, "next: ");
  const std::vector<std::string> simulate = lines_after(planned.out, "      ");
  ASSERT_EQ(check.size(), 1u) << planned.out;
  ASSERT_EQ(simulate.size(), 1u) << planned.out;
  const CommandResult checked = paste(check[0]);
  EXPECT_EQ(checked.code, 0) << checked.all();
  const CommandResult simulated = paste(simulate[0]);
  EXPECT_EQ(simulated.code, 0) << simulated.all();
  EXPECT_NE(simulated.out.find("PASS"), std::string::npos) << simulated.out;
}

// A building map's report opens on the plan, and says so without a browser: a `view:` line and
// the --json summary's view (the plan's surroundings, inside the map, under a third of it). A
// plan on a scene its own size gets the whole map.
TEST_F(FirstHour, ALargeMapsReportSaysItOpensOnThePlan) {
  REQUIRE_SHARED_SCANS();
  const std::string bt = shell_quote(scan("octomap/geb079.bt"));
  ASSERT_EQ(terrastride("map " + bt + " --out geb079-map").code, 0);
  const CommandResult planned = terrastride(
      "plan --terrain geb079-map --start 24.12,-0.04,0 --goal 25.08,-0.04,0 --out P.json");
  ASSERT_EQ(planned.code, 0) << planned.all();
  const CommandResult reported =
      terrastride("report --terrain geb079-map --plan P.json --out r.html");
  ASSERT_EQ(reported.code, 0) << reported.all();
  EXPECT_NE(reported.out.find("view: the map and 3-D views open on the plans' surroundings, x "),
            std::string::npos)
      << reported.out;
  const CommandResult as_json =
      terrastride("report --terrain geb079-map --plan P.json --out r.html --json");
  ASSERT_EQ(as_json.code, 0) << as_json.all();
  const json view = json::parse(as_json.out)["view"];
  ASSERT_TRUE(view.is_object()) << as_json.out;
  EXPECT_TRUE(view["zoomed"].get<bool>()) << view.dump();
  const auto plan = view["plan"].get<std::vector<double>>();
  const auto whole = view["whole"].get<std::vector<double>>();
  EXPECT_GE(plan[0], whole[0]);
  EXPECT_LE(plan[1], whole[1]);
  EXPECT_LT(plan[0], 24.12);
  EXPECT_GT(plan[1], 25.08);
  EXPECT_LT(plan[1] - plan[0], (whole[1] - whole[0]) / 3.0);
  ASSERT_EQ(terrastride("plan --terrain flat --out flat.json").code, 0);
  const CommandResult small = terrastride("report --terrain flat --plan flat.json --out f.html");
  ASSERT_EQ(small.code, 0) << small.all();
  EXPECT_NE(small.out.find("view: the whole map"), std::string::npos) << small.out;
}

// A cloud given where a map is expected: plan, regions, check and query refuse it with the `map`
// command to paste; pasted as printed, it writes the folder the hint then names, and regions runs
// on it.
TEST_F(FirstHour, ACloudGivenAsTerrainGetsTheMapCommandToPaste) {
  {
    std::ofstream xyz(dir_ / "my floor.xyz");
    for (int i = 0; i <= 100; ++i)
      for (int j = 0; j <= 60; ++j) xyz << 0.02 * i << ' ' << -0.6 + 0.02 * j << " 0\n";
  }
  ASSERT_EQ(terrastride("plan --terrain flat --out p.json").code, 0);
  std::string command;
  for (const std::string args :
       {"plan --terrain 'my floor.xyz' --out x.json", "regions --terrain 'my floor.xyz'",
        "check p.json --terrain 'my floor.xyz'", "query 'my floor.xyz' --at 0.5,0"}) {
    const CommandResult refused = terrastride(args);
    EXPECT_EQ(refused.code, 1) << args << "\n" << refused.all();
    std::smatch m;
    ASSERT_TRUE(std::regex_search(refused.err, m, std::regex("map it first with `([^`]*)`")))
        << args << "\n"
        << refused.err;
    EXPECT_NE(refused.err.find("'my floor-map'"), std::string::npos) << refused.err;
    if (command.empty()) command = m[1];
    EXPECT_EQ(m[1], command) << args;
  }
  const CommandResult mapped = paste(command);
  ASSERT_EQ(mapped.code, 0) << command << "\n" << mapped.all();
  EXPECT_TRUE(fs::is_directory(dir_ / "my floor-map"));
  const CommandResult listed = terrastride("regions --terrain 'my floor-map'");
  EXPECT_EQ(listed.code, 0) << listed.all();
  // A start off the map names the regions command that lists starts on it; pasted, it runs.
  const CommandResult off = terrastride("plan --terrain 'my floor-map' --start 5,5,0 --out o.json");
  EXPECT_EQ(off.code, 1) << off.all();
  std::smatch m;
  ASSERT_TRUE(
      std::regex_search(off.err, m, std::regex("--start: .*; `([^`]* regions [^`]*)` lists")))
      << off.err;
  const CommandResult pasted = paste(m[1]);
  EXPECT_EQ(pasted.code, 0) << pasted.all();
  EXPECT_NE(pasted.out.find("region 1: "), std::string::npos) << pasted.out;
}

// The demo (README's first step) from a scratch folder: it writes out/demo/report.html there and
// its check line gives the shin's distance to certain voxels, the one that fails a plan, with the
// contacts within the map's uncertainty counted as failing nothing.
TEST_F(FirstHour, TheDemoWritesItsReportAndSaysWhichShinFiguresJudgeThePlan) {
  const CommandResult demo = terrastride("demo");
  ASSERT_EQ(demo.code, 0) << demo.all();
  EXPECT_TRUE(fs::exists(dir_ / "out" / "demo" / "report.html")) << demo.all();
  std::smatch m;
  ASSERT_TRUE(std::regex_search(demo.out, m,
                                std::regex("shin min (-?[0-9.]+) mm to certain voxels, ([0-9]+) "
                                           "shin contacts with voxels within the map's "
                                           "uncertainty \\(these fail nothing\\)")))
      << demo.out;
  EXPECT_GE(std::stod(m[1]), 0.0) << "a demo plan that passes keeps its shins off certain voxels";
  EXPECT_EQ(demo.out.find("mm to the voxels"), std::string::npos) << demo.out;
}

}  // namespace
