// The trunk under an overhang, end to end through the CLI (`plan --constraints all`): shelf_60 is
// a shelf whose underside is 0.6 m up across the path (x in [0.4, 0.9]). HyQ, whose trunk's top
// stands at least 0.62 m up while a foot swings, is refused before any solve with a message naming
// the trunk and the overhang; Go2 is planned under it, clean in every post-hoc check, and passes
// in MuJoCo (--simulate). Go2 also starts under a stair tread (tread_45) and walks out; HyQ is
// refused there.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

namespace {

class OverhangPlan : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("terrastride_overhang_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  struct Planned {
    int code = -1;
    std::string output;
    json summary, plan;
  };
  Planned plan(const std::string& args, const std::string& name) {
    const fs::path out = dir_ / (name + ".json");
    const auto r = run_terrastride("plan --constraints all --max-time 120 " + args +
                                   " --json --out " + shell_quote(out.string()));
    Planned p;
    p.code = r.code;
    p.output = r.all();
    p.summary = json::parse(r.out.substr(0, r.out.find('\n')), nullptr, false);
    if (fs::exists(out)) {
      std::ifstream in(out);
      p.plan = json::parse(in);
    }
    return p;
  }
  static void expect_clean(const Planned& p) {
    const json& c = p.plan["checks"];
    ASSERT_TRUE(c.contains("trunk_collisions")) << c.dump();
    EXPECT_EQ(c["trunk_collisions"], 0);
    EXPECT_GT(c["trunk_min_distance_m"].get<double>(), 0.0);
    EXPECT_EQ(c["shin_collisions"], 0);
    EXPECT_EQ(c["thigh_collisions"], 0);
    EXPECT_TRUE(p.plan["post_hoc"]["failures"].empty()) << p.plan["post_hoc"].dump();
    EXPECT_EQ(p.summary["checks_passed"], true) << p.output;
    EXPECT_EQ(p.summary["simulation"]["verdict"], "pass") << p.output;
  }

  static fs::path dir_;
};
fs::path OverhangPlan::dir_;

TEST_F(OverhangPlan, HyQIsRefusedUnderTheShelfNamingTrunkAndOverhang) {
  const Planned p = plan("--terrain shelf_60", "hyq_shelf_60");
  EXPECT_EQ(p.code, 1) << p.output;
  EXPECT_NE(p.output.find("trunk"), std::string::npos) << p.output;
  EXPECT_NE(p.output.find("overhang"), std::string::npos) << p.output;
  EXPECT_NE(p.output.find("0.60 m above the walkable surface"), std::string::npos) << p.output;
  EXPECT_FALSE(fs::exists(dir_ / "hyq_shelf_60.json"));
}

TEST_F(OverhangPlan, Go2WalksUnderTheShelfCleanAndPassesInMuJoCo) {
  const Planned p = plan("--robot go2 --terrain shelf_60 --simulate", "go2_shelf_60");
  ASSERT_EQ(p.code, 0) << p.output;
  expect_clean(p);
  // The base went from x = 0 to 1, under the shelf (x in [0.4, 0.9]) on the way.
  const json& samples = p.plan["samples"];
  ASSERT_FALSE(samples.empty());
  EXPECT_NEAR(samples.back()["base"]["position"][0].get<double>(), 1.0, 1e-3);
}

TEST_F(OverhangPlan, HyQStartingUnderTheTreadIsRefusedNamingTrunkAndOverhang) {
  // The tread's underside 0.45 m up over the start: HyQ's trunk stands higher than that while a
  // foot swings; Go2's (below) fits.
  const Planned p = plan("--terrain tread_45", "hyq_tread_45");
  EXPECT_EQ(p.code, 1) << p.output;
  EXPECT_NE(p.output.find("hyq's trunk box cannot pass under the overhang"), std::string::npos)
      << p.output;
  EXPECT_NE(p.output.find("0.45 m above the walkable surface"), std::string::npos) << p.output;
  EXPECT_FALSE(fs::exists(dir_ / "hyq_tread_45.json"));
}

TEST_F(OverhangPlan, Go2StartsUnderATreadAndWalksOut) {
  const Planned p = plan("--robot go2 --terrain tread_45 --simulate", "go2_tread_45");
  ASSERT_EQ(p.code, 0) << p.output;
  expect_clean(p);
}

}  // namespace
