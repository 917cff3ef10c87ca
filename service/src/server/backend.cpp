// The state behind the socket service's terrain and planner operations (backend.hpp), and the
// dispatch table: one file per operation under ops/, each defining
// `void add_NAME_operation(Backend&, OperationRegistry&)`; the list is generated from the file
// names (service/CMakeLists.txt), so adding an operation touches no shared file. Each operation
// calls the real terrain/planner/collision APIs.
#include "backend.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <octomap/OcTree.h>

#include "common/terrain_source.hpp"
#include "terrastride/planner/gait.hpp"
#include "terrastride/planner/plan_io.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

// One declaration per service/src/server/ops/NAME.cpp (see service/CMakeLists.txt).
#define TERRASTRIDE_OPERATION(name) void add_##name##_operation(Backend&, OperationRegistry&);
#include "terrastride_operations.inc"
#undef TERRASTRIDE_OPERATION

namespace {

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

}  // namespace

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

Backend::Backend(const BackendOptions& options) : options_(options) {
  robot_ = robot::load_robot(robot::resolve_robot_path(options.robot));
  plan_limits_.memory_bytes = options.plan_memory_bytes;
}

std::uint64_t Backend::publish(std::shared_ptr<MapSnapshot> next) {
  const std::uint64_t gen = ++generation_;
  if (next) {
    next->generation = gen;
    next->updated_unix = unix_now();
  }
  std::atomic_store(&map_, std::shared_ptr<const MapSnapshot>(std::move(next)));
  return gen;
}

