// `report --batch` at scale: scans committed one by one, killed runs resumed to the
// very bytes of an uninterrupted run, shards running at once over one output folder, the index
// rebuilt from what exists, exit codes that tell "some scans failed" from "could not run".
// The 20-scan x 5-trial version of the kill test is scripts/batch/kill_resume_bench.sh.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::perception::test::ScratchDir;
using terrastride::test_support::CommandResult;
using terrastride::test_support::run_command;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

const std::string kScans = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/";

std::string q(const fs::path& p) {
  return shell_quote(p.string());
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Every file under `dir` (hidden ones too) by relative path, with its bytes; folders as "/".
std::map<std::string, std::string> tree(const fs::path& dir) {
  std::map<std::string, std::string> t;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string rel = e.path().lexically_relative(dir).string();
    t[rel] = e.is_directory() ? "/" : slurp(e.path());
  }
  return t;
}

// Names that differ between two trees (missing on one side or different bytes).
std::string tree_difference(const std::map<std::string, std::string>& a,
                            const std::map<std::string, std::string>& b) {
  std::string diff;
  for (const auto& [k, v] : a) {
    auto it = b.find(k);
    if (it == b.end())
      diff += "\n  only in the first: " + k;
    else if (it->second != v)
      diff += "\n  differs: " + k;
  }
  for (const auto& [k, v] : b)
    if (!a.count(k)) diff += "\n  only in the second: " + k;
  return diff;
}

void write_map_dir(const fs::path& dir, const std::string& scene_name) {
  const auto scene = terrastride::terrain::make_scene(scene_name);
  const auto map = terrastride::terrain::TerrainMap::from_scene(*scene, 0.02, {0.02, 0.05});
  fs::create_directories(dir / "layers");
  json meta = terrastride::terrain::write_terrain_layers(*map, dir.string());
  std::ofstream(dir / "terrain.json") << meta.dump(1);
}

// A small batch: four scanned clouds (one pose each), two map folders, one broken file.
fs::path make_scans(const fs::path& root) {
  const fs::path scans = root / "scans";
  fs::create_directories(scans);
  for (const char* name : {"flat", "stairs", "gap", "pallet_10"})
    fs::copy_file(kScans + name + ".pcd", scans / (std::string(name) + ".pcd"));
  write_map_dir(scans / "eur_pallet_map", "eur_pallet");
  write_map_dir(scans / "pallet_15_map", "pallet_15");
  std::ofstream(scans / "broken.pcd") << "not a point cloud\n";
  return scans;
}

pid_t spawn_terrastride(const std::string& args) {
  const std::string cmd =
      "exec " + std::string(TERRASTRIDE_BINARY) + " " + args + " >/dev/null 2>&1";
  const char* argv[] = {"sh", "-c", cmd.c_str(), nullptr};
  pid_t pid = -1;
  if (::posix_spawn(&pid, "/bin/sh", nullptr, nullptr, const_cast<char**>(argv), environ) != 0)
    return -1;
  return pid;
}

