// Test helper: starts `terrastride serve` as a child process on an ephemeral loopback port and
// parses the bound addresses it prints.
#pragma once

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace terrastride::test {

class ServerProcess {
 public:
  // Starts the server; waits until it printed every "listening ..." line (or exited).
  explicit ServerProcess(std::vector<std::string> args, int expected_addresses = 1) {
    int out[2];
    if (::pipe(out) != 0) throw std::runtime_error("pipe failed");
    pid_ = ::fork();
    if (pid_ < 0) throw std::runtime_error("fork failed");
    if (pid_ == 0) {
      ::dup2(out[1], 1);
      ::dup2(out[1], 2);
      ::close(out[0]);
      ::close(out[1]);
      std::vector<char*> argv;
      static std::string bin = TERRASTRIDE_BINARY;
      argv.push_back(bin.data());
      static std::string serve = "serve";
      argv.push_back(serve.data());
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(bin.c_str(), argv.data());
      ::_exit(127);
    }
    ::close(out[1]);
    fd_ = out[0];
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (static_cast<int>(addresses.size()) < expected_addresses &&
           std::chrono::steady_clock::now() < until) {
      if (!read_some(200)) break;  // EOF: the server exited
      std::size_t pos;
      while ((pos = buffer_.find('\n')) != std::string::npos) {
        const std::string line = buffer_.substr(0, pos);
        buffer_.erase(0, pos + 1);
        output += line + "\n";
        if (line.rfind("listening ", 0) == 0) addresses.push_back(line.substr(10));
      }
    }
  }
  ~ServerProcess() {
    if (pid_ > 0 && !exited_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    if (fd_ >= 0) ::close(fd_);
  }

  // Sends `sig` and waits for the exit (up to `timeout_s`); returns the exit code, -1 on timeout
  // or a signal death.
  int stop(int sig = SIGTERM, double timeout_s = 20) {
    ::kill(pid_, sig);
    return wait_exit(timeout_s);
  }
  int wait_exit(double timeout_s = 20) {
    const auto until = std::chrono::steady_clock::now() +
                       std::chrono::milliseconds(static_cast<long>(timeout_s * 1000));
    int status = 0;
    while (std::chrono::steady_clock::now() < until) {
      drain_output();
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        exited_ = true;
        drain_output();
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return -1;
  }
  bool running() {
    if (exited_) return false;
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) exited_ = true;
    return !exited_;
  }
  // Resident memory of the server, from /proc (kB).
  long rss_kb() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string line;
    while (std::getline(in, line))
      if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
    return -1;
  }
  int pid() const { return pid_; }
  std::string tcp() const {
    for (const auto& a : addresses)
      if (a.rfind("tcp://", 0) == 0) return a;
    return "";
  }

  std::vector<std::string> addresses;
  std::string output;

 private:
  bool read_some(int timeout_ms) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, timeout_ms) <= 0) return true;
    char buf[4096];
    const ssize_t n = ::read(fd_, buf, sizeof(buf));
    if (n <= 0) return false;
    buffer_.append(buf, static_cast<std::size_t>(n));
    return true;
  }
  void drain_output() {
    while (true) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 0) <= 0) return;
      char buf[4096];
      const ssize_t n = ::read(fd_, buf, sizeof(buf));
      if (n <= 0) return;
      output.append(buf, static_cast<std::size_t>(n));
    }
  }

  pid_t pid_ = -1;
  int fd_ = -1;
  bool exited_ = false;
  std::string buffer_;
};

}  // namespace terrastride::test
