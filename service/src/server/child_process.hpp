// Running an operation's work in a forked child process. The service uses it for plans: Debian's
// sequential MUMPS (under Ipopt) is not re-entrant, so two solves in one process crash it; in
// separate processes they run at once, on separate cores. A child also gives its memory back when
// it ends, cannot take the server down when it crashes, runs under a memory limit, and is stopped
// at once (SIGKILL) on cancel, deadline or shutdown.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>

#include "terrastride/service/server.hpp"

namespace terrastride::service {

struct ChildProcessLimits {
  // Address space the child may add to what it inherits (RLIMIT_AS); 0 = no limit. An allocation
  // beyond it fails inside the child (std::bad_alloc -> a `failed` reply), not in the server.
  std::size_t memory_bytes = std::size_t{4} << 30;
};

// Counters over every child run (for `status`).
struct ChildProcessStats {
  std::atomic<std::uint64_t> started{0};
  std::atomic<std::uint64_t> running{0};
  std::atomic<std::uint64_t> stopped{0};  // killed on cancel, deadline or shutdown
  std::atomic<std::uint64_t> died{0};     // ended by a signal or without a complete reply
};

// Forks; the child runs `work` (which may throw protocol::ProtocolError, std::bad_alloc or any
// exception, reported as usual) and sends its OpResult back through a pipe; the parent waits,
// polling ctx's cancellation token, and returns the child's OpResult (result as result_text) or
// rethrows its error. A child that dies is the error `failed` naming the signal. Everything `work`
// reads must be ready before the call (the child sees the parent's memory as it was at the fork).
OpResult run_in_child_process(OpContext& ctx, const std::function<OpResult()>& work,
                              const ChildProcessLimits& limits, ChildProcessStats* stats = nullptr);

}  // namespace terrastride::service
