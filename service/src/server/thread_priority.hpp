// The calling thread's scheduling policy, for the server's real-time answer path (docs/sessions.md):
// a budgeted session step's worker and, with `serve --realtime-io`, the I/O thread run at
// SCHED_FIFO priority 1, the lowest real-time priority, above every normal thread; everything
// else at the normal policy.
#pragma once

#include <pthread.h>
#include <sched.h>

namespace terrastride::service {

// Raises the calling thread to SCHED_FIFO priority 1 where the process may (root, CAP_SYS_NICE,
// an rtprio limit). True when the thread now runs at a real-time priority (it may already have).
inline bool raise_to_realtime() {
  const pthread_t self = pthread_self();
  int policy = SCHED_OTHER;
  sched_param param{};
  if (pthread_getschedparam(self, &policy, &param) != 0) return false;
  if (policy == SCHED_FIFO && param.sched_priority >= 1) return true;
  sched_param rt{};
  rt.sched_priority = 1;
  return pthread_setschedparam(self, SCHED_FIFO, &rt) == 0;
}

// Returns the calling thread to the normal policy if something raised it.
inline void return_to_normal_policy() {
  const pthread_t self = pthread_self();
  int policy = SCHED_OTHER;
  sched_param param{};
  if (pthread_getschedparam(self, &policy, &param) == 0 && policy != SCHED_OTHER) {
    const sched_param normal{};
    pthread_setschedparam(self, SCHED_OTHER, &normal);
  }
}

}  // namespace terrastride::service
