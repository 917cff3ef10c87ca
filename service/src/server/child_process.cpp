// See child_process.hpp. The reply travels through a pipe as
//   u64 header length | header JSON | u64 result length | result text | attachment bytes...
// with the header {"ok": true, "attachments": [{"name", "shape"}]} or {"ok": false, "code",
// "message"}; lengths in host order (both ends are this process image).
#include "child_process.hpp"

#include "terrastride/planner/solver_fork.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <new>
#include <string>

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

void append_u64(std::string& out, std::uint64_t v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}

bool write_all(int fd, const char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

std::string encode_result(const OpResult& r) {
  json head = {{"ok", true}, {"attachments", json::array()}};
  for (const auto& a : r.attachments)
    head["attachments"].push_back({{"name", a.name}, {"shape", a.shape}});
  const std::string h = head.dump();
  const std::string text = r.result_text.empty() ? r.result.dump() : r.result_text;
  std::string out;
  append_u64(out, h.size());
  out += h;
  append_u64(out, text.size());
  out += text;
  for (const auto& a : r.attachments) out += a.data;
  return out;
}

std::string encode_error(const std::string& code, const std::string& message) {
  const std::string h = json{{"ok", false}, {"code", code}, {"message", message}}.dump();
  std::string out;
  append_u64(out, h.size());
  out += h;
  return out;
}

// The child's virtual size now (bytes), from /proc/self/statm; 0 if unreadable.
std::size_t virtual_size_bytes() {
  std::ifstream in("/proc/self/statm");
  std::size_t pages = 0;
  in >> pages;
  return pages * static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
}

[[noreturn]] void run_child(int out_fd, pid_t parent, const std::function<OpResult()>& work,
                            const ChildProcessLimits& limits) {
  // Die with the server: a child must not outlive the process that waits for its reply.
  ::prctl(PR_SET_PDEATHSIG, SIGKILL);
  if (::getppid() != parent) ::_exit(1);
  // The child inherits the server's sockets; holding them would keep a closed client's connection
  // (and the listening socket) open until the plan ends.
  ::syscall(SYS_close_range, 3u, static_cast<unsigned>(out_fd) - 1u, 0u);
  ::syscall(SYS_close_range, static_cast<unsigned>(out_fd) + 1u, ~0u, 0u);
  ::signal(SIGPIPE, SIG_IGN);  // a parent gone away is an EPIPE on write, then exit
  ::signal(SIGINT, SIG_DFL);
  ::signal(SIGTERM, SIG_DFL);
  sigset_t all;
  sigemptyset(&all);
  ::pthread_sigmask(SIG_SETMASK, &all, nullptr);
  std::string reply;
  try {
    if (limits.memory_bytes > 0) {
      const rlim_t cap = virtual_size_bytes() + limits.memory_bytes;
      const rlimit rl{cap, cap};
      ::setrlimit(RLIMIT_AS, &rl);
    }
    reply = encode_result(work());
  } catch (const ProtocolError& e) {
    reply = encode_error(e.code(), e.what());
  } catch (const std::bad_alloc&) {
    reply = encode_error(pc::kFailed, "out of memory: the request needs more than the " +
                                          std::to_string(limits.memory_bytes >> 20) +
                                          " MiB a plan process may use");
  } catch (const std::exception& e) {
    reply = encode_error(pc::kFailed, e.what());
  } catch (...) {
    reply = encode_error(pc::kInternal, "unknown exception in the plan process");
  }
  // _exit: the parent's atexit handlers and static objects (the server's) are not the child's.
  ::_exit(write_all(out_fd, reply.data(), reply.size()) ? 0 : 1);
}

std::uint64_t read_u64(const std::string& s, std::size_t& at) {
  if (at + sizeof(std::uint64_t) > s.size()) throw std::out_of_range("short reply");
  std::uint64_t v;
  std::memcpy(&v, s.data() + at, sizeof v);
  at += sizeof v;
  return v;
}

OpResult decode_reply(const std::string& bytes) {
  std::size_t at = 0;
  const std::uint64_t hn = read_u64(bytes, at);
  if (hn > bytes.size() - at) throw std::out_of_range("short header");
  const json head = json::parse(bytes.substr(at, hn));
  at += hn;
  if (!head.at("ok").get<bool>())
    throw ProtocolError(head.at("code").get<std::string>(), head.at("message").get<std::string>());
  OpResult r;
  const std::uint64_t tn = read_u64(bytes, at);
  if (tn > bytes.size() - at) throw std::out_of_range("short result");
  r.result_text = bytes.substr(at, tn);
  at += tn;
  for (const json& a : head.at("attachments")) {
    protocol::Attachment att;
    att.name = a.at("name").get<std::string>();
    att.shape = a.at("shape").get<std::vector<std::uint64_t>>();
    std::uint64_t n = 4;
    for (auto d : att.shape) n *= d;
    if (n > bytes.size() - at) throw std::out_of_range("short attachment");
    att.data = bytes.substr(at, n);
    at += n;
    r.attachments.push_back(std::move(att));
  }
  return r;
}

struct RunningCounter {
  ChildProcessStats* stats;
  explicit RunningCounter(ChildProcessStats* s) : stats(s) {
    if (stats) {
      stats->started++;
      stats->running++;
    }
  }
  ~RunningCounter() {
    if (stats) stats->running--;
  }
};

}  // namespace