int wait_exit(pid_t pid) {
  int status = 0;
  ::waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(ReportBatch, KilledAtRandomMomentsAndResumedEqualsOneUninterruptedRun) {
  ScratchDir dir;
  const fs::path scans = make_scans(dir.path());
  const std::string args = "report --batch " + q(scans) + " --out ";
  const auto t0 = std::chrono::steady_clock::now();
  const CommandResult ref = run_terrastride(args + q(dir.path() / "reference"));
  const double full_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(ref.code, 3) << "one scan is broken: 'some scans failed'\n" << ref.all();
  const auto reference = tree(dir.path() / "reference");
  ASSERT_TRUE(reference.count("flat/flat.html"));
  ASSERT_TRUE(reference.count("broken/summary.json"));

  std::mt19937 random(21);  // fixed: the same kill moments every run of the test
  std::uniform_real_distribution<double> moment(0.0, full_s);
  int killed_mid_run = 0;
  for (int trial = 0; trial < 3; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const fs::path out = dir.path() / ("trial" + std::to_string(trial));
    // Two kills at random moments (the second one resuming the first), then a resume to the end.
    for (int kill = 0; kill < 2; ++kill) {
      const pid_t pid = spawn_terrastride(args + q(out) + " --resume");
      ASSERT_GT(pid, 0);
      std::this_thread::sleep_for(std::chrono::duration<double>(moment(random)));
      int status = 0;
      if (::waitpid(pid, &status, WNOHANG) == 0) {
        ::kill(pid, SIGKILL);
        ::waitpid(pid, &status, 0);
        ++killed_mid_run;
      }
    }
    const CommandResult r = run_terrastride(args + q(out) + " --resume");
    EXPECT_EQ(r.code, 3) << r.all();
    EXPECT_EQ(tree_difference(reference, tree(out)), "");
  }
  std::cerr << "[kill -9] " << killed_mid_run << " of 6 runs killed before they finished (batch "
            << full_s << " s)\n";
  EXPECT_GT(killed_mid_run, 0);
}

TEST(ReportBatch, FourShardsAtOnceEqualOneProcess) {
  ScratchDir dir;
  const fs::path scans = make_scans(dir.path());
  const std::string args = "report --batch " + q(scans) + " --out ";
  ASSERT_EQ(run_terrastride(args + q(dir.path() / "one")).code, 3);
  std::vector<pid_t> shards;
  for (int i = 0; i < 4; ++i)
    shards.push_back(spawn_terrastride(args + q(dir.path() / "four") + " --shard " +
                                       std::to_string(i) + "/4"));
  std::vector<int> codes;
  for (pid_t pid : shards) codes.push_back(wait_exit(pid));
  // Scans in name order: broken, eur_pallet_map, flat, gap, pallet_10, pallet_15_map, stairs;
  // broken (k = 0) is shard 0's, which alone reports a failure.
  EXPECT_EQ(codes, (std::vector<int>{3, 0, 0, 0}));
  EXPECT_EQ(tree_difference(tree(dir.path() / "one"), tree(dir.path() / "four")), "");
  const json index = json::parse(slurp(dir.path() / "four" / "index.json"));
  EXPECT_EQ(index["scans"], 7);
  EXPECT_EQ(index["finished"], 6);
  EXPECT_EQ(index["failed"], 1);
  EXPECT_EQ(index["complete"], true);
  EXPECT_FALSE(index.contains("generated_utc"));
}

TEST(ReportBatch, IndexListsScansOtherShardsHaveNotRunYet) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  fs::create_directories(scans);
  for (const char* name : {"a", "b", "c"}) write_map_dir(scans / name, "flat");
  const fs::path out = dir.path() / "out";
  const CommandResult r =
      run_terrastride("report --batch " + q(scans) + " --out " + q(out) + " --shard 1/2 --json");
  ASSERT_EQ(r.code, 0) << r.all();
  const json index = json::parse(slurp(out / "index.json"));
  EXPECT_EQ(index["finished"], 1);  // b (k = 1)
  EXPECT_EQ(index["pending"], 2);
  EXPECT_EQ(index["complete"], false);
  EXPECT_EQ(index["reports"][0]["scan"], "b");
  EXPECT_TRUE(index["reports"][1]["pending"].get<bool>());
  EXPECT_FALSE(fs::exists(out / "a"));
  // The other shard completes the index; a resume of the first skips its finished scan.
  ASSERT_EQ(run_terrastride("report --batch " + q(scans) + " --out " + q(out) + " --shard 0/2")
                .code,
            0);
  EXPECT_EQ(json::parse(slurp(out / "index.json"))["complete"], true);
  const CommandResult again = run_terrastride("report --batch " + q(scans) + " --out " + q(out) +
                                              " --shard 1/2 --resume --json");
  ASSERT_EQ(again.code, 0) << again.all();
  const json summary = json::parse(again.out);
  EXPECT_EQ(summary["skipped"], 1);
  EXPECT_EQ(summary["reported"], 0);
}

TEST(ReportBatch, ShardIndexFromKubernetesOrSlurmEnvironment) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  fs::create_directories(scans);
  for (const char* name : {"a", "b", "c"}) write_map_dir(scans / name, "flat");
  const std::string bin = std::string(TERRASTRIDE_BINARY);
  const auto run_env = [&](const std::string& env, const std::string& out,
                           const std::string& shard) {
    return run_command("env -u JOB_COMPLETION_INDEX -u SLURM_ARRAY_TASK_ID -u "
                       "SLURM_ARRAY_TASK_MIN " +
                       env + " " + bin + " report --batch " + q(scans) + " --out " +
                       q(dir.path() / out) + " --shard " + shard + " --json");
  };
  CommandResult r = run_env("JOB_COMPLETION_INDEX=2", "k8s", "3");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_EQ(json::parse(r.out)["shard"], "2/3");
  EXPECT_TRUE(fs::exists(dir.path() / "k8s" / "c" / "c.html"));
  EXPECT_FALSE(fs::exists(dir.path() / "k8s" / "a"));
  // A Slurm array numbered 1..3: task 1 is shard 0.
  r = run_env("SLURM_ARRAY_TASK_ID=1 SLURM_ARRAY_TASK_MIN=1", "slurm", "3");
  ASSERT_EQ(r.code, 0) << r.all();
  EXPECT_EQ(json::parse(r.out)["shard"], "0/3");
  EXPECT_TRUE(fs::exists(dir.path() / "slurm" / "a" / "a.html"));
  // Could not run (exit 1): no index in the environment, an index past the count, bad text.
  for (const auto& [env, shard, words] :
       std::vector<std::tuple<std::string, std::string, std::string>>{
           {"", "3", "JOB_COMPLETION_INDEX"},
           {"JOB_COMPLETION_INDEX=3", "3", "not below the count"},
           {"", "1/x", "not a whole number"},
           {"", "0/0", "at least 1"}}) {
    r = run_env(env, "bad", shard);
    EXPECT_EQ(r.code, 1) << shard << r.all();
    EXPECT_NE(r.err.find(words), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir.path() / "bad"));
  }
}