json Backend::map_json() const {
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

json Backend::robot_json() const {
  json legs = json::array();
  for (const auto& l : robot_.legs) legs.push_back(l.name);
  return {{"name", robot_.name},
          {"mass", robot_.mass},
          {"foot_radius", robot_.foot_radius},
          {"legs", legs}};
}

json Backend::plan_processes_json() const {
  return {{"isolated", options_.plan_in_child_process},
          {"memory_limit_bytes", plan_limits_.memory_bytes},
          {"started", plan_processes_.started.load()},
          {"running", plan_processes_.running.load()},
          {"stopped", plan_processes_.stopped.load()},
          {"died", plan_processes_.died.load()}};
}

std::shared_ptr<const SceneRaster> Backend::scene_raster(const std::string& name) {
  auto find_and_touch = [&]() -> std::shared_ptr<const SceneRaster> {
    const auto it = std::find_if(rasters_.begin(), rasters_.end(),
                                 [&](const auto& entry) { return entry.first == name; });
    if (it == rasters_.end()) return nullptr;
    rasters_.splice(rasters_.begin(), rasters_, it);
    return rasters_.front().second;
  };
  {
    std::lock_guard<std::mutex> lock(raster_mu_);
    if (auto hit = find_and_touch()) return hit;
  }
  // Built outside the lock (tens of ms): other scenes' requests need not wait for it.
  auto r = std::make_shared<SceneRaster>();
  r->scene = terrain::make_scene(name);
  r->smooth = terrain::TerrainMap::from_scene(*r->scene, 0.02, {});
  std::lock_guard<std::mutex> lock(raster_mu_);
  if (auto hit = find_and_touch()) return hit;  // another request built it meanwhile
  rasters_.emplace_front(name, std::move(r));
  while (rasters_.size() > kSceneRasterCacheEntries) rasters_.pop_back();
  return rasters_.front().second;
}

std::size_t Backend::cached_scene_rasters() const {
  std::lock_guard<std::mutex> lock(raster_mu_);
  return rasters_.size();
}

std::string Backend::terrain_dir_path(const std::string& requested,
                                      const std::string& field) const {
  namespace fs = std::filesystem;
  const auto& roots = options_.terrain_roots;
  if (roots.empty())
    throw ProtocolError(pc::kBadRequest,
                        "\"" + field + "\": '" + requested +
                            "': this server reads no terrain directories (start it with "
                            "--terrain-root DIR to allow those under DIR); use a scene name or "
                            "send the points with map.update");
  std::error_code ec;
  for (const auto& root : roots) {
    const fs::path base = fs::weakly_canonical(root, ec);
    if (ec) continue;
    const fs::path p = fs::path(requested).is_absolute() ? fs::path(requested) : base / requested;
    const fs::path real = fs::weakly_canonical(p, ec);
    if (ec) continue;
    const auto rel = real.lexically_relative(base);
    if (rel.empty() || *rel.begin() == "..") continue;
    if (!fs::is_directory(real, ec)) continue;
    return real.string();
  }
  // One message whether or not the path exists: the reply reveals nothing outside the roots.
  throw ProtocolError(pc::kBadRequest, "\"" + field + "\": '" + requested +
                                           "' is not a terrain directory under the server's "
                                           "terrain roots");
}

terrain::OpenedTerrain Backend::open_terrain_dir(const std::string& requested,
                                                const std::string& field, bool octomap) const {
  const std::string path = terrain_dir_path(requested, field);
  terrain::TerrainOpenOptions options;
  options.folder_octomap = octomap;
  try {
    return terrain::open_terrain({path}, options);
  } catch (const terrain::TerrainOpenError& e) {
    // The readers' own words (they name the file), as the operations have always replied.
    const std::string what = e.what();
    throw perception::InputError(e.input().empty() ? what : what.substr(e.input().size() + 2));
  }
}

RequestTerrain Backend::request_terrain(const std::string& spec, const std::string& op,
                                        bool smooth) {
  RequestTerrain t;
  if (spec == "current") {
    t.snapshot = map();
    if (!t.snapshot) throw ProtocolError(pc::kNoMap, op + " on \"current\": no map loaded");
    t.exact = t.smooth = t.snapshot->field.get();
    // A published scene is planned on its raster ("scene:NAME"), checked on its exact boxes.
    if (smooth && dynamic_cast<const terrain::Scene*>(t.exact)) {
      t.raster = scene_raster(t.snapshot->source.substr(t.snapshot->source.find(':') + 1));
      t.smooth = t.raster->smooth.get();
    }
  } else if (terrain::is_scene_name(spec)) {
    // By name, never through the file system: a file of a scene's name in the server's folder is
    // outside its terrain roots.
    t.raster = scene_raster(spec);
    t.smooth = t.raster->smooth.get();
    t.exact = t.raster->scene.get();
  } else {
    t.folder = open_terrain_dir(spec, "terrain", /*octomap=*/false);
    t.smooth = t.exact = t.folder.map.get();
  }
  return t;
}

std::vector<double> Backend::radii_from(const json& h) const {
  std::vector<double> radii{robot_.foot_radius};
  const auto it = h.find("foot_radii");
  if (it == h.end()) return radii;
  if (!it->is_array() || it->size() > 4)
    throw ProtocolError(pc::kBadRequest, "\"foot_radii\" must be an array of at most 4 radii");
  for (const json& r : *it) {
    if (!r.is_number() || !std::isfinite(r.get<double>()) || r.get<double>() < 0 ||
        r.get<double>() > 0.5)
      throw ProtocolError(pc::kBadRequest, "\"foot_radii\" entries must be within [0, 0.5] m");
    radii.push_back(r.get<double>());
  }
  return radii;
}

bool is_plain_name(const std::string& name) {
  return !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
}

std::string gait_name(const json& h) {
  const std::string gait = protocol::get_string(h, "gait", std::string("crawl"));
  std::string names;
  for (const auto& n : planner::gait_names()) names += (names.empty() ? "" : ", ") + n;
  if (!is_plain_name(gait))
    throw ProtocolError(pc::kBadRequest,
                        "\"gait\": a gait name (" + names + "); the server reads no gait files");
  return gait;
}

json grid_stats(const terrain::TerrainMap& tm) {
  const auto& g = tm.grid();
  return {{"kind", "grid"},
          {"resolution", g.geometry.resolution},
          {"nx", g.geometry.nx},
          {"ny", g.geometry.ny},
          {"observed_cells", g.observed_cells},
          {"filled_cells", g.filled_cells},
          {"points_in_grid", g.points_in_grid},
          {"foot_radii", tm.radii()}};
}

RequestPlan read_request_plan(const Backend& backend, const json& header, const std::string& op) {
  const auto it = header.find("plan");
  if (it == header.end() || !it->is_object())
    throw ProtocolError(pc::kBadRequest, op + " needs \"plan\": a plan.json object");
  RequestPlan r{{}, backend.robot()};
  try {
    r.trajectory = planner::plan_from_json(*it, "plan");
  } catch (const std::exception& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  const std::string& name = r.trajectory.robot;
  if (!r.trajectory.robot_definition.empty()) {
    // The plan carries its robot: judged with that definition, whatever the server's robot is.
    try {
      r.robot = planner::robot_of_plan(r.trajectory, "plan");
    } catch (const std::exception& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
  } else if (!name.empty() && name != backend.robot().name) {
    // A robot name from the data folder, never a path a client names (see gait_name).
    if (!is_plain_name(name))
      throw ProtocolError(pc::kBadRequest, "plan.robot: a robot name (e.g. " +
                                               backend.robot().name +
                                               "); the server reads no robot files a client names");
    try {
      r.robot = robot::load_robot(robot::resolve_robot_path(name));
    } catch (const robot::RobotFileError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("plan.robot: ") + e.what());
    }
  }
  return r;
}

collision::CheckTerrain snapshot_check_terrain(const MapSnapshot& snapshot,
                                               const robot::RobotModel& model,
                                               const planner::Trajectory& trajectory) {
  if (const auto* scene = dynamic_cast<const terrain::Scene*>(snapshot.field.get()))
    return scene_check_terrain(*scene, snapshot.source, model, trajectory, kPostHocVoxel);
  collision::CheckTerrain view;
  view.field = snapshot.field.get();
  view.octree = snapshot.octree;
  view.description =
      "map " + snapshot.source +
      (snapshot.octree
           ? " (its OctoMap at " + std::to_string(snapshot.octree->getResolution()) + " m)"
           : " (no OctoMap: leg capsules and trunk not checked)");
  return view;
}

std::shared_ptr<Backend> make_backend(const BackendOptions& options, OperationRegistry& registry) {
  auto backend = std::make_shared<Backend>(options);
#define TERRASTRIDE_OPERATION(name) add_##name##_operation(*backend, registry);
#include "terrastride_operations.inc"
#undef TERRASTRIDE_OPERATION
  return backend;
}

json backend_status(const Backend& backend) {
  return {{"map", backend.map_json()},
          {"plan_processes", backend.plan_processes_json()},
          {"scene_rasters",
           {{"cached", backend.cached_scene_rasters()}, {"capacity", kSceneRasterCacheEntries}}}};
}

json backend_hello(const Backend& backend) {
  return {{"robot", backend.robot_json()}, {"map", backend.map_json()}};
}

}  // namespace terrastride::service
