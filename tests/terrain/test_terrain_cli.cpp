// `terrastride map`, `query` and `scan-sim` end to end, and their handling of bad input.
#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "support/run_command.hpp"

namespace fs = std::filesystem;

namespace {

using CliResult = terrastride::test_support::CommandResult;

CliResult run(const std::string& args) {
  return terrastride::test_support::run_terrastride(args);
}

class TerrainCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride_terrain_cli_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& name, const std::string& content) {
    std::ofstream(dir_ / name, std::ios::binary) << content;
    return (dir_ / name).string();
  }
  // A 1 m x 1 m plane at z = 0.3 sampled every 5 mm, and a 10 cm step at x = 0.5.
  std::string plane_xyz(bool step) {
    std::ostringstream os;
    for (int i = 0; i < 200; ++i)
      for (int j = 0; j < 200; ++j) {
        const double x = i * 0.005, y = j * 0.005;
        os << x << " " << y << " " << (0.3 + (step && x >= 0.5 ? 0.1 : 0.0)) << "\n";
      }
    return write(step ? "step.xyz" : "plane.xyz", os.str());
  }
  // Everything in the test directory except the named inputs: must be empty after a failure.
  std::vector<std::string> leftovers(const std::vector<std::string>& inputs) {
    std::vector<std::string> extra;
    for (const auto& e : fs::directory_iterator(dir_)) {
      const std::string name = e.path().filename().string();
      if (std::find(inputs.begin(), inputs.end(), name) == inputs.end()) extra.push_back(name);
    }
    return extra;
  }
  fs::path dir_;
};

}  // namespace

