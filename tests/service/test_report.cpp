// `terrastride report`: the offline foothold-safety report, driven through the real binary.
// Plans are written here from the Trajectory struct (a simple crawl whose footholds, forces and
// timing we control), so each test knows exactly which problem the report must find.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>

#include "support/run_command.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::planner::Trajectory;

using RunResult = terrastride::test_support::CommandResult;
using terrastride::test_support::shell_quote;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

RunResult run(const std::string& args) {
  return terrastride::test_support::run_terrastride(args);
}

class ReportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           (std::string("terrastride-report-") + info->test_suite_name() + "-" + info->name() +
            "-" + std::to_string(::getpid()));  // two checkouts' suites run at once here
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

// A statically walking crawl: the base moves `advance` m along +x at the nominal height; the feet
// swing one after another (LH, LF, RH, RF) by `advance` with a 10 cm arc; the stance feet share
// the weight equally (forces scaled by `force_scale` between t0 and t1 for a torque violation).
// `foot_shift` moves every final foothold of foot `shift_foot` by that much in x.
struct CrawlSpec {
  double ground = 0.0;
  double advance = 0.15;
  double duration = 4.0;
  double force_scale = 1.0;
  double scale_t0 = 0.0, scale_t1 = 0.0;
  int shift_foot = -1;
  double foot_shift = 0.0;
};

Trajectory make_crawl(const CrawlSpec& spec) {
  const auto model = terrastride::robot::load_robot(terrastride::robot::resolve_robot_path("hyq"));
  Trajectory traj;
  traj.robot = "hyq";
  traj.gait = "crawl";
  traj.duration = spec.duration;
  traj.sample_dt = 0.01;
  traj.feet = {"LF", "RF", "LH", "RH"};
  traj.solver.status = "optimal";
  traj.solver.iterations = 42;
  traj.solver.wall_s = 0.5;
  traj.solver.n_variables = 1000;
  traj.solver.n_constraints = 900;
  const int order[4] = {2, 0, 3, 1};         // LH, LF, RH, RF
  const double phase = spec.duration / 5.0;  // four swings in the middle of five slots
  const int n = static_cast<int>(std::round(spec.duration / traj.sample_dt)) + 1;
  const double z = spec.ground + model.nominal_base_height;
  auto base_x = [&](double t) {
    const double s = std::clamp(t / spec.duration, 0.0, 1.0);
    return spec.advance * s * s * (3 - 2 * s);
  };
  auto foot_pos = [&](int f, double t, bool* contact) {
    const Eigen::Vector3d nominal = model.legs[f].nominal_foot;
    const int slot = [&] {
      for (int k = 0; k < 4; ++k)
        if (order[k] == f) return k;
      return 0;
    }();
    const double t_lift = phase * (0.5 + slot), t_land = t_lift + phase;
    const double x0 = nominal.x(),
                 x1 = nominal.x() + spec.advance + (f == spec.shift_foot ? spec.foot_shift : 0.0);
    Eigen::Vector3d p(x0, nominal.y(), spec.ground);
    *contact = true;
    if (t >= t_land) {
      p.x() = x1;
    } else if (t > t_lift) {
      const double s = (t - t_lift) / phase;
      p.x() = x0 + (x1 - x0) * s * s * (3 - 2 * s);
      p.z() = spec.ground + 0.1 * std::sin(M_PI * s);
      *contact = false;
    }
    return p;
  };
  for (int k = 0; k < n; ++k) {
    const double t = k * traj.sample_dt;
    terrastride::planner::TrajectorySample s;
    s.t = t;
    const double h = 1e-4;
    s.base.position = Eigen::Vector3d(base_x(t), 0.0, z);
    s.base.linear_velocity = Eigen::Vector3d((base_x(t + h) - base_x(t - h)) / (2 * h), 0, 0);
    s.base.linear_acceleration =
        Eigen::Vector3d((base_x(t + h) - 2 * base_x(t) + base_x(t - h)) / (h * h), 0, 0);
    int contacts = 0;
    for (int f = 0; f < 4; ++f) {
      bool c = false;
      foot_pos(f, t, &c);
      contacts += c ? 1 : 0;
    }
    for (int f = 0; f < 4; ++f) {
      terrastride::planner::FootState foot;
      bool c = false, c1 = false, c0 = false;
      foot.position = foot_pos(f, t, &c);
      foot.velocity = (foot_pos(f, t + h, &c1) - foot_pos(f, t - h, &c0)) / (2 * h);
      foot.contact = c;
      if (c) {
        double fz = model.mass * 9.81 / contacts;
        if (t >= spec.scale_t0 && t <= spec.scale_t1) fz *= spec.force_scale;
        foot.force = Eigen::Vector3d(0, 0, fz);
      }
      s.feet.push_back(foot);
    }
    traj.samples.push_back(s);
  }
  return traj;
}

