// Clouds as sensors record them, end to end through `terrastride scan-sim` and `map`: points in a
// camera's frame with its pose (VIEWPOINT, --sensor-pose, --poses) map as the same points in the
// world frame; without a pose, a cloud whose dominant plane is not level is refused, or levelled
// by --up auto; and bad poses are refused naming the option or line.
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Dense>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/npy.hpp"

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::test_support::CommandResult;
using terrastride::test_support::shell_quote;

namespace {

CommandResult run(const std::string& args) {
  return terrastride::test_support::run_terrastride(args);
}

// A map folder's elevation and observed layers and its grid.
struct Layers {
  json grid;
  std::vector<double> elevation;
  std::vector<uint8_t> observed;
};

std::vector<double> as_doubles(const terrastride::perception::NpyArray& a) {
  std::vector<double> v;
  const size_t n = a.dtype == "<f8"   ? a.bytes.size() / 8
                   : a.dtype == "<f4" ? a.bytes.size() / 4
                                      : a.bytes.size();
  for (size_t i = 0; i < n; ++i) {
    if (a.dtype == "<f8") {
      double d;
      std::memcpy(&d, a.bytes.data() + 8 * i, 8);
      v.push_back(d);
    } else if (a.dtype == "<f4") {
      float f;
      std::memcpy(&f, a.bytes.data() + 4 * i, 4);
      v.push_back(f);
    } else {
      v.push_back(static_cast<uint8_t>(a.bytes[i]));
    }
  }
  return v;
}

Layers load_layers(const fs::path& dir) {
  Layers l;
  std::ifstream in(dir / "terrain.json");
  l.grid = json::parse(in)["grid"];
  l.elevation =
      as_doubles(terrastride::perception::read_npy((dir / "layers/elevation.npy").string()));
  for (double v :
       as_doubles(terrastride::perception::read_npy((dir / "layers/observed.npy").string())))
    l.observed.push_back(v != 0);
  return l;
}

// The largest elevation difference over the cells either map observed; +inf when the grids or
// the observed cells differ.
double max_difference(const Layers& a, const Layers& b, size_t* observed = nullptr) {
  if (a.grid["nx"] != b.grid["nx"] || a.grid["ny"] != b.grid["ny"]) return INFINITY;
  for (int k = 0; k < 2; ++k)
    if (std::abs(a.grid["origin"][k].get<double>() - b.grid["origin"][k].get<double>()) > 1e-9)
      return INFINITY;
  double worst = 0;
  size_t n = 0;
  for (size_t i = 0; i < a.elevation.size(); ++i) {
    if (a.observed[i] != b.observed[i]) return INFINITY;
    if (!a.observed[i]) continue;
    ++n;
    worst = std::max(worst, std::abs(a.elevation[i] - b.elevation[i]));
  }
  if (observed) *observed = n;
  return n == 0 ? INFINITY : worst;
}

std::string numbers(const json& values) {
  std::ostringstream os;
  os.precision(17);
  for (size_t i = 0; i < values.size(); ++i) os << (i ? "," : "") << values[i].get<double>();
  return os.str();
}

class SensorFramesCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride_sensor_frames_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  // One simulated scan (one pose) of `scene`; returns scan-sim's JSON entry for the file.
  json scan(const std::string& name, const std::string& args,
            const std::string& scene = "pallet_10") {
    const CommandResult r = run("scan-sim --scene " + scene + " --poses 1 --out " +
                                shell_quote(path(name)) + " --json " + args);
    EXPECT_EQ(r.code, 0) << r.err;
    return json::parse(r.out)["files"][0];
  }
  // `map` into DIR; returns the result.
  CommandResult map(const std::string& inputs, const std::string& out,
                    const std::string& args = "") {
    return run("map " + inputs + " --out " + shell_quote(path(out)) + " --json " + args);
  }
  Layers layers(const std::string& out) const { return load_layers(dir_ / out); }

  // The points of a PCD as its file holds them (the sensor frame), written as XYZ, NPY or PLY.
  void convert(const std::string& pcd, const std::string& to, bool with_nans = false) {
    const auto file = terrastride::perception::read_cloud_file(path(pcd));
    const std::string ext = fs::path(to).extension().string();
    if (ext == ".npy") {
      std::vector<float> flat;
      for (const auto& p : file.points) flat.insert(flat.end(), {p.x(), p.y(), p.z()});
      terrastride::perception::write_npy(path(to), flat.data(), file.points.size(), 3);
      return;
    }
    std::ofstream out(path(to));
    out.precision(9);
    if (ext == ".ply")
      out << "ply\nformat ascii 1.0\nelement vertex " << file.points.size()
          << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (size_t i = 0; i < file.points.size(); ++i) {
      const auto& p = file.points[i];
      out << p.x() << " " << p.y() << " " << p.z() << "\n";
      if (with_nans && i % 100 == 0) out << "nan nan nan\n";
    }
  }
  fs::path dir_;
};

