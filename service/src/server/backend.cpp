// The operations behind the socket service: the terrain map (published atomically), terrain
// queries, plans and checks. Each operation calls the real terrain/planner/collision APIs; one whose
// backing module is not built in answers `unavailable` instead of inventing data.
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <thread>

#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/server.hpp"
#include "terrastride/terrain/height_field.hpp"
#include "terrastride/terrain/scenes.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// One published map: immutable once published; readers hold it for as long as they need it.
struct MapSnapshot {
  std::shared_ptr<const terrain::HeightField> field;
  std::uint64_t generation = 0;
  std::string source;  // "scene:pallet_10", "cloud", ...
  double updated_unix = 0.0;
  json stats = json::object();
};

constexpr std::size_t kMaxQueryPoints = 10000;

}  // namespace

class Backend {
 public:
  explicit Backend(const BackendOptions& options) : options_(options) {
    robot_ = robot::load_robot(robot::resolve_robot_path(options.robot));
  }

  std::shared_ptr<const MapSnapshot> map() const { return std::atomic_load(&map_); }

  // Publishes `next` (nullptr clears) as the new generation; readers see the old or the new map.
  std::uint64_t publish(std::shared_ptr<MapSnapshot> next) {
    const std::uint64_t gen = ++generation_;
    if (next) {
      next->generation = gen;
      next->updated_unix = unix_now();
    }
    std::atomic_store(&map_, std::shared_ptr<const MapSnapshot>(std::move(next)));
    return gen;
  }

  json map_json() const {
    const auto m = map();
    json j = {{"present", m != nullptr}, {"generation", generation_.load()}};
    if (m) {
      const auto lo = m->field->min_corner();
      const auto hi = m->field->max_corner();
      j["source"] = m->source;
      j["description"] = m->field->describe();
      j["min_corner"] = {lo.x(), lo.y()};
      j["max_corner"] = {hi.x(), hi.y()};
      j["updated_unix"] = m->updated_unix;
      j["stats"] = m->stats;
    }
    j["queries"] = queries_.load();
    j["points_queried"] = points_queried_.load();
    j["updates"] = updates_.load();
    return j;
  }

  json robot_json() const {
    json legs = json::array();
    for (const auto& l : robot_.legs) legs.push_back(l.name);
    return {{"name", robot_.name},
            {"mass", robot_.mass},
            {"foot_radius", robot_.foot_radius},
            {"legs", legs}};
  }

  OpResult map_query(OpContext& ctx) {
    const json& h = ctx.request.header;
    const double foot_radius = protocol::get_number(h, "foot_radius", robot_.foot_radius);
    if (foot_radius < 0 || foot_radius > 1)
      throw ProtocolError(pc::kBadRequest, "\"foot_radius\" must be within [0, 1] m");
    std::vector<double> xy;
    if (const auto* a = ctx.request.find("points")) {
      const auto f = protocol::read_floats(*a, 2, /*require_finite=*/true);
      xy.assign(f.begin(), f.end());
    } else {
      const auto it = h.find("points");
      if (it == h.end() || !it->is_array())
        throw ProtocolError(pc::kBadRequest,
                            "map.query needs \"points\": [[x, y], ...] or a float32 attachment "
                            "\"points\" of shape [N, 2]");
      if (it->size() > kMaxQueryPoints)
        throw ProtocolError(pc::kBadRequest, "map.query: " + std::to_string(it->size()) +
                                                 " points exceed the batch limit of " +
                                                 std::to_string(kMaxQueryPoints));
      xy.reserve(2 * it->size());
      for (std::size_t i = 0; i < it->size(); ++i) {
        const json& p = (*it)[i];
        if (!p.is_array() || p.size() != 2 || !p[0].is_number() || !p[1].is_number())
          throw ProtocolError(pc::kBadRequest, "points[" + std::to_string(i) +
                                                   "] must be [x, y] (two numbers)");
        const double x = p[0].get<double>(), y = p[1].get<double>();
        if (!std::isfinite(x) || !std::isfinite(y))
          throw ProtocolError(pc::kBadRequest, "points[" + std::to_string(i) + "] is not finite");
        xy.push_back(x);
        xy.push_back(y);
      }
    }
    if (xy.size() / 2 > kMaxQueryPoints)
      throw ProtocolError(pc::kBadRequest, "map.query: " + std::to_string(xy.size() / 2) +
                                               " points exceed the batch limit of " +
                                               std::to_string(kMaxQueryPoints));
    const auto m = map();  // one snapshot for the whole batch
    if (!m)
      throw ProtocolError(pc::kNoMap, "no terrain map loaded: send map.update first");
    json results = json::array();
    for (std::size_t i = 0; i + 1 < xy.size(); i += 2) {
      const double x = xy[i], y = xy[i + 1];
      const auto s = m->field->sample(x, y);
      const auto mg = m->field->safety_margin(x, y, foot_radius);
      const bool observed = m->field->observed(x, y);
      results.push_back({{"x", x},
                         {"y", y},
                         {"height", s.height},
                         {"gradient", {s.gradient.x(), s.gradient.y()}},
                         {"safe", observed && mg.margin > 0.0},
                         {"margin", mg.margin},
                         {"observed", observed}});
    }
    queries_++;
    points_queried_ += xy.size() / 2;
    OpResult r;
    r.result = {{"generation", m->generation}, {"results", std::move(results)}};
    return r;
  }

