// The command line: help, unknown commands, bad flags, robot subcommands.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "support/run_command.hpp"

namespace {

// stdout and stderr together, as a user sees them.
struct CliResult {
  int code = -1;
  std::string out;
};

CliResult run(const std::string& args) {
  const terrastride::test_support::CommandResult r =
      terrastride::test_support::run_terrastride(args);
  return {r.code, r.all()};
}

}  // namespace

TEST(Cli, HelpListsSubcommands) {
  const CliResult r = run("--help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("robot"), std::string::npos);
}

TEST(Cli, EverySubcommandHasHelp) {
  for (const char* sub : {"robot", "robot fk", "robot ik", "robot show"}) {
    const CliResult r = run(std::string(sub) + " --help");
    EXPECT_EQ(r.code, 0) << sub;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub << ": " << r.out;
  }
}

TEST(Cli, UnknownSubcommandAndBadFlagsFail) {
  CliResult r = run("fly");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.out.find("fly"), std::string::npos) << r.out;
  r = run("robot fk --bogus");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("--bogus"), std::string::npos) << r.out;
  r = run("");
  EXPECT_NE(r.code, 0);
}

TEST(Cli, RobotFkAndIkRoundTrip) {
  CliResult r = run("robot fk --robot hyq --leg LF --q -0.2,0.75,-1.5");
  ASSERT_EQ(r.code, 0) << r.out;
  const auto fk = nlohmann::json::parse(r.out);
  EXPECT_NEAR(fk["foot"][0].get<double>(), 0.367, 5e-4);
  EXPECT_EQ(fk["force_polytope_vertices"].size(), 8u);
  r = run("robot ik --leg LF --foot 0.367,0.323,-0.574");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NEAR(nlohmann::json::parse(r.out)["q"][1].get<double>(), 0.75, 2e-3);
}

TEST(Cli, BadInputNamesTheProblem) {
  CliResult r = run("robot ik --leg LF --foot 0,0,-3");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("out of reach"), std::string::npos) << r.out;
  r = run("robot fk --leg XX --q 0,0,0");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("no leg 'XX'"), std::string::npos) << r.out;
  r = run("robot fk --q 0,nan,0");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("--q"), std::string::npos) << r.out;
  r = run("robot show --robot nosuchbot");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("unknown robot 'nosuchbot'"), std::string::npos) << r.out;
  // Settings of the constraint sets: unknown names, non-numbers and out-of-range values are named
  // before any solve.
  for (const auto& [arg, says] : std::vector<std::pair<std::string, std::string>>{
           {"bogus=1", "unknown feasibility setting 'bogus'"},
           {"swing_acceleration=fast", "swing_acceleration = 'fast' is not a number"},
           {"shin_points=2.5", "shin_points = 2.5: must be an integer"},
           {"joint_margin=-1", "joint_margin = -1: must be in [0, 0.5] rad"},
           {"swing_acceleration", "is not NAME=VALUE"}}) {
    r = run("plan --terrain flat --out /nonexistent/never.json --feasibility " + arg);
    EXPECT_NE(r.code, 0) << arg;
    EXPECT_NE(r.out.find("--feasibility"), std::string::npos) << arg << ": " << r.out;
    EXPECT_NE(r.out.find(says), std::string::npos) << arg << ": " << r.out;
  }
}
