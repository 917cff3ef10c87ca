// The CLI never destroys or corrupts a user's files: output folders that hold anything
// terrastride did not write are refused before any work, --out is checked before the solve, links
// are followed, and temporaries left by a kill -9 are removed by the next run.
//
// Every test here is safe against a broken binary too: nothing points --out at /dev/*, whose
// entries a broken writer (as root) would replace with files.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "perception/test_util.hpp"
#include "support/run_command.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using terrastride::perception::test::ScratchDir;
using terrastride::test_support::CommandResult;
using terrastride::test_support::run_terrastride;
using terrastride::test_support::shell_quote;

const std::string kFlatScan = std::string(TERRASTRIDE_TEST_DATA_DIR) + "/scans/flat.pcd";
const std::string kQuickPlan = "plan --terrain flat --duration 2.4 --constraints baseline";  // ~0.1 s solve

std::string q(const fs::path& p) {
  return shell_quote(p.string());
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Entries anywhere under `dir` that look like temporaries (".tmp-" or the old ".tmp.").
std::vector<std::string> temporaries_under(const fs::path& dir) {
  std::vector<std::string> found;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".tmp-") != std::string::npos || name.find(".tmp.") != std::string::npos)
      found.push_back(e.path().lexically_relative(dir).string());
  }
  return found;
}

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += " " + x;
  return s;
}

// `terrastride ARGS` in the background (its pid is terrastride's own: exec), output discarded.
pid_t spawn_terrastride(const std::string& args) {
  const std::string cmd =
      "exec " + std::string(TERRASTRIDE_BINARY) + " " + args + " >/dev/null 2>&1";
  const char* argv[] = {"sh", "-c", cmd.c_str(), nullptr};
  pid_t pid = -1;
  if (::posix_spawn(&pid, "/bin/sh", nullptr, nullptr, const_cast<char**>(argv), environ) != 0)
    return -1;
  return pid;
}

// Runs `terrastride ARGS` and kill -9s it as soon as a temporary of NAME appears in DIR (its
// output being written), or lets it finish if it never shows one. Afterwards DIR holds, as after a
// kill -9 during the write, a temporary of NAME from that now-dead pid: the real one when the kill
// caught it, else one made here with exactly the name and kind (folder or file) the tool uses.
// Returns whether the kill caught the command mid-write (for the log only).
bool kill_while_writing(const std::string& args, const fs::path& dir, const std::string& name,
                        bool folder) {
  const pid_t pid = spawn_terrastride(args);
  EXPECT_GT(pid, 0);
  if (pid <= 0) return false;
  const std::string prefix = "." + name + ".tmp-" + std::to_string(pid) + "-";
  const auto leftover = [&] {
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir, ec))
      if (e.path().filename().string().rfind(prefix, 0) == 0) return true;
    return false;
  };
  bool caught = false, reaped = false;
  int status = 0;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(2);
  while (!caught && !reaped && std::chrono::steady_clock::now() < deadline) {
    caught = leftover();
    if (!caught) reaped = ::waitpid(pid, &status, WNOHANG) == pid;  // finished first
    if (!caught && !reaped) std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  if (!reaped) {  // caught mid-write, or past the deadline: kill -9 (never a reaped, reused pid)
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
  }
  if (!caught || !leftover()) {
    const fs::path fake = dir / (prefix + "0-4242");
    if (folder) {
      fs::create_directories(fake / "layers");
      std::ofstream(fake / "layers" / "half.npy") << "half-written";
    } else {
      std::ofstream(fake) << "{ \"half\": ";
    }
  }
  std::cerr << "[kill -9] " << args.substr(0, args.find(' ')) << ": "
            << (caught ? "killed while its temporary existed"
                       : "finished first; a leftover with its pid was made here")
            << "\n";
  EXPECT_TRUE(leftover());
  return caught;
}

TEST(OutputSafety, MapRefusesTheFolderOfItsScans) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  fs::create_directory(scans);
  fs::copy_file(kFlatScan, scans / "scan.pcd");
  const auto size = fs::file_size(scans / "scan.pcd");
  const CommandResult r = run_terrastride("map " + q(scans / "scan.pcd") + " --out " + q(scans));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find(scans.string()), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("scan.pcd"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("choose an empty or new folder"), std::string::npos) << r.err;
  ASSERT_TRUE(fs::exists(scans / "scan.pcd"));
  EXPECT_EQ(fs::file_size(scans / "scan.pcd"), size);
  EXPECT_EQ(std::distance(fs::directory_iterator(scans), {}), 1);
  EXPECT_TRUE(temporaries_under(dir.path()).empty()) << joined(temporaries_under(dir.path()));
}

TEST(OutputSafety, MapReplacesItsOwnOutputButKeepsAddedFiles) {
  ScratchDir dir;
  const fs::path out = dir.path() / "terrain";
  const std::string map = "map " + q(kFlatScan) + " --out " + q(out);
  CommandResult r = run_terrastride(map);
  ASSERT_EQ(r.code, 0) << r.all();
  r = run_terrastride(map);  // its own output: replaced
  ASSERT_EQ(r.code, 0) << r.all();
  std::ofstream(out / "my_notes.txt") << "notes about this terrain";
  r = run_terrastride(map);
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("my_notes.txt"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(out / "my_notes.txt"), "notes about this terrain");
  EXPECT_TRUE(fs::exists(out / "terrain.json"));
}

