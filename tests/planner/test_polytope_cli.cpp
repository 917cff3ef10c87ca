// `terrastride polytopes fit|validate` end to end: JSON figures, the written file, clear errors.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_command.hpp"
#include "terrastride/planner/polytope_model.hpp"
#include "terrastride/robot/robot_model.hpp"

namespace {

struct CliResult {
  int code = -1;
  std::string out;  // stdout only
  std::string all;  // stdout and stderr
};

CliResult run(const std::string& args) {
  const terrastride::test_support::CommandResult r =
      terrastride::test_support::run_terrastride(args);
  return {r.code, r.out, r.all()};
}

std::string temp_path(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("terrastride_polytope_cli_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

TEST(PolytopesCli, ValidatePrintsOneJsonObjectWithBothVariants) {
  const CliResult r = run("polytopes validate --robot hyq --samples 300 --json");
  ASSERT_EQ(r.code, 0) << r.all;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["legs"].size(), 4u);
  for (const char* v : {"ours", "paper", "paper_roll"}) {
    ASSERT_TRUE(j["all"].contains(v)) << v;
    EXPECT_EQ(j["all"][v]["samples"].get<int>(), 1200) << v;
  }
  EXPECT_LE(j["all"]["ours"]["rho_out_max"].get<double>(), 1.05);
  EXPECT_LE(j["all"]["ours"]["rho_out_median"].get<double>(), 1.02);
  EXPECT_GT(j["all"]["paper"]["rho_out_median"].get<double>(),
            j["all"]["ours"]["rho_out_median"].get<double>());
  EXPECT_EQ(j["legs"][0]["leg"], "LF");
}

TEST(PolytopesCli, FitWritesAFileThatValidateReads) {
  const std::string out = temp_path("monoped.polytopes.yaml");
  CliResult r =
      run("polytopes fit --robot monoped --samples 150 --l-refs 4 --alpha-refs 2 "
          "--threads 1 --seed 3 --json --out " +
          out);
  ASSERT_EQ(r.code, 0) << r.all;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["file"], out);
  ASSERT_EQ(j["legs"].size(), 1u);
  EXPECT_GT(j["legs"][0]["iterations"].get<int>(), 0);
  EXPECT_LT(j["legs"][0]["final_cost"].get<double>(), j["legs"][0]["initial_cost"].get<double>());
  ASSERT_TRUE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(out + ".tmp"));
  r = run("polytopes validate --robot monoped --samples 200 --json --file " + out);
  ASSERT_EQ(r.code, 0) << r.all;
  const auto v = nlohmann::json::parse(r.out);
  EXPECT_LT(v["all"]["ours"]["rho_out_median"].get<double>(), 1.05);
  std::filesystem::remove(out);
}

// Go2's four legs are one leg mirrored and translated: the fit says which legs it copied, in the
// JSON and in the table, and fits only the first.
TEST(PolytopesCli, FitSaysWhichLegsAreCopiesOfATwin) {
  const std::string out = temp_path("go2.polytopes.yaml");
  CliResult r = run("polytopes fit --robot go2 --threads 1 --json --out " + out);
  ASSERT_EQ(r.code, 0) << r.all;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["legs"].size(), 4u);
  EXPECT_FALSE(j["legs"][0].contains("copied_from")) << j["legs"][0].dump();
  for (int i = 1; i < 4; ++i) {
    ASSERT_TRUE(j["legs"][i].contains("copied_from")) << j["legs"][i].dump();
    EXPECT_NE(j["legs"][i]["copied_from"].get<std::string>().find("LF"), std::string::npos);
  }
  r = run("polytopes fit --robot go2 --threads 1 --out " + out);
  ASSERT_EQ(r.code, 0) << r.all;
  EXPECT_NE(r.out.find("RF   LF mirrored in y (not fitted)"), std::string::npos) << r.out;
  std::filesystem::remove(out);
}

TEST(PolytopesCli, BadInputFailsWithAMessageNamingIt) {
  CliResult r = run("polytopes validate --robot hyq --file /nonexistent/p.yaml");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all.find("/nonexistent/p.yaml"), std::string::npos) << r.all;
  EXPECT_NE(r.all.find("polytopes fit"), std::string::npos) << r.all;

  r = run("polytopes fit --robot hyq --samples 0 --out " + temp_path("never.yaml"));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all.find("--samples"), std::string::npos) << r.all;
  EXPECT_FALSE(std::filesystem::exists(temp_path("never.yaml")));

  r = run("polytopes fit --robot nosuchrobot");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all.find("nosuchrobot"), std::string::npos) << r.all;

  // Fitted for another robot: hyq's file is not monoped's.
  const std::string hyq_file =
      std::string(TERRASTRIDE_TEST_DATA_DIR) + "/robots/hyq.polytopes.yaml";
  r = run("polytopes validate --robot monoped --file " + hyq_file);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all.find("hyq"), std::string::npos) << r.all;

  // An unwritable output leaves nothing behind and names the path.
  r =
      run("polytopes fit --robot monoped --samples 100 --l-refs 3 --alpha-refs 1 "
          "--out /nonexistent/dir/p.yaml");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all.find("/nonexistent/dir/p.yaml"), std::string::npos) << r.all;
}

}  // namespace