// A world-frame scan mapped with its sensor origin: what every posed camera-frame copy of the
// same points must reproduce.
struct Reference {
  json entry;
  Layers layers;
};

TEST_F(SensorFramesCli, CameraFramesWithTheirPosesMapAsTheWorldFrame) {
  struct Pose {
    const char* name;
    std::string args;
    bool all_formats;
  };
  const std::vector<Pose> poses = {
      {"pitch45", "--pitch 45", true},
      {"yaw_roll", "--pitch 35 --yaw 30 --roll 10", false},
      {"down", "--pitch 90 --height 1.2", false},
      {"upside_down", "--pitch 40 --roll 180", false},
  };
  for (const Pose& pose : poses) {
    SCOPED_TRACE(pose.name);
    const std::string tag = pose.name;
    const json world = scan(tag + "_world.pcd", pose.args + " --frame world");
    ASSERT_FALSE(world["viewpoint"].get<bool>());
    const CommandResult ref_run = map(shell_quote(path(tag + "_world.pcd")), tag + "_ref",
                                      "--origin " + numbers(world["origin"]));
    ASSERT_EQ(ref_run.code, 0) << ref_run.err;
    const Layers ref = layers(tag + "_ref");
    const auto expect_same = [&](const std::string& out, const std::string& what) {
      size_t observed = 0;
      const double diff = max_difference(ref, layers(out), &observed);
      EXPECT_LE(diff, 1e-3) << what << ": " << observed << " observed cells";
      EXPECT_GT(observed, 100u) << what;
    };

    // The camera's optical frame with its pose as VIEWPOINT, and its body frame (the default).
    const json optical = scan(tag + "_opt.pcd", pose.args + " --frame optical");
    CommandResult r = map(shell_quote(path(tag + "_opt.pcd")), tag + "_opt");
    ASSERT_EQ(r.code, 0) << r.err;
    expect_same(tag + "_opt", "optical PCD with VIEWPOINT");
    EXPECT_EQ(json::parse(r.out)["inputs"][0]["pose"]["source"], "viewpoint");
    scan(tag + "_body.pcd", pose.args);
    ASSERT_EQ(map(shell_quote(path(tag + "_body.pcd")), tag + "_body").code, 0);
    expect_same(tag + "_body", "body-frame PCD with VIEWPOINT");

    // The same optical-frame points with the pose on the command line and in a poses file.
    const std::string sensor_pose = numbers(optical["pose"]);
    std::vector<std::string> formats = {".xyz"};
    if (pose.all_formats) formats = {".pcd", ".ply", ".xyz", ".npy"};
    std::ofstream poses_file(path(tag + "_poses.txt"));
    poses_file << "# optical-frame copies\n";
    for (const std::string& ext : formats) {
      const std::string file = tag + "_bare" + ext;
      if (ext == ".pcd") {
        scan(file, pose.args + " --frame optical --no-viewpoint");
      } else {
        convert(tag + "_opt.pcd", file, ext == ".xyz");
      }
      poses_file << file << " " << std::regex_replace(sensor_pose, std::regex(","), " ") << "\n";
      r = map(shell_quote(path(file)), tag + "_sp" + ext, "--sensor-pose " + sensor_pose);
      ASSERT_EQ(r.code, 0) << r.err;
      expect_same(tag + "_sp" + ext, "--sensor-pose " + ext);
    }
    poses_file.close();
    for (size_t k = 0; k < formats.size(); ++k) {
      const std::string& ext = formats[k];
      r = map(shell_quote(path(tag + "_bare" + ext)), tag + "_pf" + ext,
              "--poses " + shell_quote(path(tag + "_poses.txt")));
      ASSERT_EQ(r.code, 0) << r.err;
      expect_same(tag + "_pf" + ext, "--poses " + ext);
      EXPECT_EQ(json::parse(r.out)["inputs"][0]["pose"]["poses_line"], 2 + k);  // after the comment
    }
    // The body's pose with --sensor-frame optical: the optical rotation composed on it.
    const json body = scan(tag + "_body2.pcd", pose.args);
    r = map(shell_quote(path(tag + "_bare.xyz")), tag + "_body_opt",
            "--sensor-frame optical --sensor-pose " + numbers(body["pose"]));
    ASSERT_EQ(r.code, 0) << r.err;
    expect_same(tag + "_body_opt", "--sensor-frame optical with the body's pose");
  }
}

