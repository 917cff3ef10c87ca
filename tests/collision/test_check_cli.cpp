// `terrastride check`: exit codes, JSON output, series file and errors naming the bad input.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "trajectories.hpp"

namespace fs = std::filesystem;
using namespace terrastride;

namespace {

using test_support::CommandResult;

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

class CheckCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("terrastride_check_cli_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  CommandResult run(const std::string& args) const { return test_support::run_terrastride(args); }

  std::string write_plan(const std::string& name, const planner::Trajectory& traj) const {
    const std::string p = path(name);
    planner::write_plan_file(p, traj);
    return p;
  }

  fs::path dir_;
};

}  // namespace

TEST_F(CheckCli, StandingPlanPassesOnFlat) {
  const auto model = collision::test::hyq();
  const std::string plan = write_plan("stand.json", collision::test::standing(model, 0.5, 0.01));
  const CommandResult r =
      run("check " + plan + " --terrain flat --json --series " + path("s.json"));
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j.at("passed").get<bool>());
  for (const char* key : {"torque_ratio_max", "torque_violations", "shin_min_distance_m",
                          "shin_collisions", "unsafe_footholds"})
    EXPECT_TRUE(j.at("checks").contains(key)) << key;
  EXPECT_LT(j["checks"]["torque_ratio_max"].get<double>(), 1.0);
  EXPECT_EQ(j["checks"]["shin_collisions"].get<double>(), 0.0);
  EXPECT_EQ(j["legs"].size(), 4u);
  // The series file holds one torque value per joint and sample.
  const auto s = nlohmann::json::parse(slurp(path("s.json")));
  EXPECT_EQ(s["t"].size(), 51u);
  EXPECT_EQ(s["legs"][0]["tau_Nm"].size(), 3u);
  EXPECT_EQ(s["legs"][0]["tau_Nm"][1].size(), 51u);
  EXPECT_EQ(s["legs"][2]["shin_distance_m"].size(), 51u);

  // Human summary by default.
  const CommandResult h = run("check " + plan + " --terrain flat");
  EXPECT_EQ(h.code, 0) << h.err;
  EXPECT_NE(h.out.find("PASS"), std::string::npos) << h.out;
}

TEST_F(CheckCli, FailingChecksExitWith3AndSayWhy) {
  const auto model = collision::test::hyq();
  auto traj = collision::test::standing(model, 0.2, 0.01);
  for (auto& s : traj.samples) {
    s.feet[1].force = Eigen::Vector3d(0, 0, 2500.0);        // RF: far beyond its polytope
    s.feet[0].position = Eigen::Vector3d(0.55, 0.29, 0.0);  // LF: on the pallet's edge
  }
  const std::string plan = write_plan("push.json", traj);
  const CommandResult r = run("check " + plan + " --terrain pallet_10 --json");
  EXPECT_EQ(r.code, 3) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_FALSE(j.at("passed").get<bool>());
  EXPECT_GT(j["checks"]["torque_ratio_max"].get<double>(), 1.0);
  EXPECT_EQ(j["checks"]["torque_violations"].get<double>(), 21.0);
  EXPECT_EQ(j["checks"]["unsafe_footholds"].get<double>(), 1.0);
  EXPECT_EQ(j["torque_worst"]["leg"], "RF");
  EXPECT_NE(r.err.find("check(s) failed"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("torque"), std::string::npos) << r.err;
}

TEST_F(CheckCli, BadInputIsNamed) {
  const auto model = collision::test::hyq();
  const std::string good = write_plan("good.json", collision::test::standing(model, 0.1, 0.01));

  // A NaN in the plan: plan.json has no NaN literal, so a string stands in for a broken writer.
  auto j = nlohmann::json::parse(slurp(good));
  j["samples"][3]["feet"][2]["force"][1] = "nan";
  std::ofstream(path("nan.json")) << j.dump();
  CommandResult r = run("check " + path("nan.json") + " --terrain flat");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("nan.json"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("samples[3]"), std::string::npos) << r.err;

  // A missing key.
  j = nlohmann::json::parse(slurp(good));
  j["samples"][0]["base"].erase("position");
  std::ofstream(path("missing.json")) << j.dump();
  r = run("check " + path("missing.json") + " --terrain flat");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("position"), std::string::npos) << r.err;

  // A robot that does not exist.
  j = nlohmann::json::parse(slurp(good));
  j["robot"] = "nosuchbot";
  std::ofstream(path("robot.json")) << j.dump();
  r = run("check " + path("robot.json") + " --terrain flat");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("robot"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("nosuchbot"), std::string::npos) << r.err;

  // The monoped's plan checked as... the monoped has one leg, so feet must match it.
  j = nlohmann::json::parse(slurp(good));
  j["robot"] = "monoped";
  std::ofstream(path("mono.json")) << j.dump();
  r = run("check " + path("mono.json") + " --terrain flat");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("mono.json"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("feet"), std::string::npos) << r.err;

  // An unknown terrain.
  r = run("check " + good + " --terrain moon");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("moon"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("pallet_10"), std::string::npos) << r.err;  // lists the scenes

  // A terrain directory without its octomap.bt.
  fs::create_directories(path("empty_dir"));
  r = run("check " + good + " --terrain " + path("empty_dir"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("empty_dir"), std::string::npos) << r.err;
}
