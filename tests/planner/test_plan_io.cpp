// plan.json round trip, validation of malformed plan files, interpolation between samples, and
// measured start states in plan.json's conventions.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "support/fuzz_replay.hpp"
#include "terrastride/planner/piece_math.hpp"
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
  const auto path = (std::filesystem::temp_directory_path() /
                     ("terrastride_plan_io_" + std::to_string(::getpid()) + ".json"))
                        .string();
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
  // The written file has the layout of docs/formats.md, "plan.json".
  const json j = plan_to_json(t);
  EXPECT_TRUE(j["samples"][0]["base"].contains("angular_acceleration"));
  EXPECT_TRUE(j["samples"][0]["feet"][0].contains("contact"));
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp." + std::to_string(::getpid())));
}

// The samples serialised ahead (terrastride plan does it while the post-hoc checks run) give
// the very text of the whole document's dump, whatever the other keys hold: extra keys sorting
// before and after "samples", strings that look like the key, nested "samples" keys, no samples.
TEST(PlanIo, SamplesSerialisedAheadGiveTheSameText) {
  Trajectory t = two_sample_plan();
  t.extra["post_hoc"] = {{"terrain", "map \n \"samples\": null"}, {"samples", json::array({1, 2})}};
  t.extra["zzz_after"] = json::object({{"a", json::array({json::object({{"b", "x\ny"}})})}});
  t.extra["aaa_before"] = "\n \"samples\": null";
  t.extra["samples"] = "an extra key of the same name loses to the samples";
  const std::string whole = plan_to_json(t).dump(1) + "\n";
  const SerialisedSamples ahead = serialise_samples(t.samples);
  EXPECT_EQ(plan_text(t, &ahead), whole);
  EXPECT_EQ(plan_text(t), whole);
  ASSERT_NE(whole.find("\"samples\": [\n  {\n   \"base\""), std::string::npos) << whole;

  Trajectory empty = t;
  empty.samples.clear();
  const SerialisedSamples none = serialise_samples(empty.samples);
  EXPECT_EQ(plan_text(empty, &none), plan_to_json(empty).dump(1) + "\n");

  // Another plan's samples are refused, not spliced in.
  EXPECT_THROW(plan_text(empty, &ahead), std::logic_error);
  Trajectory shifted = t;
  shifted.samples.back().t += 0.01;
  EXPECT_THROW(plan_text(shifted, &ahead), std::logic_error);

  // And the file written with them reads back as the plan.
  const auto path = (std::filesystem::temp_directory_path() /
                     ("terrastride_plan_ahead_" + std::to_string(::getpid()) + ".json"))
                        .string();
  write_plan_file(path, t, &ahead);
  std::ifstream in(path);
  const std::string written((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(written, whole);
  EXPECT_EQ(read_plan_file(path).samples.size(), t.samples.size());
  std::filesystem::remove(path);
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
  const auto bad = (std::filesystem::temp_directory_path() /
                    ("terrastride_bad_plan_" + std::to_string(::getpid()) + ".json"))
                       .string();
  std::ofstream(bad) << "{ not json";
  try {
    read_plan_file(bad);
    FAIL();
  } catch (const PlanFileError& e) {
    EXPECT_NE(std::string(e.what()).find("not valid JSON"), std::string::npos);
  }
  EXPECT_THROW(write_plan_file("/nonexistent/dir/plan.json", two_sample_plan()), PlanFileError);
}

// An integer field wider than an int is refused rather than wrapped (4294967297 read as 1).
TEST(PlanIo, IntegersBeyondAnIntAreRefused) {
  json j = plan_to_json(two_sample_plan());
  j["solver"]["iterations"] = 4294967297ULL;
  EXPECT_EQ(error_of(j), "p.json: solver.iterations: is 4294967297, beyond the range of an int");
  j["solver"]["iterations"] = -3000000000LL;
  EXPECT_EQ(error_of(j), "p.json: solver.iterations: is -3000000000, beyond the range of an int");
  j["solver"]["iterations"] = 2147483647;
  EXPECT_EQ(error_of(j), "");
}

// A plan file nested deeper than perception::kMaxJsonNesting is refused when it is parsed: its
// extra keys are copied into the Trajectory and written back, and copying and dumping recurse
// once per level (1 MB of '[' overflowed the stack). Nesting up to the cap reads and writes back.
TEST(PlanIo, PlanFilesNestedBeyondTheCapAreRefused) {
  const auto path = (std::filesystem::temp_directory_path() /
                     ("terrastride_deep_plan_" + std::to_string(::getpid()) + ".json"))
                        .string();
  const std::string good = plan_to_json(two_sample_plan()).dump();
  const auto with_extra = [&](std::size_t levels) {
    std::ofstream(path) << good.substr(0, good.size() - 1) << ",\"notes\":"
                        << std::string(levels, '[') << std::string(levels, ']') << "}";
  };
  with_extra(99);  // 100 levels with the document's own object
  const Trajectory read = read_plan_file(path);
  EXPECT_EQ(plan_to_json(read)["notes"].dump(), std::string(99, '[') + std::string(99, ']'));
  for (const std::size_t levels : {std::size_t{100}, std::size_t{1} << 20}) {
    with_extra(levels);
    try {
      read_plan_file(path);
      ADD_FAILURE() << levels << " levels read";
    } catch (const PlanFileError& e) {
      EXPECT_NE(std::string(e.what()).find(path + ": not valid JSON: "), std::string::npos);
      EXPECT_NE(std::string(e.what()).find("nested more than 100 levels deep"), std::string::npos)
          << e.what();
    }
  }
  std::filesystem::remove(path);
}

// The plan fuzz target on every seed and a few mutations of each (tests/fuzz/corpus_plan): none
// crashes or traps. The seeds that are plans read; the hostile ones are refused.
TEST(PlanIo, FuzzCorpusReplay) {
  const std::filesystem::path corpus =
      std::filesystem::path(TERRASTRIDE_SOURCE_DIR) / "tests" / "fuzz" / "corpus_plan";
  ASSERT_TRUE(std::filesystem::is_directory(corpus)) << corpus;
  int read = 0;
  for (const auto& entry : std::filesystem::directory_iterator(corpus)) {
    try {
      (void)read_plan_file(entry.path().string());
      ++read;
    } catch (const PlanFileError&) {
    }
  }
  const int seeds = terrastride::test_support::replay_fuzz_corpus(corpus);
  EXPECT_GE(seeds, 10);
  // minimal, nested_at_cap, huge_times and the three robot_file plans (the robot is parsed later)
  EXPECT_EQ(read, 6);
}

// write_plan_file writes as `terrastride plan --out` does (perception::write_file_atomically): a
// symbolic link stays a link and its target gets the plan, a FIFO is written through (a temporary
// renamed over it would replace the FIFO and its reader would wait forever), /dev/null works.
TEST(PlanIo, WritesThroughLinksFifosAndDevices) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("terrastride_plan_io_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const Trajectory t = two_sample_plan();
  const std::string text = plan_to_json(t).dump(1) + "\n";

  std::ofstream((dir / "target.json").string()) << "old";
  fs::create_symlink("target.json", dir / "link.json");
  write_plan_file((dir / "link.json").string(), t);
  EXPECT_TRUE(fs::is_symlink(dir / "link.json"));
  EXPECT_EQ(read_plan_file((dir / "target.json").string()).samples.size(), t.samples.size());

  const std::string fifo = (dir / "plan.fifo").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string received;
  std::thread reader([&] {
    std::ifstream in(fifo, std::ios::binary);
    received.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  });
  write_plan_file(fifo, t);
  reader.join();
  EXPECT_EQ(received, text);
  EXPECT_TRUE(fs::is_fifo(fifo));

  EXPECT_NO_THROW(write_plan_file("/dev/null", t));
  // Nothing else was left in the folder (no temporaries).
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"link.json", "plan.fifo", "target.json"}));
  fs::remove_all(dir);
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