// A least-squares plane through the observed cells' elevations: its tilt in degrees.
double floor_tilt_deg(const Layers& l) {
  const int nx = l.grid["nx"], ny = l.grid["ny"];
  const double res = l.grid["resolution"];
  std::vector<Eigen::Vector3d> rows;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      if (l.observed[i * ny + j]) rows.emplace_back(i * res, j * res, l.elevation[i * ny + j]);
  Eigen::MatrixXd a(rows.size(), 3);
  Eigen::VectorXd b(rows.size());
  for (size_t k = 0; k < rows.size(); ++k) {
    a.row(k) << rows[k].x(), rows[k].y(), 1.0;
    b[k] = rows[k].z();
  }
  const Eigen::Vector3d c = a.colPivHouseholderQr().solve(b);
  return std::atan(std::hypot(c[0], c[1])) * 180 / M_PI;
}

TEST_F(SensorFramesCli, CameraFrameWithoutPoseIsRefusedOrLevelled) {
  // Pitched 45 deg down, the optical frame's z (depth) points 45 deg below the horizon and its y
  // (down) 45 deg behind the vertical: world up is (0, -0.71, -0.71) there, 135 deg from z.
  scan("cam.pcd", "--pitch 45 --frame optical --no-viewpoint", "flat");
  CommandResult r = map(shell_quote(path("cam.pcd")), "refused");
  EXPECT_NE(r.code, 0);
  EXPECT_FALSE(fs::exists(path("refused")));
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.err, m, std::regex("tilted ([0-9.]+) deg"))) << r.err;
  EXPECT_NEAR(std::stod(m[1]), 135.0, 1.0) << r.err;
  for (const char* fix : {"--up auto", "--sensor-pose", "--up z", "optical"})
    EXPECT_NE(r.err.find(fix), std::string::npos) << fix << " in " << r.err;

  r = map(shell_quote(path("cam.pcd")), "levelled", "--up auto");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_LT(floor_tilt_deg(layers("levelled")), 1.0);
  std::ifstream in(path("levelled/terrain.json"));
  const json up = json::parse(in)["inputs"][0]["up"];
  EXPECT_NEAR(up["tilt_deg"].get<double>(), 135.0, 1.0) << up;
  EXPECT_NEAR(up["sensor_height"].get<double>(), 0.8, 0.02) << up;
  EXPECT_GT(up["inlier_share"].get<double>(), 0.5) << up;
  EXPECT_EQ(up["plane"].size(), 4u);
  EXPECT_NE(up["method"].get<std::string>().find("SACSegmentation"), std::string::npos);
  EXPECT_NE(up["levelling_xyzw"], json());
  // The text summary says so too.
  r = run("map " + shell_quote(path("cam.pcd")) + " --up auto --out " +
          shell_quote(path("levelled2")));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("levelled (--up auto)"), std::string::npos) << r.out;
  // The report of that map says how its up direction was found; a report made from the cloud
  // itself refuses it as map does, rather than finding no problems.
  r = run("report --terrain " + shell_quote(path("levelled")) + " --out " +
          shell_quote(path("levelled.html")));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("terrain input " + path("cam.pcd") + ": levelled by the dominant plane"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("tilted 135."), std::string::npos) << r.out;
  r = run("report --terrain " + shell_quote(path("cam.pcd")) + " --out " +
          shell_quote(path("cam.html")));
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.err.find("z does not look like up"), std::string::npos) << r.err;
  // --up z maps it as it is, tilted.
  r = map(shell_quote(path("cam.pcd")), "as_is", "--up z");
  ASSERT_EQ(r.code, 0) << r.err;
  // The body frame (x forward, z up) pitched 31 deg: the floor is a 31 deg slope there.
  scan("body.pcd", "--pitch 31 --no-viewpoint", "flat");
  r = map(shell_quote(path("body.pcd")), "body");
  EXPECT_NE(r.code, 0);
  ASSERT_TRUE(std::regex_search(r.err, m, std::regex("tilted ([0-9.]+) deg"))) << r.err;
  EXPECT_NEAR(std::stod(m[1]), 31.0, 1.0) << r.err;
  EXPECT_NE(r.err.find("0.80 m above it"), std::string::npos) << r.err;
}

