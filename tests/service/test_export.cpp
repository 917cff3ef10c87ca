// `terrastride export`: the MCAP file is read back by an independent reader, @mcap/core
// (tests/service/mcap_check.js, service/report's Node toolchain), which decodes every message of
// every channel, checks it against the Foxglove schema the file carries, validates the CRCs and
// compares the message counts with what the plan and the simulation hold.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include <cstdlib>
#include "support/run_command.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::CommandResult;
using terrastride::test_support::run_command;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

std::string q(const fs::path& p) {
  return shell_quote(p.string());
}

// Runs the Node reader; its JSON verdict.
json read_back(const fs::path& mcap, const json& expected) {
  const std::string script = std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/service/mcap_check.js";
  const CommandResult r =
      run_command("node " + shell_quote(script) + " " + q(mcap) + " " + shell_quote(expected.dump()));
  try {
    return json::parse(r.out);
  } catch (const std::exception&) {
    return {{"ok", false}, {"errors", {"mcap_check.js: " + r.all()}}};
  }
}

class ExportTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (run_command("node --version").code != 0) return;
    dir_ = new TempDir();
    plan_ = dir_->path() / "plan.json";
    sim_ = dir_->path() / "sim.json";
    // A short crawl on the flat scene, and its execution in MuJoCo.
    plan_code_ = run_terrastride("plan --terrain flat --duration 2.4 --constraints baseline --out " +
                                 q(plan_)).code;
    sim_code_ = run_terrastride("simulate " + q(plan_) + " --terrain flat --out " + q(sim_)).code;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  void SetUp() override {
    if (!dir_) GTEST_SKIP() << "node is not installed (apt-get install nodejs)";
    ASSERT_EQ(plan_code_, 0);
    ASSERT_EQ(sim_code_, 0);
  }
  static json read_json(const fs::path& p) {
    std::ifstream in(p);
    return json::parse(in);
  }
  // ScratchDir names itself after the running test, and none runs in SetUpTestSuite.
  struct TempDir {
    TempDir() {
      std::string t = (fs::temp_directory_path() / "terrastride_export_XXXXXX").string();
      path_ = ::mkdtemp(t.data()) ? fs::path(t) : fs::path();
    }
    ~TempDir() {
      std::error_code ec;
      if (!path_.empty()) fs::remove_all(path_, ec);
    }
    const fs::path& path() const { return path_; }
    fs::path path_;
  };
  static inline TempDir* dir_ = nullptr;
  static inline fs::path plan_, sim_;
  static inline int plan_code_ = -1, sim_code_ = -1;
};

TEST_F(ExportTest, PlanAndSimulationDecodeOnEveryChannelWithTheRightCounts) {
  for (const std::string compression : {"zstd", "none"}) {
    SCOPED_TRACE(compression);
    const fs::path out = dir_->path() / ("run_" + compression + ".mcap");
    const CommandResult r =
        run_terrastride("export --terrain flat --plan " + q(plan_) + " --sim " + q(sim_) +
                        " --compression " + compression + " --json --out " + q(out));
    ASSERT_EQ(r.code, 0) << r.all();
    const json summary = json::parse(r.out);
    const size_t plan_samples = read_json(plan_)["samples"].size();
    const size_t sim_samples = read_json(sim_)["samples"].size();
    ASSERT_GT(plan_samples, 100u);
    ASSERT_GT(sim_samples, 100u);
    const json expected{{"/terrain/grid", 1},
                        {"/terrain/voxels", 1},
                        {"/plan/footholds", 1},
                        {"/plan/base_path", 1},
                        {"/plan/shin_contacts", 1},
                        {"/plan/robot", plan_samples},
                        {"/plan/contact_forces", plan_samples},
                        {"/tf", plan_samples + sim_samples},
                        {"/sim/robot", sim_samples},
                        {"/sim/contact_forces", sim_samples}};
    const json check = read_back(out, expected);
    EXPECT_TRUE(check["ok"].get<bool>()) << check.dump(1);
    EXPECT_EQ(check["topics"], expected) << "every channel, and no other";
    EXPECT_EQ(check["compression"], json::array({compression}));
    EXPECT_EQ(summary["messages"], check["messages"]);
    EXPECT_GT(summary["footholds"].get<int>(), 4);  // each foot steps at least once
    EXPECT_GT(summary["voxels"].get<int>(), 0);
  }
}

TEST_F(ExportTest, TerrainAloneFromAMapFolder) {
  const fs::path terrain = dir_->path() / "terrain";
  ASSERT_EQ(run_terrastride("map " + shell_quote(std::string(TERRASTRIDE_TEST_DATA_DIR) +
                                                 "/scans/flat.pcd") +
                            " --out " + q(terrain))
                .code,
            0);
  const fs::path out = dir_->path() / "terrain.mcap";
  const CommandResult r = run_terrastride("export --terrain " + q(terrain) + " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, {{"/terrain/grid", 1}, {"/terrain/voxels", 1}});
  EXPECT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_EQ(check["topics"].size(), 2u);
}

TEST_F(ExportTest, BadInputsNameTheProblemAndWriteNothing) {
  const fs::path out = dir_->path() / "bad.mcap";
  std::ofstream(dir_->path() / "broken_sim.json") << "{\"samples\": [{\"t\": 0}]}";
  std::ofstream(dir_->path() / "broken_plan.json") << "{\"robot\": \"hyq\", \"samples\": 3}";
  struct Case {
    std::string args, words;
  };
  const std::vector<Case> cases = {
      {"--terrain flat --plan " + q(dir_->path() / "missing.json"), "missing.json"},
      {"--terrain flat --plan " + q(dir_->path() / "broken_plan.json"), "broken_plan.json"},
      {"--terrain stairs --plan " + q(plan_), "planned on terrain 'flat'"},
      {"--terrain flat --sim " + q(sim_), "give --plan"},
      {"--terrain flat --plan " + q(plan_) + " --sim " + q(dir_->path() / "broken_sim.json"),
       "broken_sim.json"},
      {"--terrain flat --compression lz4", "--compression"},
  };
  for (const Case& c : cases) {
    const CommandResult r = run_terrastride("export " + c.args + " --out " + q(out));
    EXPECT_EQ(r.code, 1) << c.args << "\n" << r.all();
    EXPECT_NE(r.err.find(c.words), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(out)) << c.args;
  }
  // Unwritable --out: a missing folder, a directory, not .mcap; checked before any work.
  for (const fs::path& bad : {dir_->path() / "no" / "x.mcap", dir_->path() / "adir.mcap",
                              dir_->path() / "x.txt"}) {
    fs::create_directories(dir_->path() / "adir.mcap");
    const CommandResult r =
        run_terrastride("export --terrain flat --plan " + q(plan_) + " --out " + q(bad));
    EXPECT_EQ(r.code, 1) << r.all();
    EXPECT_NE(r.err.find("--out"), std::string::npos) << r.err;
  }
  EXPECT_FALSE(fs::exists(dir_->path() / "x.txt"));
  EXPECT_TRUE(fs::is_empty(dir_->path() / "adir.mcap"));
}

}  // namespace