namespace {

std::string start_state_error(const json& j) {
  try {
    start_state_from_json(j, "state.json", two_sample_plan(), 0.015);
  } catch (const PlanFileError& e) {
    return e.what();
  }
  return "";
}

void expect_same_start(const SrbdProblem::StartState& a, const SrbdProblem::StartState& b) {
  EXPECT_EQ(a.position, b.position);
  EXPECT_EQ(a.euler_zyx, b.euler_zyx);
  EXPECT_EQ(a.linear_velocity, b.linear_velocity);
  EXPECT_EQ(a.euler_rates, b.euler_rates);
  EXPECT_EQ(a.foot_position, b.foot_position);
  EXPECT_EQ(a.foot_velocity, b.foot_velocity);
}

}  // namespace

// A measured state need not hold every field: what it leaves out is the previous plan's state at
// the start time, exactly as a re-plan without a measured state would start.
TEST(StartState, FieldsLeftOutAreThePlansStateAtTheStartTime) {
  Trajectory plan = two_sample_plan();
  for (auto& s : plan.samples) s.base.angular_velocity = Eigen::Vector3d(0.1, -0.2, 0.3);
  expect_same_start(start_state_from_json(json::object(), "state.json", plan, 0.015),
                    start_state_of(plan, 0.015));

  const json given = {{"base", {{"position", {1.0, 2.0, 0.5}}}},
                      {"feet", {{"RF", {{"velocity", {0.0, 0.0, 1.0}}}}}}};
  const SrbdProblem::StartState s = start_state_from_json(given, "state.json", plan, 0.015);
  SrbdProblem::StartState expected = start_state_of(plan, 0.015);
  expected.position = Eigen::Vector3d(1.0, 2.0, 0.5);
  expected.foot_velocity[1] = Eigen::Vector3d(0.0, 0.0, 1.0);
  expect_same_start(s, expected);
}