  OpResult map_update(OpContext& ctx) {
    const json& h = ctx.request.header;
    const std::string mode = protocol::get_string(h, "mode", std::string("add"));
    if (mode != "add" && mode != "replace")
      throw ProtocolError(pc::kBadRequest, "\"mode\" must be \"add\" or \"replace\", got '" + mode +
                                               "'");
    const bool has_scene = h.contains("scene");
    const bool has_dir = h.contains("terrain_dir");
    const auto* points = ctx.request.find("points");
    if (int(has_scene) + int(has_dir) + int(points != nullptr) != 1)
      throw ProtocolError(pc::kBadRequest,
                          "map.update needs exactly one source: \"scene\" (a scenario name), "
                          "\"terrain_dir\" (a `terrastride map` output) or a float32 attachment "
                          "\"points\" of shape [N, 3] with \"origin\"");
    std::lock_guard<std::mutex> lock(update_mu_);  // updates are serialised; queries never wait
    ctx.check_stop();
    auto next = std::make_shared<MapSnapshot>();
    if (has_scene) {
      const std::string name = protocol::get_string(h, "scene", std::nullopt);
      std::unique_ptr<terrain::Scene> scene;
      try {
        scene = terrain::make_scene(name);
      } catch (const perception::InputError& e) {
        throw ProtocolError(pc::kBadRequest, std::string("\"scene\": ") + e.what());
      }
      next->source = "scene:" + name;
      next->stats = {{"kind", "analytic"}, {"edges", scene->edges().size()}};
      next->field = std::move(scene);
    } else if (has_dir) {
      protocol::get_string(h, "terrain_dir", std::nullopt);
      throw ProtocolError(pc::kUnavailable,
                          "map.update from \"terrain_dir\": the terrain loader is not built into "
                          "this server yet");
    } else {
      // Validate the cloud fully (shape, NaNs, origin) before anything else.
      const auto pts = protocol::read_points(*points);
      if (pts.empty()) throw ProtocolError(pc::kBadRequest, "attachment 'points' holds no points");
      if (h.contains("origin")) protocol::get_vector(h, "origin", 3);
      throw ProtocolError(pc::kUnavailable,
                          "map.update from a point cloud (" + std::to_string(pts.size()) +
                              " points): the terrain map builder is not built into this server "
                              "yet");
    }
    ctx.check_stop();
    const auto gen = publish(next);
    updates_++;
    OpResult r;
    r.result = {{"generation", gen}, {"source", next->source}, {"stats", next->stats}};
    return r;
  }

  // Inline and lock-free: an update still running publishes after the clear (last publish wins).
  OpResult map_clear(OpContext&) {
    const bool had = map() != nullptr;
    const auto gen = publish(nullptr);
    OpResult r;
    r.result = {{"generation", gen}, {"cleared", had}};
    return r;
  }

  OpResult unavailable(const std::string& op, const std::string& module) {
    throw ProtocolError(pc::kUnavailable, op + ": the " + module +
                                              " is not built into this server yet");
  }

  // Test operation (only with --debug-ops): holds a worker for `ms` milliseconds, polling the
  // cancellation token every millisecond, so tests can exercise busy, cancel and deadlines.
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
    r.result = {{"slept_ms", std::chrono::duration<double, std::milli>(
                                 std::chrono::steady_clock::now() - start)
                                 .count()}};
    return r;
  }

  const BackendOptions& options() const { return options_; }

 private:
  BackendOptions options_;
  robot::RobotModel robot_;
  std::shared_ptr<const MapSnapshot> map_;
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<std::uint64_t> queries_{0}, points_queried_{0}, updates_{0};
  std::mutex update_mu_;
};

std::shared_ptr<Backend> make_backend(const BackendOptions& options, OperationRegistry& registry) {
  auto b = std::make_shared<Backend>(options);
  Backend* p = b.get();
  registry.add({"map.query", OpKind::kInline,
                "height, gradient, safety margin for a batch of (x, y) points",
                [p](OpContext& c) { return p->map_query(c); }});
  registry.add({"map.update", OpKind::kWorker,
                "replace or extend the terrain map (scene, terrain dir or point cloud)",
                [p](OpContext& c) { return p->map_update(c); }});
  registry.add({"map.clear", OpKind::kInline, "drop the terrain map",
                [p](OpContext& c) { return p->map_clear(c); }});
  registry.add({"plan", OpKind::kWorker, "plan a motion (as `terrastride plan`)",
                [p](OpContext&) { return p->unavailable("plan", "planner (trajectory optimisation)"); }});
  registry.add({"check", OpKind::kWorker, "post-hoc checks of a plan (as `terrastride check`)",
                [p](OpContext&) { return p->unavailable("check", "post-hoc checks module"); }});
  if (options.debug_ops)
    registry.add({"debug.sleep", OpKind::kWorker, "test op: hold a worker for ms milliseconds",
                  [p](OpContext& c) { return p->debug_sleep(c); }});
  return b;
}

json backend_status(const Backend& backend) { return {{"map", backend.map_json()}}; }

json backend_hello(const Backend& backend) {
  return {{"robot", backend.robot_json()}, {"map", backend.map_json()}};
}

}  // namespace terrastride::service
