// debug.sleep (only with --debug-ops): holds a worker for `ms` milliseconds, polling the
// cancellation token, so tests can exercise busy, cancel and deadlines; with `reply_bytes`, its
// reply carries that many bytes, for tests of clients that do not read.
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
  const double reply_bytes = protocol::get_number(ctx.request.header, "reply_bytes", 0.0);
  if (reply_bytes < 0 || reply_bytes > double(std::size_t{1} << 30))
    throw ProtocolError(pc::kBadRequest, "\"reply_bytes\" must be within [0, 1 GiB]");
  OpResult r;
  if (reply_bytes >= 1) {
    // A reply of this size (a uint8 attachment "bytes"), for tests of clients that never read.
    protocol::Attachment a;
    a.name = "bytes";
    a.dtype = protocol::Dtype::kUint8;
    a.data.assign(static_cast<std::size_t>(reply_bytes), 'x');
    a.shape = {a.data.size()};
    r.attachments.push_back(std::move(a));
  }
  r.result = {{"slept_ms",
               std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                   .count()}};
  return r;
}

}  // namespace

void add_debug_sleep_operation(Backend& backend, OperationRegistry& registry) {
  if (!backend.options().debug_ops) return;
  registry.add({"debug.sleep", OpKind::kWorker, "test op: hold a worker for ms milliseconds",
                [](OpContext& c) { return debug_sleep(c); },
                std::vector<std::string>{"ms", "reply_bytes"},
                // "pad": bytes a test request carries to take memory while it waits.
                std::vector<std::string>{"pad"}});
}

}  // namespace terrastride::service
