// map.clear: drop the terrain map (and the clouds behind it).
#include <mutex>

#include "server/backend.hpp"

namespace terrastride::service {

namespace {

// Serialised with updates (a worker op, so the I/O thread never waits for this lock).
OpResult map_clear(Backend& backend, OpContext&) {
  std::lock_guard<std::mutex> lock(backend.update_mutex());
  backend.clouds().clear();
  const bool had = backend.map() != nullptr;
  const auto gen = backend.publish(nullptr);
  OpResult r;
  r.result = {{"generation", gen}, {"cleared", had}};
  return r;
}

}  // namespace

void add_map_clear_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  registry.add({"map.clear", OpKind::kWorker, "drop the terrain map",
                [b](OpContext& c) { return map_clear(*b, c); }, std::vector<std::string>{}});
}

}  // namespace terrastride::service