TEST_F(SensorFramesCli, WallsSensorsBelowAndTooFewPoints) {
  // A wall 2 m ahead, nothing else: 90 deg from level.
  {
    std::ofstream wall(path("wall.xyz"));
    for (int i = 0; i < 100; ++i)
      for (int j = 0; j < 75; ++j) wall << 2.0 << " " << -1 + 0.02 * i << " " << 0.02 * j << "\n";
  }
  CommandResult r = map(shell_quote(path("wall.xyz")), "wall");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("tilted 90.0 deg"), std::string::npos) << r.err;
  // A camera looking straight down, its optical-frame points without a pose: the floor is level
  // in that frame, but the sensor is below it.
  scan("down.pcd", "--pitch 90 --frame optical --no-viewpoint", "flat");
  r = map(shell_quote(path("down.pcd")), "down");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("below it"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("taken at the frame's origin"), std::string::npos) << r.err;
  // A world-frame floor at z = 0.3 with the sensor given beneath it.
  {
    std::ofstream floor(path("floor.xyz"));
    for (int i = 0; i < 100; ++i)
      for (int j = 0; j < 100; ++j) floor << 0.01 * i << " " << 0.01 * j << " 0.3\n";
  }
  r = map(shell_quote(path("floor.xyz")), "floor_below", "--origin 0.5,0.5,-0.5");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("0.80 m below it"), std::string::npos) << r.err;
  r = map(shell_quote(path("floor.xyz")), "floor_above", "--origin 0.5,0.5,1.5");
  ASSERT_EQ(r.code, 0) << r.err;
  const json up = json::parse(r.out)["inputs"][0]["up"];
  EXPECT_NEAR(up["tilt_deg"].get<double>(), 0.0, 0.5);
  EXPECT_NEAR(up["sensor_height"].get<double>(), 1.2, 0.01);
  // Too few points to judge: mapped as they are, and terrain.json says why; --up auto refuses.
  {
    std::ofstream few(path("few.xyz"));
    for (int i = 0; i < 5; ++i)
      for (int j = 0; j < 5; ++j) few << 0.1 * i << " " << 0.1 * j << " 0\n";
  }
  r = map(shell_quote(path("few.xyz")), "few");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(
      json::parse(r.out)["inputs"][0]["up"]["problem"].get<std::string>().find("too few points"),
      std::string::npos);
  r = map(shell_quote(path("few.xyz")), "few_auto", "--up auto");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--up auto cannot level"), std::string::npos) << r.err;
  // Only NaNs: the reader's error, not a crash.
  {
    std::ofstream nans(path("nans.xyz"));
    for (int i = 0; i < 10; ++i) nans << "nan nan nan\n";
  }
  r = map(shell_quote(path("nans.xyz")), "nans", "--up auto");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("non-finite"), std::string::npos) << r.err;
}

TEST_F(SensorFramesCli, OldWorldFramePcdIsNeverMappedShifted) {
  // The layout of terrastride's earlier writer: world-frame points, VIEWPOINT = position only.
  const json world = scan("w.pcd", "", "flat");
  const auto file = terrastride::perception::read_cloud_file(path("w.pcd"));
  {
    std::ofstream old(path("old.pcd"));
    old.precision(9);
    old << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
        << "TYPE F F F\nCOUNT 1 1 1\nWIDTH " << file.points.size() << "\nHEIGHT 1\nVIEWPOINT "
        << world["origin"][0] << " " << world["origin"][1] << " " << world["origin"][2]
        << " 1 0 0 0\nPOINTS " << file.points.size() << "\nDATA ascii\n";
    // scan-sim's default frame is the camera body: back to the world for the old layout.
    const auto back = terrastride::perception::read_cloud(path("w.pcd"));
    for (const auto& p : back.points) old << p.x() << " " << p.y() << " " << p.z() << "\n";
  }
  CommandResult r = map(shell_quote(path("old.pcd")), "old");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--viewpoint origin"), std::string::npos) << r.err;
  r = map(shell_quote(path("old.pcd")), "old_origin", "--viewpoint origin");
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_EQ(map(shell_quote(path("w.pcd")), "new").code, 0);
  EXPECT_LE(max_difference(layers("new"), layers("old_origin")), 1e-3);
}