json read_json(const fs::path& p) {
  return json::parse(slurp(p));
}

bool has_problem(const json& report, const std::string& id) {
  for (const json& p : report["problems"])
    if (p["id"] == id) return true;
  return false;
}

TEST_F(ReportTest, CleanPlanOnFlatGroundShowsNoProblem) {
  const fs::path plan = dir_ / "clean.json";
  terrastride::planner::write_plan_file(plan.string(), make_crawl({}));
  const fs::path html = dir_ / "report.html";
  const RunResult r = run("report --terrain flat --plan " + shell_quote(plan.string()) + " --out " +
                          shell_quote(html.string()) + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_TRUE(fs::exists(html));
  const json rep = read_json(dir_ / "report.json");
  EXPECT_TRUE(rep["ok"].get<bool>()) << rep["problems"].dump(1);
  EXPECT_TRUE(rep["problems"].empty());
  ASSERT_EQ(rep["plans"].size(), 1u);
  const json& p = rep["plans"][0];
  EXPECT_EQ(p["footholds"].size(), 8u);  // 4 initial + 4 final stances
  for (const json& fh : p["footholds"]) EXPECT_TRUE(fh["safe"].get<bool>());
  EXPECT_GT(p["torque"]["ratio_max"].get<double>(), 0.05);
  EXPECT_LT(p["torque"]["ratio_max"].get<double>(), 1.0);
  EXPECT_EQ(p["torque"]["legs"].size(), 4u);
  EXPECT_FALSE(p["torque"]["time"].empty());
  // The flat scene is voxelised for the capsule check: shins clear of the ground.
  ASSERT_FALSE(p["clearance"].contains("absent")) << p["clearance"].dump();
  EXPECT_GT(p["clearance"]["shin_min_m"].get<double>(), 0.0);
  EXPECT_EQ(p["clearance"]["shin_collisions"].get<int>(), 0);
  // The summary rows: nothing is flagged.
  for (const json& row : p["summary"]) EXPECT_NE(row["status"], "problem") << row.dump();
  // Flat ground is safe everywhere (the scene has no edge).
  EXPECT_DOUBLE_EQ(rep["terrain"]["safe_fraction"].get<double>(), 1.0);
  // The page inlines everything: data, script and the plotting library, no external script or
  // image (the headless-Chromium test below checks that nothing at all is fetched).
  const std::string page = slurp(html);
  EXPECT_NE(page.find("window.REPORT = {"), std::string::npos);
  EXPECT_NE(page.find("Plotly"), std::string::npos);
  EXPECT_EQ(page.find("src=\"http"), std::string::npos);
  EXPECT_EQ(page.find("/*__DATA__*/"), std::string::npos);
  // --json prints the summary with the paths.
  const json summary = json::parse(r.out);
  EXPECT_TRUE(summary["ok"].get<bool>());
  EXPECT_EQ(summary["html"], html.string());
}

TEST_F(ReportTest, FootholdOnThePalletEdgeIsAProblem) {
  // pallet_10: box from x = 0.55; LF lands at 0.31 + 0.24 = 0.55, right on the edge.
  CrawlSpec spec;
  spec.advance = 0.24;
  const fs::path plan = dir_ / "edge_plan.json";
  terrastride::planner::write_plan_file(plan.string(), make_crawl(spec));
  const fs::path html = dir_ / "edge.html";
  const RunResult r = run("report --terrain pallet_10 --plan " + shell_quote(plan.string()) +
                          " --out " + shell_quote(html.string()));
  ASSERT_EQ(r.code, 0) << r.err;
  const json rep = read_json(dir_ / "edge.json");
  EXPECT_FALSE(rep["ok"].get<bool>());
  EXPECT_TRUE(has_problem(rep, "unsafe_foothold")) << rep["problems"].dump(1);
  EXPECT_FALSE(has_problem(rep, "torque_limit"));
  int unsafe = 0;
  for (const json& fh : rep["plans"][0]["footholds"])
    if (!fh["safe"].get<bool>()) {
      ++unsafe;
      EXPECT_TRUE(fh["foot"] == "LF" || fh["foot"] == "RF") << fh.dump();
      EXPECT_LT(fh["margin_m"].get<double>(), 0.0);
    }
  EXPECT_EQ(unsafe, 2);  // both front feet land on the edge
  EXPECT_NE(r.out.find("PROBLEM"), std::string::npos) << r.out;
  // The same plan, 10 cm shorter, stays clear of the edge: no problem.
  spec.advance = 0.14;
  terrastride::planner::write_plan_file(plan.string(), make_crawl(spec));
  const RunResult ok = run("report --terrain pallet_10 --plan " + shell_quote(plan.string()) +
                           " --out " + shell_quote(html.string()));
  ASSERT_EQ(ok.code, 0) << ok.err;
  EXPECT_TRUE(read_json(dir_ / "edge.json")["problems"].empty());
}

TEST_F(ReportTest, TorqueViolationIsAProblem) {
  CrawlSpec spec;
  spec.force_scale = 4.0;  // four times the weight on the stance legs for half a second
  spec.scale_t0 = 1.0;
  spec.scale_t1 = 1.5;
  const fs::path plan = dir_ / "heavy_plan.json";
  terrastride::planner::write_plan_file(plan.string(), make_crawl(spec));
  const fs::path html = dir_ / "heavy.html";
  const RunResult r = run("report --terrain flat --plan " + shell_quote(plan.string()) + " --out " +
                          shell_quote(html.string()));
  ASSERT_EQ(r.code, 0) << r.err;
  const json rep = read_json(dir_ / "heavy.json");
  EXPECT_TRUE(has_problem(rep, "torque_limit")) << rep["problems"].dump(1);
  EXPECT_GT(rep["plans"][0]["torque"]["ratio_max"].get<double>(), 1.0);
  EXPECT_GT(rep["plans"][0]["torque"]["violating_samples"].get<int>(), 10);
  EXPECT_FALSE(has_problem(rep, "unsafe_foothold"));
}

TEST_F(ReportTest, PlanFileChecksAndSolverStatusAreFlagged) {
  Trajectory traj = make_crawl({});
  traj.solver.status = "time_limit";
  traj.checks["penetration_max_m"] = 0.02;  // 2 cm > 5 mm
  traj.checks["slip_max_m"] = 0.0001;       // fine
  const fs::path plan = dir_ / "p.json";
  terrastride::planner::write_plan_file(plan.string(), traj);
  const RunResult r = run("report --terrain flat --plan " + shell_quote(plan.string()) + " --out " +
                          shell_quote((dir_ / "r.html").string()));
  ASSERT_EQ(r.code, 0) << r.err;
  const json rep = read_json(dir_ / "r.json");
  EXPECT_TRUE(has_problem(rep, "solver"));
  EXPECT_TRUE(has_problem(rep, "penetration_max_m"));
  EXPECT_FALSE(has_problem(rep, "slip_max_m"));
  bool absent_row = false;
  for (const json& row : rep["plans"][0]["summary"])
    if (row["label"] == "friction-pyramid violation") absent_row = row["status"] == "absent";
  EXPECT_TRUE(absent_row) << "a check missing from the plan is shown as not available";
}

// A map folder in the terrain module's on-disk format, written with its own API.
void write_map_dir(const fs::path& dir, const std::string& scene_name) {
  const auto scene = terrastride::terrain::make_scene(scene_name);
  const auto map = terrastride::terrain::TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05});
  fs::create_directories(dir / "layers");
  json meta = terrastride::terrain::write_terrain_layers(*map, dir.string());
  std::ofstream(dir / "terrain.json") << meta.dump(1);
}

