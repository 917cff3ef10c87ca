// plan.json round trip, validation of malformed plan files, and interpolation between samples.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"

using namespace terrastride::planner;
using nlohmann::json;

namespace {

Trajectory two_sample_plan() {
  Trajectory t;
  t.robot = "hyq";
  t.gait = "crawl";
  t.duration = 0.02;
  t.sample_dt = 0.01;
  t.feet = {"LF", "RF"};
  for (int k = 0; k < 3; ++k) {
    TrajectorySample s;
    s.t = 0.01 * k;
    s.base.position = Eigen::Vector3d(0.1 * k, 0, 0.58);
    s.base.euler_zyx = Eigen::Vector3d(0.01 * k, 0, 0);
    s.base.linear_acceleration = Eigen::Vector3d(0, 0, -0.5 * k);
    for (int i = 0; i < 2; ++i) {
      FootState f;
      f.position = Eigen::Vector3d(0.31, i ? -0.29 : 0.29, 0);
      f.force = Eigen::Vector3d(1, 2, 400 + k);
      f.contact = (k + i) % 2 == 0;
      s.feet.push_back(f);
    }
    t.samples.push_back(s);
  }
  t.solver = {"optimal", 42, 0.25, 1000, 900};
  t.checks["dynamics_linear_max_N"] = 1.5;
  t.extra["phases"] = json::array({json::array({0.0, 0.5})});
  return t;
}

std::string error_of(const json& j) {
  try {
    plan_from_json(j, "p.json");
  } catch (const PlanFileError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(PlanIo, RoundTripKeepsEverything) {
  const Trajectory t = two_sample_plan();
  const auto path = (std::filesystem::temp_directory_path() / "terrastride_plan_io.json").string();
  write_plan_file(path, t);
  const Trajectory r = read_plan_file(path);
  EXPECT_EQ(r.robot, "hyq");
  EXPECT_EQ(r.feet, t.feet);
  ASSERT_EQ(r.samples.size(), 3u);
  EXPECT_EQ(r.samples[2].base.position, t.samples[2].base.position);
  EXPECT_EQ(r.samples[1].feet[1].force, t.samples[1].feet[1].force);
  EXPECT_EQ(r.samples[1].feet[0].contact, t.samples[1].feet[0].contact);
  EXPECT_EQ(r.solver.status, "optimal");
  EXPECT_EQ(r.solver.iterations, 42);
  EXPECT_DOUBLE_EQ(r.checks.at("dynamics_linear_max_N"), 1.5);
  EXPECT_EQ(r.extra["phases"], t.extra["phases"]);
  // The written file has DESIGN.md's layout.
  const json j = plan_to_json(t);
  EXPECT_TRUE(j["samples"][0]["base"].contains("angular_acceleration"));
  EXPECT_TRUE(j["samples"][0]["feet"][0].contains("contact"));
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp." + std::to_string(::getpid())));
}

TEST(PlanIo, MalformedPlansNameTheField) {
  json good = plan_to_json(two_sample_plan());
  json j = good;
  j.erase("robot");
  EXPECT_EQ(error_of(j), "p.json: robot: missing");
  j = good;
  j["samples"][1]["base"]["position"] = json::array({0, 1});
  EXPECT_EQ(error_of(j), "p.json: samples[1].base.position: must be an array of 3 numbers");
  j = good;
  j["samples"][2]["feet"][1]["force"][2] = nullptr;  // how a NaN comes out of a JSON writer
  EXPECT_NE(error_of(j).find("samples[2].feet[1].force: element 2 is not a finite number"),
            std::string::npos);
  j = good;
  j["samples"][2]["t"] = 0.0;
  EXPECT_NE(error_of(j).find("samples[2].t: times must increase"), std::string::npos);
  j = good;
  j["samples"][0]["feet"].erase(1);
  EXPECT_NE(error_of(j).find("expected 2"), std::string::npos);
  j = good;
  j["samples"] = json::array();
  EXPECT_NE(error_of(j).find("samples: must not be empty"), std::string::npos);
  EXPECT_NE(error_of(json::array()).find("must be a JSON object"), std::string::npos);
  EXPECT_THROW(read_plan_file("/nonexistent/plan.json"), PlanFileError);
  const auto bad = (std::filesystem::temp_directory_path() / "terrastride_bad_plan.json").string();
  std::ofstream(bad) << "{ not json";
  try {
    read_plan_file(bad);
    FAIL();
  } catch (const PlanFileError& e) {
    EXPECT_NE(std::string(e.what()).find("not valid JSON"), std::string::npos);
  }
  EXPECT_THROW(write_plan_file("/nonexistent/dir/plan.json", two_sample_plan()), PlanFileError);
}

// interpolate_plan: positions and their rates come from the cubic through the two neighbouring
// samples, so a cubic motion (what the planner's splines are between knots) is reproduced exactly
// between samples, not only at them.
TEST(InterpolatePlan, ReproducesACubicMotionBetweenSamples) {
  using terrastride::planner::Trajectory;
  using terrastride::planner::TrajectorySample;
  auto pos = [](double t) { return Eigen::Vector3d(t * t * t - t, 0.5 * t * t, 0.2 * t); };
  auto vel = [](double t) { return Eigen::Vector3d(3 * t * t - 1, t, 0.2); };
  Trajectory tr;
  tr.feet = {"F"};
  for (int k = 0; k <= 10; ++k) {
    TrajectorySample s;
    s.t = 0.1 * k;
    s.base.position = pos(s.t);
    s.base.linear_velocity = vel(s.t);
    s.base.euler_zyx = 0.1 * pos(s.t);  // small angles, rates 0.1 vel; omega = E(e) e_dot
    const Eigen::Vector3d e = s.base.euler_zyx, ed = 0.1 * vel(s.t);
    Eigen::Matrix3d E;
    E << 0, -std::sin(e[0]), std::cos(e[0]) * std::cos(e[1]), 0, std::cos(e[0]),
        std::sin(e[0]) * std::cos(e[1]), 1, 0, -std::sin(e[1]);
    s.base.angular_velocity = E * ed;
    terrastride::planner::FootState f;
    f.position = pos(s.t) + Eigen::Vector3d(1, 0, 0);
    f.velocity = vel(s.t);
    s.feet.push_back(f);
    tr.samples.push_back(s);
  }
  for (double t : {0.03, 0.47, 0.951}) {
    const TrajectorySample s = terrastride::planner::interpolate_plan(tr, t);
    EXPECT_LT((s.base.position - pos(t)).norm(), 1e-12) << t;
    EXPECT_LT((s.base.linear_velocity - vel(t)).norm(), 1e-12) << t;
    EXPECT_LT((s.base.euler_zyx - 0.1 * pos(t)).norm(), 1e-12) << t;
    EXPECT_LT((s.feet[0].position - pos(t) - Eigen::Vector3d(1, 0, 0)).norm(), 1e-12) << t;
    EXPECT_LT((s.feet[0].velocity - vel(t)).norm(), 1e-12) << t;
  }
}
