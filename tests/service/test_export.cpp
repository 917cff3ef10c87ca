// `terrastride export`: the MCAP file is read back by an independent reader, @mcap/core
// (tests/service/mcap_check.js, service/report's Node toolchain), which decodes every message of
// every channel, checks it against the Foxglove schema the file carries, validates the CRCs and
// compares the message counts with what the plan and the simulation hold.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include <octomap/OcTree.h>
#include <algorithm>
#include <cmath>
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
  const CommandResult r = run_command("node " + shell_quote(script) + " " + q(mcap) + " " +
                                      shell_quote(expected.dump()));
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
                        {"/terrain/relief", 1},
                        {"/plan/footholds", 1},
                        {"/plan/base_path", 1},
                        {"/plan/shin_contacts", 1},
                        {"/plan/robot", plan_samples},
                        {"/plan/contact_forces", plan_samples},
                        {"/plan/joints", plan_samples},
                        {"/plan/feet", plan_samples},
                        {"/plan/verdict", 2},
                        {"/tf", plan_samples + sim_samples},
                        {"/sim/robot", sim_samples},
                        {"/sim/contact_forces", sim_samples},
                        {"/sim/joints", sim_samples},
                        {"/sim/feet", sim_samples},
                        {"/sim/tracking", sim_samples},
                        {"/sim/verdict", 2}};
    const json check = read_back(out, expected);
    ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
    json topics = check["topics"];
    EXPECT_GT(topics["/terrain/voxels"].get<int>(), 0);
    EXPECT_GT(topics["/log"].get<int>(), 1);  // the checks' verdict and the simulation's
    topics.erase("/terrain/voxels");
    topics.erase("/log");
    EXPECT_EQ(topics, expected) << "every channel, and no other";
    EXPECT_EQ(check["compression"], json::array({compression}));
    EXPECT_EQ(summary["messages"], check["messages"]);
    EXPECT_GT(summary["footholds"].get<int>(), 4);  // each foot steps at least once
    EXPECT_EQ(check["cubes"]["/terrain/voxels"], summary["voxels"]);
    EXPECT_LE(check["largest"]["bytes"].get<size_t>(), 3500000u);
    // The legs' frames, planned and simulated, below map.
    for (const std::string leg : {"LF", "RF", "LH", "RH"})
      for (const std::string link : {"_hip", "_thigh", "_shin"}) {
        const json& frames = check["frames"];
        EXPECT_NE(std::find(frames.begin(), frames.end(), leg + link), frames.end()) << leg + link;
        EXPECT_NE(std::find(frames.begin(), frames.end(), "sim_" + leg + link), frames.end());
      }
    // The links placed by /tf: each planned foot's sphere (in its shin's frame) lands on the
    // plan's first foot positions, and the simulated robot's on the simulation's.
    const json first_plan = read_json(plan_)["samples"][0]["feet"];
    const json first_sim = read_json(sim_)["samples"][0]["feet"];
    for (const auto& [topic, feet] :
         {std::pair{"/plan/robot", first_plan}, {"/sim/robot", first_sim}})
      for (const json& foot : feet) {
        double nearest = 1e9;
        for (const json& sp : check["robot_spheres"][topic])
          nearest = std::min(nearest,
                             std::hypot(sp[0].get<double>() - foot["position"][0].get<double>(),
                                        sp[1].get<double>() - foot["position"][1].get<double>(),
                                        sp[2].get<double>() - foot["position"][2].get<double>()));
        EXPECT_LT(nearest, 1e-3) << topic << " " << foot["position"];
      }
    // The numbers: the joints' worst torque ratio is the checks' torque_ratio_max; forces and
    // margins are there for every foot; the clock starts at the stated epoch.
    const json& n = check["numbers"];
    double worst = 0.0;
    for (const std::string leg : {"LF", "RF", "LH", "RH"}) {
      for (const std::string joint : {"haa", "hfe", "kfe"})
        worst = std::max(worst,
                         n["/plan/joints." + leg + "." + joint + ".torque_ratio"][1].get<double>());
      EXPECT_GT(n["/plan/feet." + leg + ".normal_force"][1].get<double>(), 100.0) << leg;
      EXPECT_TRUE(n.contains("/plan/feet." + leg + ".friction_margin")) << leg;
      EXPECT_TRUE(n.contains("/plan/feet." + leg + ".polytope_margin")) << leg;
      EXPECT_TRUE(n.contains("/sim/joints." + leg + ".kfe.torque")) << leg;
    }
    EXPECT_NEAR(worst, n["/plan/verdict.torque_ratio_max"][1].get<double>(), 1e-9);
    EXPECT_LT(n["/sim/tracking.position_error_norm"][1].get<double>(), 0.05);
    EXPECT_EQ(check["start_ns"], "1735689600000000000");
  }
}