TEST_F(ReportTest, MapFolderAndBatchRanking) {
  write_map_dir(dir_ / "scans" / "flat_map", "flat");
  write_map_dir(dir_ / "scans" / "stairs_map", "stairs");
  const RunResult one =
      run("report --terrain " + shell_quote((dir_ / "scans" / "stairs_map").string()) + " --out " +
          shell_quote((dir_ / "stairs.html").string()) + " --json");
  ASSERT_EQ(one.code, 0) << one.err;
  const json rep = read_json(dir_ / "stairs.json");
  EXPECT_EQ(rep["terrain"]["kind"], "map");
  const double stairs_safe = rep["terrain"]["safe_fraction"].get<double>();
  EXPECT_GT(stairs_safe, 0.3);
  EXPECT_LT(stairs_safe, 1.0);                     // the riser edges are unsafe
  ASSERT_EQ(rep["terrain"]["layers"].size(), 2u);  // the map's radii 0.02 and 0.05
  EXPECT_GE(rep["terrain"]["layers"][0]["safe_fraction"].get<double>(),
            rep["terrain"]["layers"][1]["safe_fraction"].get<double>());

  const fs::path out = dir_ / "batch";
  const RunResult b = run("report --batch " + shell_quote((dir_ / "scans").string()) + " --out " +
                          shell_quote(out.string()));
  ASSERT_EQ(b.code, 0) << b.err;
  EXPECT_TRUE(fs::exists(out / "index.html"));
  EXPECT_TRUE(fs::exists(out / "flat_map" / "flat_map.html"));
  EXPECT_TRUE(fs::exists(out / "stairs_map" / "stairs_map.json"));
  const json index = read_json(out / "index.json");
  ASSERT_EQ(index["reports"].size(), 2u);
  EXPECT_EQ(index["reports"][0]["scan"], "flat_map");  // flat ranks first (safer)
  EXPECT_EQ(index["reports"][1]["scan"], "stairs_map");
  EXPECT_GT(index["reports"][0]["safe_fraction"].get<double>(),
            index["reports"][1]["safe_fraction"].get<double>());
}

