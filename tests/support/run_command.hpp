// Running a shell command (usually the terrastride binary) from a test and capturing its exit
// code, stdout and stderr separately. Shared by the CLI tests of every module.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace terrastride::test_support {

struct CommandResult {
  int code = -1;    // exit status; -1 when the command could not run or was killed by a signal
  std::string out;  // stdout
  std::string err;  // stderr
  std::string all() const { return out + err; }
};

// Single-quotes `s` for the shell.
inline std::string shell_quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

// Runs `command` with /bin/sh; stderr goes through a private temporary file.
inline CommandResult run_command(const std::string& command) {
  CommandResult r;
  std::string err_path =
      (std::filesystem::temp_directory_path() / "terrastride_test_stderr_XXXXXX").string();
  const int fd = ::mkstemp(err_path.data());
  if (fd < 0) return r;
  ::close(fd);
  const std::string cmd = command + " 2>" + shell_quote(err_path);
  if (FILE* pipe = ::popen(cmd.c_str(), "r")) {
    std::array<char, 4096> buf;
    std::size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) r.out.append(buf.data(), n);
    const int status = ::pclose(pipe);
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }
  std::ifstream in(err_path, std::ios::binary);
  r.err.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  std::filesystem::remove(err_path);
  return r;
}

#ifdef TERRASTRIDE_BINARY
// `terrastride ARGS` (ARGS already shell-quoted where needed).
inline CommandResult run_terrastride(const std::string& args) {
  return run_command(std::string(TERRASTRIDE_BINARY) + " " + args);
}
#endif

}  // namespace terrastride::test_support
