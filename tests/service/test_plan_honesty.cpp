// `terrastride plan` never exits 0 with a plan that fails a post-hoc check, and never plans from a
// measured stance foot that is off the ground.
#include <gtest/gtest.h>
#include <unistd.h>

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

json read_json(const fs::path& path) {
  std::ifstream in(path);
  return json::parse(in);
}

class PlanHonesty : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) / ("terrastride_honesty_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// The exit code and the summary agree with plan.json's post-hoc verdict: 0 only when every check
// passed, 4 (with the failures listed) when the solver's plan fails one, 3 when it did not solve.
void expect_honest(const std::string& args, const fs::path& out) {
  fs::remove(out);
  const auto r = run_terrastride("plan " + args + " --json --out " + out.string());
  ASSERT_TRUE(r.code == 0 || r.code == 3 || r.code == 4) << args << ": " << r.all();
  if (r.code == 3) return;  // not optimal: its own exit code
  ASSERT_TRUE(fs::exists(out)) << args;
  const json plan = read_json(out);
  const json failures = plan["post_hoc"].value("failures", json::array());
  EXPECT_EQ(r.code == 0, failures.empty()) << args << ": " << r.all();
  const json summary = json::parse(r.out.substr(0, r.out.find('\n')), nullptr, false);
  ASSERT_FALSE(summary.is_discarded()) << r.out;
  EXPECT_EQ(summary["checks_passed"], failures.empty()) << args;
  EXPECT_EQ(summary["failures"], failures) << args;
}

// The paper's terrain experiment: the baseline plan drives a shin into the 15 cm pallet's edge.
// It used to exit 0 as "optimal"; the checks' verdict is now its exit code.
TEST_F(PlanHonesty, ABaselinePlanThatHitsThePalletExitsFour) {
  const fs::path out = dir_ / "baseline.json";
  const auto r = run_terrastride("plan --terrain pallet_15 --constraints baseline --out " + out.string());
  EXPECT_EQ(r.code, 4) << r.all();
  EXPECT_NE(r.all().find("post-hoc check"), std::string::npos) << r.all();
  EXPECT_NE(r.all().find("FAILED: "), std::string::npos) << r.all();
  ASSERT_TRUE(fs::exists(out));  // written for inspection
  EXPECT_EQ(read_json(out)["solver"]["status"], "optimal");
  EXPECT_FALSE(read_json(out)["post_hoc"]["failures"].empty());
  expect_honest("--terrain pallet_15 --constraints baseline", dir_ / "again.json");
}

// Off the benchmark's path: other goals, a yaw, a lateral offset, another gait, every set.
TEST_F(PlanHonesty, OffPathRequestsAreCleanOrFailLoudly) {
  for (const char* args : {"--terrain pallet_10 --constraints all --goal 1,0.3,0.5",
                           "--terrain eur_pallet --constraints all --goal 1.5,0,0",
                           "--terrain stairs --constraints all --goal 1,0.3,0.5",
                           "--terrain flat --gait trot --constraints all --goal 0.8,0.2,0.3"})
    expect_honest(std::string(args) + " --max-time 30", dir_ / "off_path.json");
}

// A re-plan from a measured state whose stance foot is off the ground: 2 cm is refused naming the
// foot; 5 mm is placed on the terrain and the correction recorded.
TEST_F(PlanHonesty, MeasuredStanceFeetOffTheGroundAreRefusedOrSettled) {
  const fs::path first = dir_ / "first.json";
  ASSERT_EQ(run_terrastride("plan --terrain flat --duration 2.4 --constraints baseline --out " +
                            first.string()).code, 0);
  const json plan = read_json(first);
  const json& s = plan["samples"][10];  // t = 0.1 s: every foot in stance
  ASSERT_TRUE(s["feet"][0]["contact"].get<bool>());
  const fs::path state = dir_ / "state.json";
  const fs::path out = dir_ / "next.json";
  for (const auto& [dz, refused] :
       std::vector<std::pair<double, bool>>{{0.02, true}, {-0.02, true}, {0.005, false}}) {
    json pos = s["feet"][0]["position"];
    pos[2] = pos[2].get<double>() + dz;
    std::ofstream(state) << json{{"feet", {{"LF", {{"position", pos}}}}}}.dump();
    fs::remove(out);
    const auto r = run_terrastride("plan --terrain flat --init " + first.string() +
                                   " --start-time 0.1 --start-state " + state.string() + " --out " +
                                   out.string());
    if (refused) {
      EXPECT_NE(r.code, 0) << dz;
      EXPECT_NE(r.all().find("feet.LF: in stance"), std::string::npos) << r.all();
      EXPECT_NE(r.all().find(dz > 0 ? "above the terrain" : "below the terrain"), std::string::npos)
          << r.all();
      EXPECT_FALSE(fs::exists(out));
    } else {
      ASSERT_EQ(r.code, 0) << r.all();
      const json next = read_json(out);
      ASSERT_EQ(next["start_state_corrections"].size(), 1u) << next.dump().substr(0, 300);
      EXPECT_EQ(next["start_state_corrections"][0]["foot"], "LF");
      EXPECT_NEAR(next["samples"][0]["feet"][0]["position"][2].get<double>(), 0.0, 1e-9);
    }
  }
}

// A start or goal whose stance is off the map, or a start foot on an edge, is refused before any
// solve, naming the foot and the place (the robot used to start at (0, 0) whatever the map, and
// plan "optimal" with every foothold unsafe).
TEST_F(PlanHonesty, StartsAndGoalsOffTheMapOrOnAnEdgeAreRefused) {
  const fs::path out = dir_ / "never.json";
  for (const auto& [args, says] : std::vector<std::pair<std::string, std::string>>{
           {"--terrain flat --start 3,0,0", "--start: [3, 0, 0]: the nominal LF foot at"},
           {"--terrain flat --goal 5,0,0", "--goal: [5, 0, 0]: the nominal LF foot at"},
           {"--terrain pallet_15 --start 0.24,0,0", "is not a safe foothold"}}) {
    const auto r = run_terrastride("plan " + args + " --out " + out.string());
    EXPECT_EQ(r.code, 1) << args << ": " << r.all();
    EXPECT_NE(r.all().find(says), std::string::npos) << args << ": " << r.all();
    EXPECT_EQ(r.all().find("Ipopt"), std::string::npos) << r.all();
    EXPECT_FALSE(fs::exists(out)) << args;
  }
  // Beside the edge the same start plans (and exits by its checks' verdict).
  expect_honest("--terrain pallet_15 --start 0.1,0.05,0.1 --constraints all --max-time 30",
                dir_ / "beside.json");
}

}  // namespace