TEST_F(ExportTest, TerrainAloneFromAMapFolder) {
  const fs::path terrain = dir_->path() / "terrain";
  ASSERT_EQ(run_terrastride(
                "map " + shell_quote(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/flat.pcd") +
                " --out " + q(terrain))
                .code,
            0);
  const fs::path out = dir_->path() / "terrain.mcap";
  const CommandResult r = run_terrastride("export --terrain " + q(terrain) + " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, {{"/terrain/grid", 1}, {"/terrain/relief", 1}});
  EXPECT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  // The grid, the relief, the voxels, the cloud the map was built from (its file is still there)
  // and the frame of the sensor that took it.
  EXPECT_EQ(check["topics"].size(), 5u) << check["topics"];
  EXPECT_EQ(check["frames"], json::array({"sensor_0"}));
  EXPECT_GT(check["points"]["/terrain/points"].get<int>(), 1000);
  EXPECT_GT(check["topics"]["/terrain/voxels"].get<int>(), 0);
  // The flat scan's relief: merged into far fewer triangles than two per cell, and all there.
  const json summary = json::parse(
      run_terrastride("export --terrain " + q(terrain) + " --json --out " + q(out)).out);
  EXPECT_EQ(check["triangles"]["/terrain/relief"], summary["relief_triangles"]);
  EXPECT_GT(summary["relief_triangles"].get<int>(), 0);
  EXPECT_LT(summary["relief_triangles"].get<size_t>(), summary["relief_cells"].get<size_t>());
  // The layout beside the file: a 3-D panel, the log.
  const json layout = read_json(dir_->path() / "terrain.layout.json");
  EXPECT_TRUE(layout["configById"].contains("3D!scene"));
  EXPECT_TRUE(layout["configById"].contains("Log!log"));
}

// A plan whose forces the legs cannot hold: the checks' findings are log messages at their time
// (a warning at the first sample each joint passes its limit, errors for the failed checks) and
// the verdict topic says it failed.
TEST_F(ExportTest, FindingsAreLogMessagesAtTheirTime) {
  json plan = read_json(plan_);
  for (json& s : plan["samples"])
    for (json& f : s["feet"])
      for (json& c : f["force"]) c = 4.0 * c.get<double>();
  const fs::path heavy = dir_->path() / "heavy_plan.json", out = dir_->path() / "heavy.mcap";
  std::ofstream(heavy) << plan.dump();
  const CommandResult r =
      run_terrastride("export --terrain flat --plan " + q(heavy) + " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, json::object());
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_EQ(check["numbers"]["/plan/verdict.passed"], json::array({0, 0}));
  int over_limit = 0, errors = 0;
  const double start = 1735689600.0, end = start + plan["samples"].back()["t"].get<double>();
  for (const json& log : check["logs"]) {
    const std::string text = log["message"];
    if (text.find("x its limit") != std::string::npos) {
      ++over_limit;
      EXPECT_EQ(log["level"], 3);
      EXPECT_GE(log["t"].get<double>(), start);
      EXPECT_LE(log["t"].get<double>(), end + 1e-6);
    }
    if (log["level"] == 4) ++errors;
  }
  EXPECT_GT(over_limit, 0) << check["logs"];
  EXPECT_GT(errors, 0) << check["logs"];  // the failed torque check
}

// A grid too large for one message is coarsened (a cell keeps the lowest margin of those it
// covers), and the relief of the same cells, tiled, stays under the budget.
TEST_F(ExportTest, FineGridIsCoarsenedUnderTheBudget) {
  const fs::path out = dir_->path() / "fine.mcap";
  const CommandResult r =
      run_terrastride("export --terrain pallet_15 --resolution 0.004 --json --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json summary = json::parse(r.out);
  EXPECT_EQ(summary["grid_decimation"], 2);
  const json check = read_back(out, {{"/terrain/grid", 1}});
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_LE(check["largest"]["bytes"].get<size_t>(), 3500000u);
  EXPECT_EQ(check["triangles"]["/terrain/relief"], summary["relief_triangles"]);
  // The coarse grid keeps the box's top (15 cm) and its unsafe edges (a margin below zero).
  const json& fields = check["grids"]["/terrain/grid"];
  EXPECT_NEAR(fields["height"][1].get<double>(), 0.15, 1e-3) << fields;
  bool unsafe = false;
  for (const auto& [name, range] : fields.items())
    if (name.rfind("margin_r", 0) == 0) unsafe = unsafe || range[0].get<double>() < 0;
  EXPECT_TRUE(unsafe) << fields;
}

// A map folder's cloud is drawn where the map put it: a --sensor-pose 5 m along x from the file's
// own VIEWPOINT moves the points there, not back to the VIEWPOINT.
TEST_F(ExportTest, MapFolderCloudsArePlacedAsTheMapPlacedThem) {
  const fs::path terrain = dir_->path() / "moved_terrain", out = dir_->path() / "moved.mcap";
  const std::string cloud = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/flat.pcd";
  // flat.pcd's VIEWPOINT is -1 0 0.8, pitched 40 degrees down.
  ASSERT_EQ(
      run_terrastride("map " + shell_quote(cloud) +
                      " --sensor-pose 4,0,0.8,0,0.342020143,0,0.939692621 --out " + q(terrain))
          .code,
      0);
  const CommandResult r = run_terrastride("export --terrain " + q(terrain) + " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, {{"/terrain/points", 1}});
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  const json& box = check["point_boxes"]["/terrain/points"];
  EXPECT_GT(box[0].get<double>(), 4.0) << box;  // the VIEWPOINT would put them from x = -0.7
  EXPECT_NEAR(box[2].get<double>(), 0.0, 0.03) << box;
  EXPECT_NEAR(box[5].get<double>(), 0.0, 0.03) << box;
  EXPECT_TRUE(check["logs"].empty()) << check["logs"];
}

// A plan's layout plots fields that exist in the file.
TEST_F(ExportTest, LayoutPlotsFieldsTheFileHolds) {
  const fs::path out = dir_->path() / "layout.mcap", layout = dir_->path() / "my_layout.json";
  const CommandResult r = run_terrastride("export --terrain flat --plan " + q(plan_) + " --sim " +
                                          q(sim_) + " --layout " + q(layout) + " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, json::object());
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  const json l = read_json(layout);
  int plotted = 0;
  for (const auto& [id, panel] : l["configById"].items()) {
    if (id.rfind("Plot!", 0) != 0) continue;
    for (const json& path : panel["paths"]) {
      EXPECT_TRUE(check["numbers"].contains(path["value"].get<std::string>())) << path["value"];
      ++plotted;
    }
  }
  EXPECT_GT(plotted, 10);
  EXPECT_FALSE(fs::exists(dir_->path() / "layout.layout.json"));
}

// A map built from a recording: the clock is the recording's, the clouds are re-read from the bag
// (decimated to --max-points), and the sensor's poses are frames.
TEST_F(ExportTest, BagMapKeepsTheRecordingsTimeCloudsAndSensorFrames) {
  const std::string bag = std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/bags/scan.bag";
  const fs::path terrain = dir_->path() / "bag_terrain";
  ASSERT_EQ(run_terrastride("map " + shell_quote(bag) + " --topic /points --frame odom --out " +
                            q(terrain))
                .code,
            0);
  const fs::path out = dir_->path() / "bag.mcap";
  CommandResult r = run_terrastride("export --terrain " + q(terrain) +
                                    " --bag-frame odom --max-points 1000 --json --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  json summary = json::parse(r.out);
  EXPECT_NEAR(summary["epoch_s"].get<double>(), 1700000000.013, 1e-6);  // the first cloud's stamp
  EXPECT_GT(summary["points_in"].get<int>(), 3000);
  EXPECT_GT(summary["points"].get<int>(), 100);
  EXPECT_LE(summary["points"].get<int>(), 1000);
  json check = read_back(out, {{"/terrain/points", 1}, {"/tf", 10}});  // 9 clouds + the frames
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_EQ(check["points"]["/terrain/points"], summary["points"]);
  EXPECT_EQ(check["start_ns"], "1700000000013000000");
  EXPECT_EQ(check["end_ns"], "1700000001613000000");  // the last cloud
  for (const std::string f : {"sensor", "sensor_0", "sensor_8"}) {
    const json& frames = check["frames"];
    EXPECT_NE(std::find(frames.begin(), frames.end(), f), frames.end()) << f;
  }
  // --start-time moves the clock; without --bag-frame the points are not read.
  r = run_terrastride("export --terrain " + q(terrain) + " --start-time 1000 --json --out " +
                      q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  check = read_back(out, json::object());
  EXPECT_EQ(check["start_ns"], "1000000000000");
  EXPECT_EQ(check["end_ns"], "1001600000000");  // the sensor's last pose, 1.6 s in
  EXPECT_FALSE(check["topics"].contains("/terrain/points"));
}

// geb079 (a building floor, 143 729 occupied voxels): every voxel drawn, no message above 4 MB.
TEST_F(ExportTest, LargeOctomapStaysUnderTheMessageBudgetWithEveryVoxel) {
  const fs::path bt =
      fs::path(TERRASTRIDE_SOURCE_DIR) / ".." / "shared" / "scans" / "octomap" / "geb079.bt";
  if (!fs::exists(bt)) GTEST_SKIP() << bt << " is absent (the shared scans)";
  octomap::OcTree tree(bt.string());
  size_t occupied = 0;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it)
    if (tree.isNodeOccupied(*it)) ++occupied;
  const fs::path out = dir_->path() / "geb079.mcap";
  const CommandResult r = run_terrastride("export --terrain " + q(bt) + " --json --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json check = read_back(out, json::object());
  ASSERT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_LE(check["largest"]["bytes"].get<size_t>(), 4000000u) << check["largest"];
  EXPECT_EQ(check["cubes"]["/terrain/voxels"].get<size_t>(), occupied);
  EXPECT_GT(check["topics"]["/terrain/voxels"].get<int>(), 1);
  EXPECT_TRUE(check["topics"].contains("/terrain/overhead"));
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
      {"--terrain flat --start-time -5", "--start-time"},
      {"--terrain " +
           shell_quote(std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/bags/scan.bag"),
       "mapped first"},
      {"--terrain flat --layout " + q(dir_->path() / "layout.txt"), "--layout"},
  };
  for (const Case& c : cases) {
    const CommandResult r = run_terrastride("export " + c.args + " --out " + q(out));
    EXPECT_EQ(r.code, 1) << c.args << "\n" << r.all();
    EXPECT_NE(r.err.find(c.words), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(out)) << c.args;
  }
  // Unwritable --out: a missing folder, a directory, not .mcap; checked before any work.
  for (const fs::path& bad :
       {dir_->path() / "no" / "x.mcap", dir_->path() / "adir.mcap", dir_->path() / "x.txt"}) {
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

namespace {
// The exports people open first, read back by the independent reader: the demo's folder (the
// shipped pallet scan, its plan) and pallet_15 with `all` and its execution in MuJoCo.
TEST_F(ExportTest, TheDemoAndThePallet15AllRunWithItsSimulationValidate) {
  const fs::path demo = dir_->path() / "demo";
  CommandResult r = run_terrastride("demo --out " + q(demo));
  ASSERT_EQ(r.code, 0) << r.all();
  const fs::path demo_mcap = dir_->path() / "demo.mcap";
  r = run_terrastride("export --terrain " + q(demo / "terrain") + " --plan " +
                      q(demo / "plan.json") + " --out " + q(demo_mcap));
  ASSERT_EQ(r.code, 0) << r.all();
  json check = read_back(demo_mcap, {{"/terrain/grid", 1}});
  EXPECT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_LE(check["largest"]["bytes"].get<size_t>(), 3500000u);

  const fs::path plan = dir_->path() / "p15.json", sim = dir_->path() / "p15_sim.json";
  r = run_terrastride("plan --terrain pallet_15 --constraints all --out " + q(plan));
  ASSERT_EQ(r.code, 0) << r.all();
  r = run_terrastride("simulate " + q(plan) + " --terrain pallet_15 --out " + q(sim));
  ASSERT_EQ(r.code, 0) << r.all();
  const fs::path p15_mcap = dir_->path() / "p15.mcap";
  r = run_terrastride("export --terrain pallet_15 --plan " + q(plan) + " --sim " + q(sim) +
                      " --out " + q(p15_mcap));
  ASSERT_EQ(r.code, 0) << r.all();
  check = read_back(p15_mcap, {{"/terrain/grid", 1}});
  EXPECT_TRUE(check["ok"].get<bool>()) << check.dump(1);
  EXPECT_LE(check["largest"]["bytes"].get<size_t>(), 3500000u);
}
}  // namespace
