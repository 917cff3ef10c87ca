// debug.sleep (only with --debug-ops): holds a worker for `ms` milliseconds, polling the
// cancellation token, so tests can exercise busy, cancel and deadlines.
#include <chrono>
#include <thread>

#include "server/backend.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using protocol::ProtocolError;

namespace {

OpResult debug_sleep(OpContext& ctx) {
  const double ms = protocol::get_number(ctx.request.header, "ms", std::nullopt);
  if (ms < 0 || ms > 60000)
    throw ProtocolError(pc::kBadRequest, "\"ms\" must be within [0, 60000]");
  const auto start = std::chrono::steady_clock::now();
  const auto end = start + std::chrono::microseconds(static_cast<long long>(ms * 1000));
  while (std::chrono::steady_clock::now() < end) {
    ctx.check_stop();
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  OpResult r;
  r.result = {{"slept_ms",
               std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                   .count()}};
  return r;
}

}  // namespace

void add_debug_sleep_operation(Backend& backend, OperationRegistry& registry) {
  if (!backend.options().debug_ops) return;
  registry.add({"debug.sleep", OpKind::kWorker, "test op: hold a worker for ms milliseconds",
                [](OpContext& c) { return debug_sleep(c); }, std::vector<std::string>{"ms"}});
}

}  // namespace terrastride::service
