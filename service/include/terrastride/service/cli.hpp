// The `terrastride` command line: each subcommand registers itself on a CLI11 app.
#pragma once

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <stdexcept>
#include <string>
#include <vector>

namespace terrastride::service {

// A failure the user can act on (bad input, unreachable goal, solver failure): printed as
// "terrastride <command>: error: <message>" with exit code `exit_code`.
class CommandError : public std::runtime_error {
 public:
  explicit CommandError(const std::string& message, int exit_code = 1)
      : std::runtime_error(message), exit_code_(exit_code) {}
  int exit_code() const { return exit_code_; }

 private:
  int exit_code_;
};

// Exit codes (docs/design.md, "Command line"): `plan` (and `demo`, which runs one) exits 3 when the
// solver did not reach an optimal plan, 4 when it did but a post-hoc check fails (torques, leg
// capsules, trunk, footholds, and with --simulate a "fail" verdict of the simulated execution):
// never 0 for a plan that fails a check.
constexpr int kExitNotOptimal = 3;
constexpr int kExitChecksFailed = 4;
// `report --batch`: it ran, but some scans of its shard failed (recorded in the index); 1 is kept
// for "could not run at all" (bad --batch, --out or settings).
constexpr int kExitBatchScansFailed = 3;

// Parses "x,y" or "x,y,z" (exactly `n` finite numbers); `what` names the option in errors.
Eigen::VectorXd parse_numbers(const std::string& text, int n, const std::string& what);

// Runs the command line; returns the process exit code. Never throws.
int run_cli(int argc, char** argv);

// Parses and runs `app` (usage errors exit 2, CommandError its code, other errors 1, each printed
// as "NAME COMMAND: error: ..."): the terrastride binary's and its tools' (tests/bench/bench_service)
// shared handling.
int run_command_line(CLI::App& app, int argc, char** argv);

// Subcommands: each service/src/cli/cmd_NAME.cpp defines `void add_NAME_command(CLI::App& app)`,
// registered automatically from the file name (see service/CMakeLists.txt).

}  // namespace terrastride::service
