// Any quadruped, first class: a URDF imported with `terrastride robot import` (force polytopes
// fitted as part of it) goes through `plan --constraints all` on flat ground and over pallet_10,
// `check`, `simulate`, `export` and `report`, each with exit 0, and each reading the robot from the
// plan alone: the robot files are deleted after planning and no data folder names them, and the
// flat plan is checked and simulated once more in a folder holding only it. Robots:
// Go2 and ANYmal C (../shared/robots, skipped without it) and quadrupeds written here
// (support/quadruped_urdf.hpp) varied as real ones vary; a URDF the importer cannot take as it is
// is refused naming the joint or link and the flag that fixes it, then imported with that flag.
#include <gtest/gtest.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "support/quadruped_urdf.hpp"
#include "support/run_command.hpp"

namespace terrastride {
namespace {

namespace fs = std::filesystem;
using test_support::CommandResult;
using test_support::QuadrupedSpec;
using test_support::run_command;

fs::path scratch(const std::string& tag) {
  const fs::path p = fs::temp_directory_path() /
                     ("terrastride_any_quadruped_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

// `terrastride ARGS` in `dir`, with no TERRASTRIDE_DATA_DIR.
CommandResult run_in(const fs::path& dir, const std::string& args) {
  return run_command("cd " + test_support::shell_quote(dir.string()) +
                     " && env -u TERRASTRIDE_DATA_DIR " + TERRASTRIDE_BINARY + " " + args);
}

// Imports `urdf` (written to dir/robot.urdf unless it is a path) with `flags`, then the whole
// pipeline; every step must exit 0.
void expect_end_to_end(const std::string& tag, const std::string& urdf_path,
                       const std::string& flags) {
  SCOPED_TRACE(tag);
  const fs::path dir = scratch(tag);
  fs::create_directories(dir / "robots");
  CommandResult r =
      run_in(dir, "robot import " + urdf_path + " --out robots/" + tag + ".yaml " + flags);
  ASSERT_EQ(r.code, 0) << r.all();
  ASSERT_TRUE(fs::exists(dir / "robots" / (tag + ".polytopes.yaml"))) << r.all();
  for (const std::string terrain : {"flat", "pallet_10"}) {
    const std::string plan = terrain + ".json";
    r = run_in(dir, "plan --robot robots/" + tag + ".yaml --terrain " + terrain +
                        " --goal 1,0,0 --constraints all --out " + plan);
    ASSERT_EQ(r.code, 0) << terrain << ": " << r.all();
  }
  // From here on the plans alone carry the robot.
  fs::remove_all(dir / "robots");
  const fs::path alone = scratch(tag + "_plan_alone");
  fs::copy_file(dir / "flat.json", alone / "plan.json");
  for (const std::string terrain : {"flat", "pallet_10"}) {
    const std::string plan = terrain + ".json";
    r = run_in(dir, "check " + plan + " --terrain " + terrain);
    EXPECT_EQ(r.code, 0) << terrain << ": check: " << r.all();
    r = run_in(dir, "simulate " + plan + " --terrain " + terrain + " --out sim_" + plan);
    EXPECT_EQ(r.code, 0) << terrain << ": simulate: " << r.all();
    r = run_in(dir, "export --terrain " + terrain + " --plan " + plan + " --sim sim_" + plan +
                        " --out " + terrain + ".mcap");
    EXPECT_EQ(r.code, 0) << terrain << ": export: " << r.all();
    r = run_in(dir, "report --terrain " + terrain + " --plan " + plan + " --out " + terrain +
                        "_report.html");
    EXPECT_EQ(r.code, 0) << terrain << ": report: " << r.all();
  }
  // A fresh folder holding nothing but the plan.
  r = run_in(alone, "check plan.json --terrain flat");
  EXPECT_EQ(r.code, 0) << "plan alone: check: " << r.all();
  r = run_in(alone, "simulate plan.json --terrain flat");
  EXPECT_EQ(r.code, 0) << "plan alone: simulate: " << r.all();
  fs::remove_all(alone);
  fs::remove_all(dir);
}

// The written robots' stance for the pallet: 0.28 m, two thirds of the stretched leg. At the
// import's default (75 %, 0.315 m) the 1 m pallet_10 crawl is not served: for the backward-kneed
// ones the start puts a front knee within 0.12 deg of its straight limit (post-hoc exit 4), the
// re-solve ends infeasible at the pallet's edge after 214 iterations; the forward-kneed one, on
// the gait timed to its size, leaves RH's KFE range by 0.85 deg at one sample between the joint
// rows' points (exit 4). A limit of the planner left as it is; Go2's own URDF plans there at the
// default.
const std::string kPalletStance = " --nominal-height 0.28";

// Writes `spec`'s URDF into a folder of its own and returns its path.
std::string written(const std::string& tag, const QuadrupedSpec& spec) {
  const fs::path dir = scratch("urdf_" + tag);
  std::ofstream(dir / "robot.urdf") << test_support::quadruped_urdf(spec);
  return (dir / "robot.urdf").string();
}

// The refusal names `what` and the flag; nothing is written.
void expect_refused(const std::string& tag, const std::string& urdf_path, const std::string& what,
                    const std::string& flag) {
  const fs::path dir = scratch("refused_" + tag);
  const CommandResult r = run_in(dir, "robot import " + urdf_path + " --out robot.yaml");
  EXPECT_EQ(r.code, 1) << tag << ": " << r.all();
  EXPECT_NE(r.err.find(what), std::string::npos) << tag << ": " << r.err;
  EXPECT_NE(r.err.find(flag), std::string::npos) << tag << ": " << r.err;
  EXPECT_FALSE(fs::exists(dir / "robot.yaml")) << tag;
  fs::remove_all(dir);
}

TEST(AnyQuadruped, MeshFeetAreRefusedThenImportedWithTheRadius) {
  QuadrupedSpec mesh;
  mesh.robot = "mesh_feet";
  mesh.mesh_feet = true;
  const std::string urdf = written("mesh", mesh);
  expect_refused("mesh", urdf, "FL_calf_joint", "--foot-radius");
  expect_end_to_end("mesh_feet", urdf, "--foot-radius 0.022" + kPalletStance);
}

TEST(AnyQuadruped, PlaceholderLimitsAreRefusedThenImportedWithTheMotorsLimits) {
  QuadrupedSpec placeholder;
  placeholder.robot = "placeholder";
  placeholder.effort_hip = placeholder.effort_knee = 1000;
  placeholder.velocity_hip = placeholder.velocity_knee = 1000;
  const std::string urdf = written("placeholder", placeholder);
  expect_refused("placeholder", urdf, "joint 'FL_hip_joint' has the effort limit 1000",
                 "--effort FL_hip_joint=");
  expect_end_to_end("placeholder", urdf,
                    "--effort haa,hfe=23.7 --effort kfe=45.43 --velocity haa,hfe=30.1 "
                    "--velocity kfe=15.7" +
                        kPalletStance);
}

TEST(AnyQuadruped, ReversedJointAxes) {
  QuadrupedSpec reversed;
  reversed.robot = "reversed";
  reversed.reversed_axes = true;
  expect_end_to_end("reversed", written("reversed", reversed), kPalletStance);
}

// Knees forward on every leg, other joint names and another writing order.
TEST(AnyQuadruped, KneesForwardOtherNamesAndOrder) {
  QuadrupedSpec forward;
  forward.robot = "forward";
  forward.knee = {-1, -1, -1, -1};
  forward.prefix = {"lf", "rf", "lh", "rh"};
  forward.haa = "_haa";
  forward.hfe = "_hfe";
  forward.kfe = "_kfe";
  forward.write_order = {3, 1, 2, 0};
  expect_end_to_end("forward", written("forward", forward), kPalletStance);
}

// HyQ's knees (front backward, hind forward); the base's centre of mass 4 cm ahead of and 3 cm
// above its frame.
TEST(AnyQuadruped, KneesInwardAndABaseFrameAwayFromTheCentreOfMass) {
  QuadrupedSpec x_knees;
  x_knees.robot = "x_knees";
  x_knees.knee = {+1, +1, -1, -1};
  x_knees.base_com_x = 0.04;
  x_knees.base_com_z = 0.03;
  expect_end_to_end("x_knees", written("x_knees", x_knees), kPalletStance);
}

// Import does the whole job: the robot file and its fitted force polytopes beside it, which
// `polytopes validate` reads back; with --no-fit the hint it prints is a command that works when
// pasted, and so is the hint of the planner's error for the missing polytopes.
TEST(AnyQuadruped, ImportFitsThePolytopesAndItsHintsWork) {
  const fs::path dir = scratch("hints");
  std::ofstream(dir / "quad.urdf") << test_support::quadruped_urdf({});
  CommandResult r = run_in(dir, "robot import quad.urdf --out fitted.yaml");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_TRUE(fs::exists(dir / "fitted.polytopes.yaml"));
  r = run_in(dir, "polytopes validate --robot ./fitted.yaml --samples 60");
  EXPECT_EQ(r.code, 0) << r.all();

  const auto hint_of = [](const std::string& text) {
    const size_t a = text.find("`terrastride ");
    const size_t b = a == std::string::npos ? a : text.find('`', a + 1);
    return a == std::string::npos || b == std::string::npos ? std::string()
                                                            : text.substr(a + 1, b - a - 1);
  };
  r = run_in(dir, "robot import quad.urdf --out quad.yaml --no-fit");
  ASSERT_EQ(r.code, 0) << r.all();
  const std::string hint = hint_of(r.out);
  ASSERT_FALSE(hint.empty()) << r.out;
  // The planner's own error for the missing file names the same fix.
  r = run_in(
      dir,
      "plan --robot quad.yaml --terrain flat --goal 0.3,0,0 --constraints all --out plan.json");
  EXPECT_NE(r.code, 0) << r.all();
  EXPECT_EQ(hint_of(r.all()), hint) << r.all();
  // Pasted.
  r = run_in(dir, hint.substr(std::string("terrastride ").size()) + " --samples 200");
  EXPECT_EQ(r.code, 0) << hint << ": " << r.all();
  EXPECT_TRUE(fs::exists(dir / "quad.polytopes.yaml"));
  r = run_in(
      dir,
      "plan --robot quad.yaml --terrain flat --goal 0.3,0,0 --constraints all --out plan.json");
  EXPECT_EQ(r.code, 0) << r.all();
  fs::remove_all(dir);
}

// Go2 with its knees' velocity limit cut from 15.7 to `kfe` rad/s, as robots/NAME.yaml in `dir`
// (its fitted polytopes beside it: the polytopes do not depend on velocity limits).
void write_slow_go2(const fs::path& dir, const std::string& kfe = "8.0",
                    const std::string& name = "go2_slow") {
  fs::create_directories(dir / "robots");
  const std::string data = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/";
  const auto read = [](const std::string& path) {
    std::ifstream in(path);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  const auto replace_all = [](std::string text, const std::string& from, const std::string& to) {
    for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
      text.replace(at, from.size(), to);
    return text;
  };
  std::string robot = replace_all(read(data + "go2.yaml"), "name: go2\n", "name: " + name + "\n");
  robot = replace_all(robot, "kfe: 15.7}", "kfe: " + kfe + "}");
  ASSERT_NE(robot.find("kfe: " + kfe + "}"), std::string::npos);
  std::ofstream(dir / "robots" / (name + ".yaml")) << robot;
  std::ofstream(dir / "robots" / (name + ".polytopes.yaml"))
      << replace_all(read(data + "go2.polytopes.yaml"), "robot: go2\n", "robot: " + name + "\n");
}

// A fast trot (1 m in 1.6 s) on a Go2 whose knees turn at 8 rad/s at most: planned without the
// joint rows its knees reach twice their limit, which `check` catches (exit 3, naming the leg and
// joint); `all` holds the limit and the check passes.
TEST(AnyQuadruped, FastTrotVelocityIsCaughtByTheCheckAndHeldByAll) {
  const fs::path dir = scratch("velocity");
  write_slow_go2(dir);
  const std::string trot =
      "plan --robot robots/go2_slow.yaml --terrain flat --gait trot --goal 1,0,0 --duration 1.6 ";
  CommandResult r = run_in(dir, trot + "--constraints baseline --out baseline.json");
  EXPECT_NE(r.code, 0) << r.all();  // the post-hoc velocity check fails the plan
  r = run_in(dir, "check baseline.json --terrain flat");
  EXPECT_EQ(r.code, 3) << r.all();
  EXPECT_NE(r.all().find("joint velocity above the limit"), std::string::npos) << r.all();
  EXPECT_NE(r.all().find("KFE"), std::string::npos) << r.all();
  r = run_in(dir, trot + "--constraints all --out all.json");
  ASSERT_EQ(r.code, 0) << r.all();
  r = run_in(dir, "check all.json --terrain flat --json");
  EXPECT_EQ(r.code, 0) << r.all();
  EXPECT_NE(r.out.find("\"velocity_violations\":0"), std::string::npos) << r.out;
  fs::remove_all(dir);
}

// The joint rows hold at their constraint points; between them a joint may still pass its limit:
// Go2 with 8 rad/s knees on a 1.4 s trot passed it by 0.9 % in a swing, with 1 rad/s knees on
// the default crawl by 41 % in the stance leaving rest. The planner's dense check finds these
// instants, adds joint rows there and solves again (plan.json's joint_refinement): both plans
// pass every post-hoc check at 1 ms samples.
TEST(AnyQuadruped, JointVelocitiesBetweenConstraintPointsAreHeldByRefinement) {
  const fs::path dir = scratch("refinement");
  write_slow_go2(dir);
  write_slow_go2(dir, "1.0", "go2_1rad");
  for (const std::string request :
       {"--robot robots/go2_slow.yaml --gait trot --goal 1,0,0 --duration 1.4",
        "--robot robots/go2_1rad.yaml"}) {
    SCOPED_TRACE(request);
    CommandResult r = run_in(dir, "plan --terrain flat --constraints all --sample-dt 0.001 " +
                                      request + " --out plan.json");
    ASSERT_EQ(r.code, 0) << r.all();
    std::ifstream in(dir / "plan.json");
    const nlohmann::json plan = nlohmann::json::parse(in);
    const nlohmann::json refinement = plan.value("joint_refinement", nlohmann::json());
    ASSERT_TRUE(refinement.is_object()) << r.all();
    EXPECT_GT(refinement["before"]["velocity_ratio"].get<double>(), 1.0);
    EXPECT_LE(refinement["after"]["velocity_ratio"].get<double>(), 1.0);
    EXPECT_TRUE(refinement["held"].get<bool>());
    EXPECT_GE(refinement["points"].get<int>(), 1);
    r = run_in(dir, "check plan.json --terrain flat --json");
    EXPECT_EQ(r.code, 0) << r.all();
    EXPECT_NE(r.out.find("\"velocity_violations\":0"), std::string::npos) << r.out;
  }
  fs::remove_all(dir);
}

// A quadruped whose motors turn at 0.3 rad/s (a variant URDF: the hip and knee velocity limits
// cut) is refused before any solve for the default 1 m crawl, naming the leg, the joint, the speed
// it needs, its limit and the --duration that would serve; no plan is written. The same robot
// walking that long passes the check before the solve.
TEST(AnyQuadruped, MotorsTooSlowForTheGaitAreRefusedBeforeTheSolve) {
  QuadrupedSpec slow;
  slow.robot = "slow_motors";
  slow.velocity_hip = slow.velocity_knee = 0.3;
  const std::string urdf = written("slow_motors", slow);
  const fs::path dir = scratch("slow_motors");
  CommandResult r = run_in(dir, "robot import " + urdf + " --out slow_motors.yaml");
  ASSERT_EQ(r.code, 0) << r.all();
  const std::string plan =
      "plan --robot slow_motors.yaml --terrain flat --goal 1,0,0 --out plan.json";
  r = run_in(dir, plan);
  EXPECT_EQ(r.code, 1) << r.all();
  for (const std::string part :
       {"--duration: robot 'slow_motors' cannot swing its legs fast enough", "crawl gait",
        "rad/s on average, above its limit of 0.3 rad/s", "--cycles"})
    EXPECT_NE(r.err.find(part), std::string::npos) << part << " in: " << r.err;
  EXPECT_FALSE(fs::exists(dir / "plan.json"));
  const std::string fix = "plan a slower walk: --duration ";
  const size_t at = r.err.find(fix);
  ASSERT_NE(at, std::string::npos) << r.err;
  const double hint = std::stod(r.err.substr(at + fix.size()));
  EXPECT_GT(hint, 10.0) << r.err;
  // The pre-check passes at that duration (a solve limited to a second: only the pre-check's
  // verdict matters here, not the plan's).
  r = run_in(dir, plan + " --duration " + std::to_string(hint) + " --max-time 1");
  EXPECT_EQ(r.err.find("cannot swing its legs fast enough"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

// A plan written before plans carried their robot names a robot that is not shipped: `check`
// says how to give it (--robot FILE) and works with it; a plan that carries its robot refuses a
// different --robot.
TEST(AnyQuadruped, PlansWithoutTheirRobotTakeItFromRobotFlag) {
  const fs::path dir = scratch("old_plan");
  write_slow_go2(dir);
  CommandResult r = run_in(dir,
                           "plan --robot robots/go2_slow.yaml --terrain flat --goal 0.3,0,0 "
                           "--constraints all --out plan.json");
  ASSERT_EQ(r.code, 0) << r.all();
  {
    std::ifstream in(dir / "plan.json");
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const size_t a = text.find("\n \"robot_file\":");
    ASSERT_NE(a, std::string::npos);
    const size_t b = text.find("\n \"", a + 1);  // the next top-level key
    text.erase(a, b - a);
    std::ofstream(dir / "old.json") << text;
  }
  r = run_in(dir, "check old.json --terrain flat");
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("--robot FILE"), std::string::npos) << r.err;
  r = run_in(dir, "check old.json --terrain flat --robot robots/go2_slow.yaml");
  EXPECT_EQ(r.code, 0) << r.all();
  r = run_in(dir, "check plan.json --terrain flat --robot go2");
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("is not the robot plan.json was planned with"), std::string::npos) << r.err;
  fs::remove_all(dir);
}

#define REQUIRE_SHARED_ROBOTS()                                           \
  if (!fs::is_directory(std::string(TERRASTRIDE_SHARED_DIR) + "/robots")) \
  GTEST_SKIP() << "no " << TERRASTRIDE_SHARED_DIR                         \
               << "/robots (the shared URDFs are not part of a user's clone)"

TEST(AnyQuadruped, Go2AndAnymalWorkEndToEnd) {
  REQUIRE_SHARED_ROBOTS();
  const std::string shared = std::string(TERRASTRIDE_SHARED_DIR) + "/robots/";
  expect_end_to_end("go2", shared + "go2/go2_description.urdf", "");
  std::string ranges;
  for (const std::string leg : {"LF", "RF", "LH", "RH"})
    ranges += " --joint-range " + leg + "_HFE=-90:90 --joint-range " + leg +
              (leg[1] == 'F' ? "_KFE=-150:-10" : "_KFE=10:150");
  expect_refused("anymal", shared + "anymal_c/anymal.urdf", "LF_HFE", "--joint-range LF_HFE");
  expect_end_to_end("anymal_c", shared + "anymal_c/anymal.urdf", ranges);
}

}  // namespace
}  // namespace terrastride