TEST_F(ReportTest, BadInputsNameTheProblemAndWriteNothing) {
  const fs::path html = dir_ / "r.html";
  RunResult r = run("report --terrain " + shell_quote((dir_ / "nope").string()) + " --out " +
                    shell_quote(html.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("nope"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(html));

  r = run("report --terrain flat --out " + shell_quote((dir_ / "r.txt").string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find(".html"), std::string::npos) << r.err;

  std::ofstream(dir_ / "broken.json") << "{\"robot\": \"hyq\", \"samples\": 3}";
  r = run("report --terrain flat --plan " + shell_quote((dir_ / "broken.json").string()) +
          " --out " + shell_quote(html.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("broken.json"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(html));
  EXPECT_FALSE(fs::exists(dir_ / "r.json"));

  r = run("report --out " + shell_quote(html.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--terrain"), std::string::npos) << r.err;

  r = run("report --terrain flat --foot-radius 0.02,-1 --out " + shell_quote(html.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("--foot-radius"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(html));
}

// ---- What the report says is true ----

// A 45-degree slope: next to no cell of it is a safe foothold (slope 1 > the 0.6 limit; 1.9 % at
// its rim for a 2 cm foot). Its terrain rows
// must say so with a status against a stated threshold, in `map`'s words and figure.
TEST_F(ReportTest, TerrainRowsCarryStatusesAgainstStatedThresholds) {
  {
    std::ofstream xyz(dir_ / "slope.xyz");
    for (int i = 0; i <= 100; ++i)
      for (int j = 0; j <= 100; ++j) xyz << i * 0.01 << " " << j * 0.01 << " " << i * 0.01 << "\n";
  }
  // A world-frame slope: z is up although its dominant plane is 45 deg from level.
  const auto mapped = run("map " + shell_quote((dir_ / "slope.xyz").string()) + " --up z --out " +
                          shell_quote((dir_ / "slope").string()));
  ASSERT_EQ(mapped.code, 0) << mapped.all();
  const auto r = run("report --terrain " + shell_quote((dir_ / "slope").string()) + " --out " +
                     shell_quote((dir_ / "slope.html").string()));
  ASSERT_EQ(r.code, 0) << r.all();
  const json rep = read_json(dir_ / "slope.json");
  const json& primary = rep["summary"][rep["terrain"]["primary_layer"].get<int>()];
  // `map` prints "safe for foot radius 0.02 m: 1.9 % of observed cells"; the report the same.
  EXPECT_EQ(primary["label"], "safe for foot radius 0.02 m") << primary.dump();
  EXPECT_EQ(primary["unit"], "% of observed cells");
  const double percent = primary["value"].get<double>();
  EXPECT_LT(percent, 5.0);  // a few cells at the slope's rim
  EXPECT_EQ(primary["status"], "problem") << primary.dump();
  EXPECT_NE(primary["note"].get<std::string>().find("problem below 5 %"), std::string::npos);
  bool flagged = false;
  for (const json& p : rep["problems"]) flagged |= p["id"] == "terrain_unsafe";
  EXPECT_TRUE(flagged) << rep["problems"].dump();
  EXPECT_FALSE(rep["ok"].get<bool>());
  // One definition: the map's own figure (terrain.json, SafetyLayer::safe_fraction()).
  const json terrain = read_json(dir_ / "slope" / "terrain.json");
  for (const json& layer : terrain["safety"]["radii"]) {
    bool found = false;
    for (const json& l : rep["terrain"]["layers"])
      if (std::abs(l["radius_m"].get<double>() - layer["radius"].get<double>()) < 1e-9) {
        EXPECT_NEAR(l["safe_fraction"].get<double>(), layer["safe_fraction"].get<double>(), 1e-4);
        found = true;
      }
    EXPECT_TRUE(found) << layer.dump();
  }
  char words[96];
  std::snprintf(words, sizeof words, "safe for foot radius 0.02 m: %.1f %% of observed cells",
                percent);
  EXPECT_NE(mapped.out.find(words), std::string::npos) << words << "\n" << mapped.out;
}

// The page shows how each cloud's up direction was found (terrain.json inputs[k].up) and the
// overhead layer's figures: a floor with a table top seen only from beneath, from a sensor 0.4 m
// up at the side whose position is given (--origin), so the floor is checked against gravity.
TEST_F(ReportTest, UpEstimateAndOverhangFiguresAreOnThePage) {
  {
    std::ofstream xyz(dir_ / "room.xyz");
    for (int i = 0; i < 200; ++i)
      for (int j = 0; j < 100; ++j) xyz << i * 0.01 + 0.005 << " " << j * 0.01 - 0.495 << " 0\n";
    for (int i = 0; i < 50; ++i)
      for (int j = 0; j < 50; ++j) xyz << 1.005 + i * 0.01 << " " << j * 0.01 - 0.245 << " 0.75\n";
  }
  const auto mapped = run("map " + shell_quote((dir_ / "room.xyz").string()) +
                          " --origin -1,0,0.4 --out " + shell_quote((dir_ / "room").string()));
  ASSERT_EQ(mapped.code, 0) << mapped.all();
  const auto r = run("report --terrain " + shell_quote((dir_ / "room").string()) + " --out " +
                     shell_quote((dir_ / "room.html").string()));
  ASSERT_EQ(r.code, 0) << r.all();
  const json rep = read_json(dir_ / "room.json");
  const json& t = rep["terrain"];
  ASSERT_EQ(t["inputs"].size(), 1u) << t.dump().substr(0, 400);
  const json& in = t["inputs"][0];
  EXPECT_EQ(in["method"], "check") << in.dump();
  EXPECT_NEAR(in["tilt_deg"].get<double>(), 0.0, 0.5) << in.dump();
  EXPECT_NEAR(in["sensor_height_m"].get<double>(), 0.4, 0.02) << in.dump();
  EXPECT_GT(in["inlier_share"].get<double>(), 0.5) << in.dump();
  EXPECT_GT(t["overhang_cells"].get<size_t>(), 100u);
  EXPECT_NEAR(t["min_free_height_m"].get<double>(), 0.75, 0.05) << t["min_free_height_m"];
  // The same figures as rows of the summary table the page draws.
  bool up_row = false, free_row = false;
  for (const json& row : rep["summary"]) {
    const std::string label = row["label"];
    if (label.find("up of ") == 0 && label.find("room.xyz") != std::string::npos) {
      up_row = true;
      EXPECT_EQ(row["status"], "ok") << row.dump();
      EXPECT_NE(row["note"].get<std::string>().find("0.40 m from the dominant plane"),
                std::string::npos)
          << row.dump();
    }
    if (label == "minimum free height under an overhang") {
      free_row = true;
      EXPECT_NEAR(row["value"].get<double>(), 0.75, 0.05) << row.dump();
    }
  }
  EXPECT_TRUE(up_row) << rep["summary"].dump(1);
  EXPECT_TRUE(free_row) << rep["summary"].dump(1);
  // The page carries the figures and the table that shows them.
  const std::string page = slurp(dir_ / "room.html");
  EXPECT_NE(page.find("terrain-inputs-table"), std::string::npos);
  EXPECT_NE(page.find("\"sensor_height_m\":"), std::string::npos);
  EXPECT_NE(page.find("\"min_free_height_m\":"), std::string::npos);
  // A map levelled by a guess (--up auto) is a note, not an ok.
  ASSERT_EQ(run("map " + shell_quote((dir_ / "room.xyz").string()) +
                " --origin -1,0,0.4 --up auto --out " + shell_quote((dir_ / "auto").string()))
                .code,
            0);
  ASSERT_EQ(run("report --terrain " + shell_quote((dir_ / "auto").string()) + " --out " +
                shell_quote((dir_ / "auto.html").string()))
                .code,
            0);
  const json levelled = read_json(dir_ / "auto.json");
  EXPECT_EQ(levelled["terrain"]["inputs"][0]["method"], "auto");
  for (const json& row : levelled["summary"])
    if (row["label"].get<std::string>().find("up of ") == 0) EXPECT_EQ(row["status"], "note");
}

// The shin chart's thresholds are the verdict's: on the demo's scan (pallet_10, 5 cm OctoMap) the
// shins dip into the voxels within the map's uncertainty (the exact scene says they clear the
// pallet); a sample deeper than one voxel is a certain collision in the chart and the summary.
TEST_F(ReportTest, TheShinChartAndTheSummaryAgree) {
  std::string clouds;
  for (const char* f : {"pallet_10.pcd", "pallet_10.1.pcd", "pallet_10.2.pcd"})
    clouds += " " + shell_quote(std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/" + f);
  ASSERT_EQ(run("map" + clouds + " --out " + shell_quote((dir_ / "terrain").string())).code, 0);
  const auto planned = run("plan --terrain " + shell_quote((dir_ / "terrain").string()) +
                           " --constraints all --max-time 60 --out " +
                           shell_quote((dir_ / "plan.json").string()));
  ASSERT_TRUE(planned.code == 0 || planned.code == 4) << planned.all();
  ASSERT_EQ(run("report --terrain " + shell_quote((dir_ / "terrain").string()) + " --plan " +
                shell_quote((dir_ / "plan.json").string()) + " --out " +
                shell_quote((dir_ / "r.html").string()))
                .code,
            0);
  const json rep = read_json(dir_ / "r.json");
  const json& cl = rep["plans"][0]["clearance"];
  ASSERT_TRUE(cl.contains("deep_contact_depth_m")) << "the chart needs the certain threshold";
  const double deep = cl["deep_contact_depth_m"].get<double>();
  // One voxel edge plus the depth the map's noise fills with voxels (3 sigma, terrain.json).
  std::ifstream terrain_json(dir_ / "terrain" / "terrain.json");
  const double sigma = json::parse(terrain_json)["grid"]["noise_sigma"].get<double>();
  EXPECT_NEAR(deep, cl["octree_resolution_m"].get<double>() + 3.0 * sigma, 1e-4);
  double lowest = 1.0;
  for (const json& leg : cl["legs"]) {
    ASSERT_EQ(leg["shin_m"].size(), leg["shin_verdict"].size());
    for (size_t k = 0; k < leg["shin_m"].size(); ++k) {
      if (leg["shin_m"][k].is_null()) continue;
      const double d = leg["shin_m"][k].get<double>();
      lowest = std::min(lowest, d);
      // Below the chart's red line is a certain collision, whatever the certain solid says.
      if (d < -deep) {
        EXPECT_EQ(leg["shin_verdict"][k], 2) << leg["name"] << " sample " << k;
      }
    }
  }
  const bool certain = cl["shin_collisions_certain"].get<int>() > 0;
  for (const json& row : rep["plans"][0]["summary"]) {
    if (row["label"] == "shin samples in certain collision") {
      EXPECT_EQ(row["status"], certain ? "problem" : "ok") << row.dump();
    }
  }
  if (!certain) {
    EXPECT_GE(lowest, -deep);
  }
  std::printf("demo scan: lowest shin distance to the voxels %.1f mm, certain below %.1f mm, "
              "certain samples %d\n",
              lowest * 1e3, -deep * 1e3, cl["shin_collisions_certain"].get<int>());
}

// ---- headless Chromium: the page as a person opens it ----

std::string find_program(const char* name) {
  const char* path = std::getenv("PATH");
  std::stringstream ss(path ? path : "");
  std::string dir;
  while (std::getline(ss, dir, ':')) {
    const fs::path p = fs::path(dir) / name;
    if (fs::exists(p)) return p.string();
  }
  return {};
}

json browser_check(const fs::path& html, const fs::path& dir, int* code,
                   const std::string& extra = "") {
  const std::string script =
      fs::path(TERRASTRIDE_SOURCE_DIR) / "tests" / "service" / "report_check.js";
  const fs::path out = dir / "check.json";
  const std::string cmd = "node " + shell_quote(script) + " " + shell_quote(html.string()) + " " +
                          extra + " >" + shell_quote(out.string()) + " 2>" +
                          shell_quote((dir / "check.err").string());
  const int status = std::system(cmd.c_str());
  *code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  try {
    return json::parse(slurp(out));
  } catch (const std::exception&) {
    return json{{"unparsable", slurp(out) + slurp(dir / "check.err")}};
  }
}

class ReportBrowserTest : public ReportTest {
 protected:
  void SetUp() override {
    ReportTest::SetUp();
    // Required, not optional: scripts/setup.sh installs both (Debian's chromium and nodejs).
    ASSERT_FALSE(find_program("chromium").empty())
        << "chromium is not installed (apt-get install chromium)";
    ASSERT_FALSE(find_program("node").empty()) << "node is not installed (apt-get install nodejs)";
  }
};

TEST_F(ReportBrowserTest, ReportsOpenOfflineWithEveryChartDrawnAndProblemsShown) {
  // A plan with both problems on pallet_10, and a clean plan on flat ground.
  CrawlSpec bad;
  bad.advance = 0.24;
  bad.force_scale = 4.0;
  bad.scale_t0 = 1.0;
  bad.scale_t1 = 1.5;
  terrastride::planner::write_plan_file((dir_ / "bad_plan.json").string(), make_crawl(bad));
  terrastride::planner::write_plan_file((dir_ / "clean_plan.json").string(), make_crawl({}));
  ASSERT_EQ(
      run("report --terrain pallet_10 --plan " + shell_quote((dir_ / "bad_plan.json").string()) +
          " --out " + shell_quote((dir_ / "bad.html").string()))
          .code,
      0);
  ASSERT_EQ(run("report --terrain flat --plan " + shell_quote((dir_ / "clean_plan.json").string()) +
                " --out " + shell_quote((dir_ / "clean.html").string()))
                .code,
            0);

  int code = -1;
  const json bad_check = browser_check(dir_ / "bad.html", dir_, &code);
  ASSERT_EQ(code, 0) << bad_check.dump(1);
  EXPECT_TRUE(bad_check["network_requests"].empty());
  EXPECT_TRUE(bad_check["console_errors"].empty());
  // Height map, profile, torques, clearance, 3-D view: all drawn with data.
  EXPECT_EQ(bad_check["charts"].size(), 5u) << bad_check["charts"].dump();
  for (const json& c : bad_check["charts"]) EXPECT_GT(c["points"].get<int>(), 0) << c.dump();
  // The page flags exactly the problems of report.json.
  const json bad_rep = read_json(dir_ / "bad.json");
  std::set<std::string> page_flags, json_flags;
  for (const json& f : bad_check["flags"]) page_flags.insert(f.get<std::string>());
  for (const json& p : bad_rep["problems"]) json_flags.insert(p["id"].get<std::string>());
  EXPECT_EQ(page_flags, json_flags);
  EXPECT_TRUE(page_flags.count("unsafe_foothold"));
  EXPECT_TRUE(page_flags.count("torque_limit"));
  // The base path shows on the height map wherever it goes, the pallet's white top included
  // (it was drawn white: 1.2:1 there).
  ASSERT_EQ(bad_check["base_paths"].size(), 1u) << bad_check.dump(1);
  EXPECT_GE(bad_check["base_paths"][0]["min_contrast"].get<double>(), 3.0);

  const json clean_check = browser_check(dir_ / "clean.html", dir_, &code);
  ASSERT_EQ(code, 0) << clean_check.dump(1);
  EXPECT_TRUE(clean_check["flags"].empty()) << clean_check["flags"].dump();
  EXPECT_EQ(clean_check["charts"].size(), 5u);

  // The checker has teeth: a page that fetches something or logs an error fails.
  std::string page = slurp(dir_ / "clean.html");
  const size_t at = page.find("</body>");
  ASSERT_NE(at, std::string::npos);
  page.insert(at,
              "<img src=\"http://127.0.0.1:9/pixel.png\"><script>console.error('boom')</script>");
  std::ofstream(dir_ / "tampered.html") << page;
  const json tampered = browser_check(dir_ / "tampered.html", dir_, &code);
  EXPECT_EQ(code, 1) << tampered.dump(1);
  bool saw_request = false, saw_error = false;
  for (const json& f : tampered["failures"]) {
    const std::string s = f.get<std::string>();
    saw_request |= s.find("network request") != std::string::npos;
    saw_error |= s.find("boom") != std::string::npos;
  }
  EXPECT_TRUE(saw_request) << tampered.dump(1);
  EXPECT_TRUE(saw_error) << tampered.dump(1);
}

}  // namespace

namespace {

// ---- terrastride demo ----

TEST_F(ReportTest, DemoNamesAMissingScanAndWritesNothing) {
  const fs::path out = dir_ / "demo";
  const RunResult r = run("demo --scan " + shell_quote((dir_ / "missing.pcd").string()) +
                          " --out " + shell_quote(out.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("stage 'scan'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("missing.pcd"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
}

TEST_F(ReportTest, DemoRunsMapPlanChecksAndReport) {
  // A simulated pallet scan (three sensor poses), as the shipped one is made.
  const RunResult sim =
      run("scan-sim --scene pallet_10 --out " + shell_quote((dir_ / "p.pcd").string()));
  ASSERT_EQ(sim.code, 0) << sim.err;
  std::string scans;
  for (const char* name : {"p.pcd", "p.1.pcd", "p.2.pcd", "p.3.pcd"})
    if (fs::exists(dir_ / name)) scans += " " + shell_quote((dir_ / name).string());
  const fs::path out = dir_ / "demo";
  // A generous solver time limit: the test machine may be busy with other builds.
  const RunResult r =
      run("demo --scan" + scans + " --out " + shell_quote(out.string()) + " --max-time 60 --json");
  // 0: every stage ran; 3: the solver did not reach optimality (the report still shows it).
  ASSERT_TRUE(r.code == 0 || r.code == 3) << r.code << "\n" << r.err;
  const json summary = json::parse(r.out.substr(0, r.out.find('\n')));
  for (const char* stage : {"scan", "map", "plan", "checks", "report"})
    EXPECT_TRUE(summary["stage_s"].contains(stage)) << stage;
  EXPECT_EQ(summary["report"], (out / "report.html").string());
  EXPECT_TRUE(fs::exists(out / "report.html"));
  EXPECT_TRUE(fs::exists(out / "plan.json"));
  EXPECT_TRUE(fs::exists(out / "terrain" / "terrain.json"));
  const json rep = read_json(out / "report.json");
  EXPECT_EQ(rep["terrain"]["kind"], "map");
  ASSERT_EQ(rep["plans"].size(), 1u);
  const json& p = rep["plans"][0];
  EXPECT_EQ(p["torque"]["legs"].size(), 4u);
  EXPECT_FALSE(p["clearance"].contains("absent"));  // the scan's OctoMap is used
  EXPECT_FALSE(p["footholds"].empty());
  // The report's paths name the final folder, not the temporary one it was written in.
  EXPECT_EQ(p["path"], (out / "plan.json").string());
  EXPECT_GT(rep["terrain"]["safe_fraction"].get<double>(), 0.2);
}

}  // namespace

namespace {
// `report --plan flat.json --out flat.html` would write its report.json over the plan: refused,
// naming the file, and the plan is left as it was.
TEST_F(ReportTest, TheReportNeverWritesOverItsInputs) {
  const fs::path plan = dir_ / "flat.json";
  terrastride::planner::write_plan_file(plan.string(), make_crawl({}));
  const std::string before = slurp(plan);
  const auto r = run("report --terrain flat --plan " + shell_quote(plan.string()) + " --out " +
                     shell_quote((dir_ / "flat.html").string()));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("--plan input"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("flat.json"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(plan), before);
  EXPECT_FALSE(fs::exists(dir_ / "flat.html"));
}
}  // namespace