TEST(ReportBatch, ManifestListsScansRelativeToItsFolder) {
  ScratchDir dir;
  fs::create_directories(dir.path() / "x" / "deep");
  fs::copy_file(kScans + "flat.pcd", dir.path() / "x" / "flat.pcd");
  fs::copy_file(kScans + "flat.1.pcd", dir.path() / "x" / "flat.1.pcd");
  write_map_dir(dir.path() / "x" / "deep" / "steps", "stairs");
  std::ofstream(dir.path() / "x" / "list.txt")
      << "# two scans\nflat.pcd\nflat.1.pcd\n\n" << (dir.path() / "x" / "deep" / "steps").string()
      << "\n";
  const fs::path out = dir.path() / "out";
  CommandResult r = run_terrastride("report --batch " + q(dir.path() / "x" / "list.txt") +
                                    " --out " + q(out));
  ASSERT_EQ(r.code, 0) << r.all();
  const json index = json::parse(slurp(out / "index.json"));
  ASSERT_EQ(index["scans"], 2);
  for (const json& row : index["reports"]) {
    if (row["scan"] == "flat") {
      EXPECT_EQ(row["files"].size(), 2u);  // both poses mapped together
    }
  }

  std::ofstream(dir.path() / "bad.txt") << "flat.pcd\nmissing.pcd\n";
  fs::copy_file(kScans + "flat.pcd", dir.path() / "flat.pcd");
  r = run_terrastride("report --batch " + q(dir.path() / "bad.txt") + " --out " +
                      q(dir.path() / "out2"));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("line 2"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("missing.pcd"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir.path() / "out2"));

  std::ofstream(dir.path() / "twice.txt") << "flat.pcd\nx/flat.pcd\n";  // two scans named flat
  r = run_terrastride("report --batch " + q(dir.path() / "twice.txt") + " --out " +
                      q(dir.path() / "out2"));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("two scans are named 'flat'"), std::string::npos) << r.err;
}

TEST(ReportBatch, ExitCodesAndSettingsOfAnExistingFolder) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  fs::create_directories(scans);
  write_map_dir(scans / "a", "flat");
  const fs::path out = dir.path() / "out";
  const std::string args = "report --batch " + q(scans) + " --out " + q(out);
  CommandResult r = run_terrastride(args);
  EXPECT_EQ(r.code, 0) << r.all();
  // Every process writing into one folder must share the settings: refused before any work.
  r = run_terrastride(args + " --foot-radius 0.05 --resume");
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("radii_m"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("[1/1]"), std::string::npos) << r.err;
  // Some scans failed: 3, the others reported and the failure in the index.
  std::ofstream(scans / "z.xyz") << "1 2\n";
  r = run_terrastride(args + " --resume");
  EXPECT_EQ(r.code, 3) << r.all();
  EXPECT_NE(r.err.find("z.xyz"), std::string::npos) << r.err;
  const json index = json::parse(slurp(out / "index.json"));
  EXPECT_EQ(index["failed"], 1);
  EXPECT_EQ(index["reports"][1]["scan"], "z");
  EXPECT_TRUE(index["reports"][1].contains("error"));
  // A time stamp only when asked (another folder: it is a setting).
  r = run_terrastride("report --batch " + q(scans) + " --out " + q(dir.path() / "stamped") +
                      " --timestamp");
  EXPECT_EQ(r.code, 3) << r.all();
  EXPECT_TRUE(json::parse(slurp(dir.path() / "stamped" / "index.json")).contains("generated_utc"));
  EXPECT_TRUE(json::parse(slurp(dir.path() / "stamped" / "a" / "a.json")).contains("generated_utc"));
  EXPECT_FALSE(json::parse(slurp(out / "a" / "a.json")).contains("generated_utc"));
  // A folder terrastride did not write is never written into.
  fs::create_directories(dir.path() / "mine");
  std::ofstream(dir.path() / "mine" / "notes.txt") << "mine";
  r = run_terrastride("report --batch " + q(scans) + " --out " + q(dir.path() / "mine"));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("notes.txt"), std::string::npos) << r.err;
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path() / "mine"), {}), 1);
}

}  // namespace
