// The state behind the socket service's terrain and planner operations, and the helpers they
// share. Each operation lives in its own file under service/src/server/ops/ (one file per
// operation, registered from its file name, as the CLI's cmd_*.cpp are); this header is all they
// share.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "child_process.hpp"
#include "terrastride/collision/checks.hpp"
#include "terrastride/planner/trajectory.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "terrastride/service/server.hpp"
#include "terrastride/terrain/height_field.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"
#include "terrastride/terrain/terrain_open.hpp"

namespace terrastride::service {

// One published map: immutable once published; readers hold it for as long as they need it.
struct MapSnapshot {
  std::shared_ptr<const terrain::HeightField> field;
  // The occupancy map the post-hoc leg-capsule and trunk checks need: a cloud's (map.update
  // builds it as `terrastride map` does) or a terrain dir's octomap.bt. Null for a scene (checked
  // on its exact boxes) and a terrain dir without one.
  std::shared_ptr<const octomap::OcTree> octree;
  std::uint64_t generation = 0;
  std::string source;  // "scene:pallet_10", "cloud", ...
  double updated_unix = 0.0;
  nlohmann::json stats = nlohmann::json::object();
};

// The clouds behind the current map: "add" rebuilds the map from every cloud since the last
// replace. Guarded by Backend::update_mutex().
struct CloudHistory {
  std::vector<perception::PointCloud> clouds;
  std::size_t points = 0;
  void clear() {
    clouds.clear();
    points = 0;
  }
};

// A scene and its C2 rasterisation, built once per scene name (Backend::scene_raster).
// The cache keeps the most recently used ones: every pallet_NN height is a scene name (66 names
// in all) and each raster holds about 0.5 MB, so an unbounded cache would grow with the requests'
// variety rather than with the work in flight. Requests hold their own reference, so an evicted
// raster lives on until the last one using it finishes.
constexpr std::size_t kSceneRasterCacheEntries = 8;
struct SceneRaster {
  std::shared_ptr<const terrain::Scene> scene;
  std::shared_ptr<const terrain::TerrainMap> smooth;
};

// The terrain a request names, as the operations open it (Backend::request_terrain): "current"
// (the published map), a scene name or a terrain directory under the server's roots. Holds what
// the fields live in.
struct RequestTerrain {
  std::shared_ptr<const MapSnapshot> snapshot;  // "current": the published map, kept alive
  std::shared_ptr<const SceneRaster> raster;    // a scene (or a published one, when planned on)
  terrain::OpenedTerrain folder;                // a terrain directory (folder.spec: its real path)
  const terrain::HeightField* smooth = nullptr;  // what the optimiser plans on (C2), when asked
  const terrain::HeightField* exact = nullptr;   // what the checks and the simulation judge on
};

class Backend {
 public:
  explicit Backend(const BackendOptions& options);

  const BackendOptions& options() const { return options_; }
  const robot::RobotModel& robot() const { return robot_; }

  // The published map (null when none); one snapshot serves a whole request.
  std::shared_ptr<const MapSnapshot> map() const { return std::atomic_load(&map_); }
  // Publishes `next` (nullptr clears) as the new generation; readers see the old or the new map.
  std::uint64_t publish(std::shared_ptr<MapSnapshot> next);

  // Map updates are serialised by this mutex (queries never take it); it guards clouds().
  std::mutex& update_mutex() { return update_mu_; }
  CloudHistory& clouds() { return clouds_; }

  // Counters for `status` and `hello`.
  void count_query(std::size_t points) {
    queries_++;
    points_queried_ += points;
  }
  void count_update() { updates_++; }

  // Scenes are immutable and made from their name alone, so a scene and its C2 rasterisation
  // (about 10 ms) are built once per name and shared by every plan on it.
  std::shared_ptr<const SceneRaster> scene_raster(const std::string& name);
  // How many scene rasters the cache holds now (at most kSceneRasterCacheEntries).
  std::size_t cached_scene_rasters() const;

  // A terrain directory a client names: only inside one of the server's --terrain-root folders
  // (after resolving symlinks and ".."), and named relative to it or absolutely. `field` names the
  // request field in errors.
  std::string terrain_dir_path(const std::string& requested, const std::string& field) const;
  // A terrain directory a client names, confined as terrain_dir_path and opened by
  // terrain::open_terrain (its octomap.bt too when `octomap` and the folder has one). A folder it
  // cannot read is a perception::InputError naming the file, as the terrain readers word it.
  terrain::OpenedTerrain open_terrain_dir(const std::string& requested, const std::string& field,
                                          bool octomap) const;
  // The terrain in a request's "terrain": "current" (no_map, naming `op`, when none is
  // published), a scene name (through the raster cache) or a terrain directory
  // (open_terrain_dir, without its OctoMap: the post-hoc checks read it). `smooth`: the optimiser's
  // field is needed too (a published scene's raster).
  RequestTerrain request_terrain(const std::string& spec, const std::string& op, bool smooth);
  // Extra safety-layer radii to precompute ("foot_radii": [r, ...]); the robot's is always there.
  std::vector<double> radii_from(const nlohmann::json& header) const;

  // Plans run in child processes under these limits (child_process.hpp), counted here.
  const ChildProcessLimits& plan_limits() const { return plan_limits_; }
  ChildProcessStats& plan_processes() { return plan_processes_; }

  nlohmann::json map_json() const;
  nlohmann::json robot_json() const;
  nlohmann::json plan_processes_json() const;

 private:
  BackendOptions options_;
  robot::RobotModel robot_;
  std::shared_ptr<const MapSnapshot> map_;
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<std::uint64_t> queries_{0}, points_queried_{0}, updates_{0};
  std::mutex update_mu_;
  CloudHistory clouds_;  // guarded by update_mu_
  mutable std::mutex raster_mu_;
  // Most recently used first, at most kSceneRasterCacheEntries (guarded by raster_mu_).
  std::list<std::pair<std::string, std::shared_ptr<const SceneRaster>>> rasters_;
  ChildProcessLimits plan_limits_;
  ChildProcessStats plan_processes_;
};

// Helpers shared by the operations.

// A name of a file in the data folder (letters, digits, '_', '-'): never a path.
bool is_plain_name(const std::string& name);
// A request's gait: a name from the data folder. The server reads no gait file a client names
// ("/etc/shadow" would otherwise be opened, and the error would tell whether it exists).
std::string gait_name(const nlohmann::json& header);
// map.update's and status's figures of a grid map.
nlohmann::json grid_stats(const terrain::TerrainMap& map);
double seconds_since(std::chrono::steady_clock::time_point t);

// A request's "plan" (a plan.json object) and the robot it names (the server's when it names none;
// another only by a plain name from the data folder): `check` and `simulate` read it alike.
// bad_request naming the field otherwise.
struct RequestPlan {
  planner::Trajectory trajectory;
  robot::RobotModel robot;
};
RequestPlan read_request_plan(const Backend& backend, const nlohmann::json& header,
                              const std::string& op);

// The post-hoc checks' view of a published map, as `terrastride check` sees a map folder: the
// height field for the footholds and the map's OctoMap for the leg capsules and the trunk (a
// scene published as the map: its exact boxes voxelised where the legs go). A map without an
// OctoMap says so in the description (its capsules and trunk are not checked).
collision::CheckTerrain snapshot_check_terrain(const MapSnapshot& snapshot,
                                               const robot::RobotModel& model,
                                               const planner::Trajectory& trajectory);

}  // namespace terrastride::service