TEST_F(SensorFramesCli, BadPosesAreRefusedNamingTheOptionOrLine) {
  scan("s.pcd", "--frame optical --no-viewpoint", "flat");
  const std::string in = shell_quote(path("s.pcd"));
  struct Case {
    std::string args;
    std::vector<std::string> needles;
  };
  const std::vector<Case> cases = {
      {"--sensor-pose 1,2,3", {"--sensor-pose", "expected 7 numbers"}},
      {"--sensor-pose 0,0,1,0,0,0,nan", {"--sensor-pose", "not a finite number"}},
      {"--sensor-pose 0,0,1,0,0,0,0", {"--sensor-pose", "zero"}},
      {"--sensor-pose 0,0,1,0,0,0,2", {"--sensor-pose", "norm 2"}},
      {"--sensor-pose 0,0,1,0,0,0,1 --origin 0,0,1", {"--origin", "--sensor-pose"}},
      {"--up sideways", {"--up", "sideways"}},
      {"--sensor-frame camera", {"--sensor-frame", "camera"}},
      {"--viewpoint world", {"--viewpoint", "world"}},
      {"--poses " + shell_quote(path("missing.txt")), {"--poses", "missing.txt", "cannot open"}},
  };
  for (const Case& c : cases) {
    const CommandResult r = map(in, "out", c.args);
    EXPECT_NE(r.code, 0) << c.args;
    for (const auto& n : c.needles)
      EXPECT_NE(r.err.find(n), std::string::npos) << c.args << ": " << r.err;
  }
  std::ofstream(path("p1.txt")) << "# header\ns.pcd 0 0 1 0 0 0 1\nother.pcd 0 0 1 0 0\n";
  CommandResult r = map(in, "out", "--poses " + shell_quote(path("p1.txt")));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("p1.txt: line 3"), std::string::npos) << r.err;
  std::ofstream(path("p2.txt")) << "other.pcd 0 0 1 0 0 0 1\n";
  r = map(in, "out", "--poses " + shell_quote(path("p2.txt")));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("no pose for it"), std::string::npos) << r.err;
  // A poses file alone names the clouds to map.
  std::ofstream(path("p3.txt")) << "s.pcd 0 0 1 -0.5 0.5 -0.5 0.5\n";
  r = run("map --poses " + shell_quote(path("p3.txt")) + " --out " + shell_quote(path("p3")));
  EXPECT_EQ(r.code, 0) << r.err;
}

}  // namespace

namespace {

// A real world-frame cloud whose VIEWPOINT holds the sensor's pose (skipped without ../shared):
// refused with --viewpoint origin as the first suggestion (the cloud as written is level), --up z
// said to keep the VIEWPOINT's rotation; --up auto levels it (the rotation applied, then the
// plane's).
TEST(SensorFramesShared, WorldFramePcdWithASensorViewpointLeadsWithViewpointOrigin) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  terrastride::perception::test::ScratchDir dir;
  const std::string cloud =
      shell_quote(terrastride::perception::test::scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"));
  CommandResult r = run("map " + cloud + " --out " + shell_quote(dir.file("refused")));
  EXPECT_EQ(r.code, 1) << r.all();
  const size_t origin = r.err.find("say --viewpoint origin");
  ASSERT_NE(origin, std::string::npos) << r.err;
  EXPECT_NE(r.err.find("as written, that plane is 1.6 deg from level"), std::string::npos) << r.err;
  for (const char* later : {"--sensor-pose", "--up auto", "--up z"}) {
    const size_t at = r.err.find(later);
    ASSERT_NE(at, std::string::npos) << later << ": " << r.err;
    EXPECT_GT(at, origin) << later << ": " << r.err;
  }
  EXPECT_NE(r.err.find("--up z maps it with the VIEWPOINT's rotation applied"), std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir.file("refused")));
  const std::string out = dir.file("levelled");
  r = run("map " + cloud + " --up auto --out " + shell_quote(out));
  ASSERT_EQ(r.code, 0) << r.all();
  std::ifstream in(fs::path(out) / "terrain.json");
  const json up = json::parse(in)["inputs"][0]["up"];
  EXPECT_EQ(up["from"], "levelled by the dominant plane (--up auto)") << up.dump();
  EXPECT_NEAR(up["tilt_deg"].get<double>(), 91.5, 0.5) << up.dump();
}

}  // namespace