TEST(OutputSafety, ReportBatchRefusesTheFolderOfItsScans) {
  ScratchDir dir;
  const fs::path scans = dir.path() / "scans";
  fs::create_directory(scans);
  fs::copy_file(kFlatScan, scans / "flat.pcd");
  const CommandResult r = run_terrastride("report --batch " + q(scans) + " --out " + q(scans));
  EXPECT_EQ(r.code, 1) << r.all();
  EXPECT_NE(r.err.find("choose an empty or new folder"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("[1/1]"), std::string::npos) << "refused only after mapping:\n" << r.err;
  ASSERT_TRUE(fs::exists(scans / "flat.pcd"));
  EXPECT_EQ(fs::file_size(scans / "flat.pcd"), fs::file_size(kFlatScan));
  EXPECT_EQ(std::distance(fs::directory_iterator(scans), {}), 1);
}

TEST(OutputSafety, PlanChecksOutBeforeSolving) {
  ScratchDir dir;
  // --verbose shows Ipopt's output: none may appear, since the solve must not start.
  for (const fs::path& out : {dir.path() / "missing" / "plan.json", dir.path()}) {
    const CommandResult r = run_terrastride(kQuickPlan + " --verbose --out " + q(out));
    EXPECT_EQ(r.code, 1) << r.all();
    EXPECT_NE(r.err.find("--out: " + out.string()), std::string::npos) << r.err;
    EXPECT_EQ(r.all().find("Ipopt"), std::string::npos) << "solved before checking --out:\n"
                                                        << r.all();
    EXPECT_EQ(r.all().find("EXIT:"), std::string::npos) << r.all();
  }
  const CommandResult r =
      run_terrastride(kQuickPlan + " --out " + q(dir.path() / "missing" / "plan.json"));
  EXPECT_NE(r.err.find("missing does not exist"), std::string::npos) << r.err;
}

TEST(OutputSafety, PlanWritesThroughASymbolicLink) {
  ScratchDir dir;
  fs::create_directory(dir.path() / "plans");
  const fs::path link = dir.path() / "latest.json";
  fs::create_symlink("plans/plan.json", link);  // relative and dangling: the target is written
  for (int k = 0; k < 2; ++k) {                 // then replaced
    const CommandResult r = run_terrastride(kQuickPlan + " --out " + q(link));
    ASSERT_EQ(r.code, 0) << r.all();
    EXPECT_TRUE(fs::is_symlink(link));
    ASSERT_TRUE(fs::is_regular_file(dir.path() / "plans" / "plan.json"));
    EXPECT_TRUE(
        nlohmann::json::parse(slurp(dir.path() / "plans" / "plan.json")).contains("samples"));
  }
  EXPECT_TRUE(temporaries_under(dir.path()).empty()) << joined(temporaries_under(dir.path()));
}

TEST(OutputSafety, PlanToStandardOutputKeepsTheSummaryOffIt) {
  // /dev/fd/1 rather than /dev/stdout: the same descriptor, but a broken writer cannot create a
  // temporary in /proc/self/fd, so it fails instead of replacing /dev/stdout.
  for (const std::string flags : {"", " --json"}) {
    const CommandResult r = run_terrastride(kQuickPlan + flags + " --out /dev/fd/1");
    ASSERT_EQ(r.code, 0) << r.all();
    nlohmann::json plan;
    ASSERT_NO_THROW(plan = nlohmann::json::parse(r.out)) << r.out.substr(0, 300);
    EXPECT_TRUE(plan.contains("samples"));
    EXPECT_NE(r.err.find(flags.empty() ? "plan: optimal" : "\"status\""), std::string::npos)
        << r.err;
  }
}

TEST(OutputSafety, KilledRunsLeaveNoTemporariesAfterTheNextRun) {
  ScratchDir dir;
  const fs::path out = dir.path() / "out";
  fs::create_directories(out / "scans");
  fs::copy_file(kFlatScan, out / "scans" / "flat.pcd");
  struct Case {
    std::string args, name;
    bool folder;
  };
  const std::vector<Case> cases = {
      {"map " + q(kFlatScan) + " --out " + q(out / "terrain"), "terrain", true},
      {kQuickPlan + " --out " + q(out / "plan.json"), "plan.json", false},
      {"report --batch " + q(out / "scans") + " --out " + q(out / "reports"), "reports", true},
      {"demo --out " + q(out / "demo") + " --json", "demo", true}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.args);
    kill_while_writing(c.args, out, c.name, c.folder);
    const CommandResult r = run_terrastride(c.args);
    EXPECT_EQ(r.code, 0) << r.all();
    EXPECT_TRUE(fs::exists(out / c.name));
    const auto left = temporaries_under(out);
    EXPECT_TRUE(left.empty()) << "left behind:" << joined(left);
  }
}

}  // namespace