// plan.json's angular velocity is in the world frame; the planner's start state holds ZYX Euler
// rates. Converted back with the planner's own kinematics, the rates give the angular velocity.
TEST(StartState, AngularVelocityBecomesEulerRatesAtTheGivenOrientation) {
  const Eigen::Vector3d euler(0.3, 0.2, -0.1), omega(0.4, -0.5, 0.6);
  const json given = {{"base",
                       {{"euler_zyx", {euler.x(), euler.y(), euler.z()}},
                        {"angular_velocity", {omega.x(), omega.y(), omega.z()}}}}};
  const SrbdProblem::StartState s =
      start_state_from_json(given, "state.json", two_sample_plan(), 0.015);
  EXPECT_EQ(s.euler_zyx, euler);
  EXPECT_EQ(s.euler_rates, euler_rates_of(euler, omega));
  Eigen::Vector3d back;
  euler_to_angular<double>(euler, s.euler_rates, Eigen::Vector3d::Zero(), &back, nullptr);
  EXPECT_NEAR((back - omega).norm(), 0.0, 1e-12);
}

TEST(StartState, MalformedStatesNameTheField) {
  // JSON text cannot hold infinity (nlohmann refuses 1e999), but a json value built in code can.
  const json inf = {{"base", {{"position", {std::numeric_limits<double>::infinity(), 0.0, 0.5}}}}};
  for (const auto& [state, says] : std::vector<std::pair<json, std::string>>{
           {json::array(), "state.json: top level: must be an object"},
           {{{"base", 3}}, "state.json: base: must be an object"},
           {{{"base", {{"position", {0.0, 0.0}}}}},
            "state.json: base.position: must be an array of 3 numbers"},
           {{{"base", {{"linear_velocity", "fast"}}}},
            "state.json: base.linear_velocity: must be an array of 3 numbers"},
           {{{"base", {{"position", {0.0, nullptr, 0.5}}}}},
            "state.json: base.position: element 1 is not a finite number"},
           {inf, "state.json: base.position: element 0 is not finite"},
           {{{"base", {{"postion", {0.0, 0.0, 0.5}}}}},
            "state.json: base.postion: unknown field (known: position, euler_zyx, "
            "linear_velocity, angular_velocity)"},
           {{{"base", {{"euler_zyx", {0.0, M_PI / 2, 0.0}}}}},
            "state.json: base.euler_zyx: pitch 1.570796 rad is at +-pi/2"},
           {{{"feet", json::array()}}, "state.json: feet: must be an object keyed by foot name"},
           {{{"feet", {{"XX", {{"position", {0.0, 0.0, 0.0}}}}}}},
            "state.json: feet.XX: unknown foot (the plan's feet: LF, RF)"},
           {{{"feet", {{"LF", {{"force", {0.0, 0.0, 0.0}}}}}}},
            "state.json: feet.LF.force: unknown field (known: position, velocity)"},
           {{{"feet", {{"LF", {{"velocity", {0.0, 0.0, 0.0, 1.0}}}}}}},
            "state.json: feet.LF.velocity: must be an array of 3 numbers"},
           {{{"time", 0.1}}, "state.json: time: unknown field (known: base, feet)"}}) {
    const std::string e = start_state_error(state);
    EXPECT_NE(e.find(says), std::string::npos) << state.dump() << " -> '" << e << "'";
  }
}

// ProblemOptions::start_lead: how far a re-plan's start lies ahead of the plan's state
// at that time along the options' path line (a diagonal one here); 0 when behind it, beside it,
// or without a line.
TEST(StartLead, IsTheStartsLeadOverThePlanAlongThePathLine) {
  const Trajectory plan = two_sample_plan();
  ProblemOptions o;
  o.has_path_line = true;
  o.path_line_start = Eigen::Vector2d(0.0, 0.0);
  o.path_line_end = Eigen::Vector2d(3.0, 4.0);  // along (0.6, 0.8), across (-0.8, 0.6)
  const Eigen::Vector2d along(0.6, 0.8), across(-0.8, 0.6);
  const SrbdProblem::StartState on_plan = start_state_of(plan, 0.015);
  auto lead_of = [&](const Eigen::Vector2d& shift, const ProblemOptions& options) {
    SrbdProblem::StartState s = on_plan;
    s.position.head<2>() += shift;
    ProblemOptions out = options;
    out.start_lead = 123.0;  // overwritten
    set_start_lead_of(plan, 0.015, s, &out);
    return out.start_lead;
  };
  EXPECT_NEAR(lead_of(Eigen::Vector2d::Zero(), o), 0.0, 1e-12);
  EXPECT_NEAR(lead_of(0.03 * along, o), 0.03, 1e-12);
  EXPECT_NEAR(lead_of(0.03 * along + 0.05 * across, o), 0.03, 1e-12);
  EXPECT_EQ(lead_of(-0.03 * along, o), 0.0);
  EXPECT_EQ(lead_of(0.05 * across, o), 0.0);
  ProblemOptions no_line;
  EXPECT_EQ(lead_of(0.03 * along, no_line), 0.0);
}