OpResult run_in_child_process(OpContext& ctx, const std::function<OpResult()>& work,
                              const ChildProcessLimits& limits, ChildProcessStats* stats) {
  ctx.check_stop();
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0)
    throw ProtocolError(pc::kFailed,
                        std::string("cannot start a plan process: pipe: ") + std::strerror(errno));
  const pid_t parent = ::getpid();
  // No solve of this process (a planning session's, in another thread) may be half-way through
  // when the child is made: the child would inherit the solver's state mid-factorisation.
  planner::SolverForkGuard solver_idle(CancellationToken::as_callback(ctx.token));
  if (!solver_idle.held()) {
    ::close(fds[0]);
    ::close(fds[1]);
    ctx.check_stop();  // throws cancelled / deadline_exceeded / shutting_down
    throw ProtocolError(pc::kFailed, "cannot start a plan process: stopped waiting for the solver");
  }
  const pid_t pid = ::fork();
  if (pid < 0) {
    const int err = errno;
    ::close(fds[0]);
    ::close(fds[1]);
    throw ProtocolError(pc::kFailed,
                        std::string("cannot start a plan process: fork: ") + std::strerror(err));
  }
  if (pid == 0) {
    solver_idle.release_in_child();
    ::close(fds[0]);
    run_child(fds[1], parent, work, limits);
  }
  solver_idle.release();
  RunningCounter counter(stats);
  ::close(fds[1]);
  const int in = fds[0];
  std::string bytes;
  bool stopped = false;
  char buf[1 << 16];
  for (;;) {
    pollfd p{in, POLLIN, 0};
    const int ready = ::poll(&p, 1, 10);  // the token is polled every 10 ms
    if (ready < 0 && errno != EINTR) break;
    if (ctx.token->stop_requested()) {
      stopped = true;
      break;
    }
    if (ready <= 0) continue;
    const ssize_t n = ::read(in, buf, sizeof buf);
    if (n < 0 && (errno == EINTR || errno == EAGAIN)) continue;
    if (n <= 0) break;  // EOF: the child has written everything and exited (or died)
    bytes.append(buf, static_cast<std::size_t>(n));
  }
  ::close(in);
  if (stopped) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (stopped) {
    if (stats) stats->stopped++;
    ctx.check_stop();  // throws cancelled / deadline_exceeded / shutting_down
  }
  try {
    return decode_reply(bytes);
  } catch (const ProtocolError&) {
    throw;
  } catch (const std::exception&) {
    if (stats) stats->died++;
    std::string how;
    if (WIFSIGNALED(status))
      how = "was ended by signal " + std::to_string(WTERMSIG(status)) + " (" +
            strsignal(WTERMSIG(status)) + ")" +
            (WTERMSIG(status) == SIGKILL ? ", possibly by the system's out-of-memory killer" : "");
    else
      how = "exited with code " + std::to_string(WEXITSTATUS(status)) + " without a complete reply";
    throw ProtocolError(pc::kFailed, "the plan process " + how);
  }
}

}  // namespace terrastride::service
