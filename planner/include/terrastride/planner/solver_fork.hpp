// Forking a process that will solve, from a process whose other threads solve.
#pragma once

#include <pthread.h>

#include <functional>
#include <mutex>

namespace terrastride::planner {

// Held across a fork() whose child will solve (the service's plan processes). Debian's sequential
// MUMPS keeps process-wide state; a child forked while another thread of the parent was inside a
// solve inherits that state half-way through a factorisation, and its own solve then corrupts the
// heap ("double free or corruption", signal 6). The guard waits until no solve runs in this
// process and keeps new ones from starting (they wait for it, ahead of other waiting solves)
// until it is released, right after the fork.
class SolverForkGuard {
 public:
  // Polls `should_stop` while a solve runs; held() is false when it said stop.
  explicit SolverForkGuard(const std::function<bool()>& should_stop);
  ~SolverForkGuard();
  SolverForkGuard(const SolverForkGuard&) = delete;
  SolverForkGuard& operator=(const SolverForkGuard&) = delete;
  bool held() const { return lock_.owns_lock(); }
  // In the parent, after the fork: lets solves run again.
  void release();
  // In the child, after the fork: the lock belongs to the parent's thread; the child starts with
  // a free solver (nothing of the parent's solves is in its memory).
  void release_in_child();

 private:
  std::unique_lock<std::timed_mutex> lock_;
  bool waiting_ = false;
};

// A process-wide mutex (one per Tag type) that every fork takes and both sides release: a child
// forked from a multi-threaded process (the service's plan processes) never inherits it held by a
// thread it does not have.
template <typename Tag>
std::mutex& fork_safe_mutex() {
  static std::mutex m;
  static const int atfork =
      pthread_atfork(+[] { m.lock(); }, +[] { m.unlock(); }, +[] { m.unlock(); });
  (void)atfork;
  return m;
}

}  // namespace terrastride::planner