// A plan carries the robot file it was made with ("robot_file": its text and content hash), and
// robot_of_plan returns that robot, never the shipped file of the same name; plans without one
// (written before) keep naming a shipped robot.
TEST(PlanRobot, ThePlanCarriesItsRobotAndNoSameNamedOneReplacesIt) {
  namespace fs = std::filesystem;
  const std::string shipped = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.yaml";
  const terrastride::robot::RobotModel hyq = terrastride::robot::load_robot(shipped);
  ASSERT_FALSE(hyq.definition.empty());
  // Another robot named hyq: the shipped file 2 kg heavier.
  std::string text = hyq.definition;
  const std::size_t at = text.find("mass:");
  ASSERT_NE(at, std::string::npos);
  const std::size_t end = text.find('\n', at);
  const double mass = std::stod(text.substr(at + 5, end - at - 5));
  text.replace(at, end - at, "mass: " + std::to_string(mass + 2.0));
  const terrastride::robot::RobotModel heavier = terrastride::robot::parse_robot(text, "heavier");
  ASSERT_EQ(heavier.name, "hyq");

  Trajectory t = two_sample_plan();
  t.robot_definition = heavier.definition;
  const json j = plan_to_json(t);
  ASSERT_TRUE(j.contains("robot_file"));
  EXPECT_EQ(j["robot_file"]["hash"], terrastride::robot::robot_definition_hash(text));
  const Trajectory back = plan_from_json(j, "p.json");
  EXPECT_EQ(back.robot_definition, text);
  EXPECT_FALSE(back.extra.contains("robot_file"));
  const auto carried = robot_of_plan(back, "p.json");
  EXPECT_DOUBLE_EQ(carried.mass, heavier.mass);
  EXPECT_NE(carried.mass, hyq.mass);

  // The shipped definition itself is recognised as the shipped file (its polytopes beside it).
  t.robot_definition = hyq.definition;
  EXPECT_TRUE(fs::equivalent(robot_of_plan(plan_from_json(plan_to_json(t), "p.json"), "p.json")
                                 .source_file,
                             shipped));
  // A plan written before plans carried their robot: the shipped robot of its name.
  t.robot_definition.clear();
  EXPECT_FALSE(plan_to_json(t).contains("robot_file"));
  EXPECT_DOUBLE_EQ(robot_of_plan(t, "p.json").mass, hyq.mass);
}

TEST(PlanRobot, AnAlteredOrMismatchedRobotDefinitionIsRefusedByField) {
  Trajectory t = two_sample_plan();
  t.robot_definition = terrastride::robot::load_robot(std::string(TERRASTRIDE_TEST_DATA_DIR) +
                                                      "/robots/go2.yaml")
                           .definition;
  json j = plan_to_json(t);
  json altered = j;
  altered["robot_file"]["yaml"] = j["robot_file"]["yaml"].get<std::string>() + "# edited\n";
  EXPECT_NE(error_of(altered).find("p.json: robot_file.hash: is "), std::string::npos)
      << error_of(altered);
  // "robot" says hyq, the definition is go2's.
  try {
    robot_of_plan(plan_from_json(j, "p.json"), "p.json");
    ADD_FAILURE() << "a go2 definition under the name hyq was accepted";
  } catch (const PlanFileError& e) {
    EXPECT_NE(std::string(e.what()).find("defines robot 'go2'"), std::string::npos) << e.what();
  }
  json broken = j;
  broken["robot_file"]["yaml"] = "name: [";
  broken["robot_file"]["hash"] = terrastride::robot::robot_definition_hash("name: [");
  try {
    robot_of_plan(plan_from_json(broken, "p.json"), "p.json");
    ADD_FAILURE() << "an invalid robot definition was accepted";
  } catch (const PlanFileError& e) {
    EXPECT_NE(std::string(e.what()).find("p.json: robot_file.yaml"), std::string::npos) << e.what();
  }
}
