// A cancellation token shared between the server and a running operation. Long computations
// (map fusion, planning) poll `stop_requested()` at safe points, e.g. from Ipopt's intermediate
// callback, and return early; `as_callback()` gives the `std::function<bool()>` form for modules
// that must not depend on the service.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <limits>
#include <memory>
#include <string>

namespace terrastride::service {

class CancellationToken {
 public:
  using Clock = std::chrono::steady_clock;
  enum class Reason { kNone = 0, kCancelled = 1, kDeadline = 2, kShutdown = 3 };

  void cancel(Reason why = Reason::kCancelled) {
    int expected = 0;
    reason_.compare_exchange_strong(expected, static_cast<int>(why));
  }
  void set_deadline(Clock::time_point t) {
    deadline_ns_.store(t.time_since_epoch().count(), std::memory_order_relaxed);
  }
  bool has_deadline() const { return deadline_ns_.load(std::memory_order_relaxed) != kNoDeadline; }
  Clock::time_point deadline() const {
    return Clock::time_point(Clock::duration(deadline_ns_.load(std::memory_order_relaxed)));
  }
  // True once cancelled or past the deadline (the deadline turns into a sticky reason).
  bool stop_requested() {
    if (reason_.load(std::memory_order_relaxed) != 0) return true;
    if (has_deadline() && Clock::now() >= deadline()) {
      cancel(Reason::kDeadline);
      return true;
    }
    return false;
  }
  Reason reason() const { return static_cast<Reason>(reason_.load()); }
  // For modules that take a plain callback: returns true when the computation should stop.
  static std::function<bool()> as_callback(std::shared_ptr<CancellationToken> token) {
    return [token] { return token->stop_requested(); };
  }

 private:
  static constexpr Clock::rep kNoDeadline = std::numeric_limits<Clock::rep>::max();
  std::atomic<int> reason_{0};
  std::atomic<Clock::rep> deadline_ns_{kNoDeadline};
};

}  // namespace terrastride::service