TEST_F(TerrainCli, MapThenQueryAPlaneWithAStep) {
  const std::string cloud = plane_xyz(true);
  const std::string out = (dir_ / "map").string();
  CliResult r = run("map " + cloud + " --origin 0.5,0.5,1.5 --foot-radius 0.02,0.05 --out " + out +
                    " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto summary = nlohmann::json::parse(r.out);
  EXPECT_EQ(summary["points_in"].get<size_t>(), 40000u);
  EXPECT_EQ(summary["safe"].size(), 2u);
  EXPECT_TRUE(summary["timings"].contains("total_s"));
  for (const char* f : {"terrain.json", "octomap.bt", "layers/elevation.npy", "layers/variance.npy",
                        "layers/min.npy", "layers/max.npy", "layers/count.npy",
                        "layers/observed.npy", "layers/safe_r20.npy", "layers/margin_r50.npy"})
    EXPECT_TRUE(fs::exists(fs::path(out) / f)) << f;
  r = run("query " + out + " --at 0.25,0.5 --at 0.75,0.5 --at 0.5,0.5");
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream lines(r.out);
  std::string line;
  std::vector<nlohmann::json> q;
  while (std::getline(lines, line)) q.push_back(nlohmann::json::parse(line));
  ASSERT_EQ(q.size(), 3u);
  for (const char* key : {"x", "y", "height", "gradient", "safe", "margin", "observed"})
    EXPECT_TRUE(q[0].contains(key)) << key;
  EXPECT_NEAR(q[0]["height"].get<double>(), 0.3, 0.005);
  EXPECT_NEAR(q[1]["height"].get<double>(), 0.4, 0.005);
  EXPECT_TRUE(q[0]["safe"].get<bool>());
  EXPECT_TRUE(q[1]["safe"].get<bool>());
  EXPECT_FALSE(q[2]["safe"].get<bool>());  // on the step edge
  EXPECT_LT(q[2]["margin"].get<double>(), 0.0);
  EXPECT_GT(q[2]["gradient"][0].get<double>(), 0.5);
  // Human summary names the figures. Without --origin the sensor is at the frame's origin, below
  // the plane: these world-frame points need z taken as up.
  r = run("map " + cloud + " --up z --out " + out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("kept after cleaning"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("safe for foot radius"), std::string::npos) << r.out;
}

// Across a safe/unsafe border `query` says margin > 0 exactly where it says safe (the cell's
// margin; the planner's interpolated one is field_margin), for points 1 mm apart over 20 cm.
TEST_F(TerrainCli, QueryMarginAgreesWithSafeAcrossCellBorders) {
  const std::string out = (dir_ / "map").string();
  CliResult r = run("map " + plane_xyz(true) + " --up z --foot-radius 0.02 --out " + out);
  ASSERT_EQ(r.code, 0) << r.err;
  std::string at;
  for (int k = 0; k <= 200; ++k) at += " --at " + std::to_string(0.4 + 0.001 * k) + ",0.5013";
  r = run("query " + out + at);
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream lines(r.out);
  std::string line;
  int points = 0, unsafe = 0;
  while (std::getline(lines, line)) {
    const auto q = nlohmann::json::parse(line);
    ++points;
    unsafe += !q["safe"].get<bool>();
    EXPECT_EQ(q["margin"].get<double>() > 0.0, q["safe"].get<bool>()) << line;
    if (!q["safe"].get<bool>()) {
      EXPECT_TRUE(q.contains("unsafe_because")) << line;
    }
    EXPECT_TRUE(q.contains("field_margin") && q.contains("overhead")) << line;
    EXPECT_TRUE(q["overhead"].is_null()) << line;  // nothing overhead on a plane
  }
  EXPECT_EQ(points, 201);
  EXPECT_GT(unsafe, 0);
}

TEST_F(TerrainCli, OctoMapMaxRangeCutsLongRays) {
  // Sensor 1.2 m above the middle of the plane: the plane's corners are ~1.39 m away.
  const std::string cloud = plane_xyz(false);
  // The plane z = 0.3 lies on a 5 cm voxel border: look just above and below it.
  const auto occupied = [](const std::string& bt, double x, double y, double z) {
    octomap::OcTree tree(bt);
    for (double dz : {-0.01, 0.01}) {
      const octomap::OcTreeNode* n = tree.search(x, y, z + dz);
      if (n != nullptr && tree.isNodeOccupied(n)) return true;
    }
    return false;
  };
  const std::string full = (dir_ / "full").string(), cut = (dir_ / "cut").string();
  CliResult r = run("map " + cloud + " --origin 0.5,0.5,1.5 --out " + full + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  r = run("map " + cloud + " --origin 0.5,0.5,1.5 --octomap-max-range 1.3 --out " + cut +
          " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream meta(fs::path(cut) / "terrain.json");
  EXPECT_DOUBLE_EQ(nlohmann::json::parse(meta)["octomap"]["max_range"].get<double>(), 1.3);
  EXPECT_TRUE(occupied(full + "/octomap.bt", 0.5, 0.5, 0.3));  // 1.2 m: a hit either way
  EXPECT_TRUE(occupied(cut + "/octomap.bt", 0.5, 0.5, 0.3));
  EXPECT_TRUE(occupied(full + "/octomap.bt", 0.02, 0.02, 0.3));  // 1.39 m: cut off
  EXPECT_FALSE(occupied(cut + "/octomap.bt", 0.02, 0.02, 0.3));
  // The height grid does not depend on it.
  r = run("query " + cut + " --at 0.05,0.05");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NEAR(nlohmann::json::parse(r.out)["height"].get<double>(), 0.3, 0.005);
  r = run("map --help");
  EXPECT_NE(r.out.find("--octomap-max-range"), std::string::npos) << r.out;
}

// Clouds are cleaned in parallel and the OctoMap is built beside the height grid: the output must
// not depend on the scheduling, and a failure must name the same cloud as a sequential run would.
TEST_F(TerrainCli, ParallelStagesAreDeterministic) {
  const std::string pcd = (dir_ / "scan.pcd").string();
  ASSERT_EQ(run("scan-sim --scene eur_pallet --poses 3 --seed 5 --out " + pcd).code, 0);
  const std::string clouds =
      pcd + " " + (dir_ / "scan.1.pcd").string() + " " + (dir_ / "scan.2.pcd").string();
  const auto slurp = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  std::vector<std::string> outs;
  for (int k = 0; k < 3; ++k) {
    outs.push_back((dir_ / ("map" + std::to_string(k))).string());
    const CliResult r = run("map " + clouds + " --out " + outs.back());
    ASSERT_EQ(r.code, 0) << r.err;
  }
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(outs[0])) {
    if (!e.is_regular_file() || e.path().filename() == "terrain.json") continue;  // has timings
    const fs::path rel = fs::relative(e.path(), outs[0]);
    for (int k = 1; k < 3; ++k)
      EXPECT_EQ(slurp(e.path()), slurp(fs::path(outs[k]) / rel)) << rel << " differs in run " << k;
    ++files;
  }
  EXPECT_GE(files, 10u);
  // Every cloud fails to clean (a voxel far too small): the error names the first one.
  const std::string a = plane_xyz(false), b = plane_xyz(true);
  const CliResult r =
      run("map " + a + " " + b + " --up z --voxel 1e-7 --out " + (dir_ / "bad").string());
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("plane.xyz"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("step.xyz"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
}

TEST_F(TerrainCli, ScanSimThenMapThePallet) {
  const std::string pcd = (dir_ / "pallet.pcd").string();
  CliResult r = run("scan-sim --scene pallet_15 --poses 2 --seed 3 --out " + pcd + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto s = nlohmann::json::parse(r.out);
  ASSERT_EQ(s["files"].size(), 2u);
  EXPECT_TRUE(fs::exists(dir_ / "pallet.pcd"));
  EXPECT_TRUE(fs::exists(dir_ / "pallet.1.pcd"));
  const std::string out = (dir_ / "map").string();
  r = run("map " + pcd + " " + (dir_ / "pallet.1.pcd").string() + " --out " + out);
  ASSERT_EQ(r.code, 0) << r.err;
  r = run("query " + out + " --at 1.1,0.0 --at 0.3,0.0");
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream lines(r.out);
  std::string a, b;
  std::getline(lines, a);
  std::getline(lines, b);
  EXPECT_NEAR(nlohmann::json::parse(a)["height"].get<double>(), 0.15, 0.01);
  EXPECT_NEAR(nlohmann::json::parse(b)["height"].get<double>(), 0.0, 0.01);
  r = run("scan-sim --scene palette --out " + pcd);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("palette"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("eur_pallet"), std::string::npos) << r.err;
  r = run("scan-sim --scene flat --out " + (dir_ / "x.txt").string());
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find(".pcd"), std::string::npos) << r.err;
}

TEST_F(TerrainCli, BadInputFailsCleanlyAndWritesNothing) {
  const std::string good = plane_xyz(false);
  const std::string out = (dir_ / "map").string();
  struct Case {
    std::string args, expect;
  };
  const std::string empty = write("empty.xyz", "");
  const std::string nan = write("nan.xyz", "nan nan nan\nnan 1 2\n");
  const std::string inf = write("inf.xyz", "inf 0 0\n0 -inf 0\n");
  const std::string garbage = write("garbage.pcd", "this is not a point cloud\n\x01\x02");
  const std::string fake_npy = write("fake.npy", "0 0 0\n1 1 1\n");
  const std::vector<Case> cases = {
      {"map " + empty + " --out " + out, "empty.xyz"},
      {"map " + nan + " --out " + out, "nan.xyz"},
      {"map " + inf + " --out " + out, "inf.xyz"},
      {"map " + garbage + " --out " + out, "garbage.pcd"},
      {"map " + fake_npy + " --out " + out, "fake.npy"},
      {"map " + (dir_ / "missing.pcd").string() + " --out " + out, "missing.pcd"},
      {"map " + good + " --resolution 0 --out " + out, "--resolution"},
      {"map " + good + " --resolution 1e-6 --out " + out, "--resolution"},
      {"map " + good + " --resolution 100 --out " + out, "--resolution"},
      {"map " + good + " --resolution nan --out " + out, "resolution"},
      {"map " + good + " --foot-radius -0.1 --out " + out, "--foot-radius"},
      {"map " + good + " --origin 1,2 --out " + out, "--origin"},
      {"map " + good + " --octomap-max-range -1 --out " + out, "--octomap-max-range"},
      {"map " + good + " --octomap-max-range nan --out " + out, "--octomap-max-range"},
      {"map " + good + " --octomap-max-range inf --out " + out, "--octomap-max-range"},
      {"map " + good + " --out " + (dir_ / "no" / "such" / "dir").string(), "--out"},
  };
  for (const auto& c : cases) {
    const CliResult r = run(c.args);
    EXPECT_NE(r.code, 0) << c.args;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_TRUE(r.out.empty()) << c.args << "\n" << r.out;
    EXPECT_FALSE(fs::exists(out)) << c.args;
    const auto extra =
        leftovers({"plane.xyz", "empty.xyz", "nan.xyz", "inf.xyz", "garbage.pcd", "fake.npy"});
    EXPECT_TRUE(extra.empty()) << c.args << ": left " << extra.front();
  }
  // A failed map must not clobber an existing good one.
  ASSERT_EQ(run("map " + good + " --up z --out " + out).code, 0);  // world frame, z up
  const auto before = fs::last_write_time(fs::path(out) / "terrain.json");
  EXPECT_NE(run("map " + nan + " --out " + out).code, 0);
  EXPECT_EQ(fs::last_write_time(fs::path(out) / "terrain.json"), before);
  // Query: outside the map (names the point, prints nothing), bad point, not a terrain dir.
  CliResult r = run("query " + out + " --at 0.5,0.5 --at 7,8");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("7,8"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("outside the map"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
  r = run("query " + out + " --at 0.5");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--at"), std::string::npos) << r.err;
  r = run("query " + dir_.string() + " --at 0.5,0.5");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("terrain.json"), std::string::npos) << r.err;
  // A mislabeled layer: elevation.npy replaced by a text file.
  std::ofstream(fs::path(out) / "layers" / "elevation.npy") << "not an npy";
  r = run("query " + out + " --at 0.5,0.5");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("elevation.npy"), std::string::npos) << r.err;
}
