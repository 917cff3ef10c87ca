// The operations behind the socket service: the terrain map (published atomically), terrain
// queries, plans and checks. Each operation calls the real terrain/planner/collision APIs; one
// whose backing module is not built in answers `unavailable` instead of inventing data.
#include <algorithm>
#include <cctype>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "terrastride/collision/checks.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/planner/feasibility.hpp"
#include "terrastride/planner/plan_io.hpp"
#include "terrastride/planner/planner.hpp"
#include "terrastride/robot/robot_model.hpp"
#include "child_process.hpp"
#include "plan_request.hpp"
#include "terrain_source.hpp"
#include "terrastride/planner/request_limits.hpp"
#include "terrastride/service/server.hpp"
#include "terrastride/terrain/height_field.hpp"
#include "terrastride/terrain/height_grid.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
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
// Points kept for "add" updates (the map is rebuilt from every cloud since the last replace).
constexpr std::size_t kMaxMapPoints = 20'000'000;

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

class Backend {
 public:
  explicit Backend(const BackendOptions& options) : options_(options) {
    robot_ = robot::load_robot(robot::resolve_robot_path(options.robot));
    plan_limits_.memory_bytes = options.plan_memory_bytes;
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
    if (!(foot_radius >= 0) || foot_radius > 0.5)  // as `terrastride query --foot-radius`
      throw ProtocolError(pc::kBadRequest, "\"foot_radius\" must be within [0, 0.5] m");
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
          throw ProtocolError(pc::kBadRequest,
                              "points[" + std::to_string(i) + "] must be [x, y] (two numbers)");
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
    if (!m) throw ProtocolError(pc::kNoMap, "no terrain map loaded: send map.update first");
    // A scanned map answers only for the radii whose safety layers it holds: computing a new
    // layer takes a distance transform over the whole grid, not a query's budget.
    const auto* grid_map = dynamic_cast<const terrain::TerrainMap*>(m->field.get());
    if (grid_map) {
      const auto radii = grid_map->radii();
      bool known = false;
      std::string list;
      for (double r : radii) {
        known = known || std::abs(r - foot_radius) < 1e-9;
        list += (list.empty() ? "" : ", ") + std::to_string(r);
      }
      if (!known)
        throw ProtocolError(pc::kBadRequest,
                            "\"foot_radius\" " + std::to_string(foot_radius) +
                                " has no safety layer in this map (available: " + list +
                                "); send map.update with \"foot_radii\" to add one");
      // Outside a scanned map nothing is known: refused, as `terrastride query` refuses it
      // (an analytic scene is defined everywhere and answers).
      const Eigen::Vector2d lo = grid_map->min_corner(), hi = grid_map->max_corner();
      for (std::size_t i = 0; i + 1 < xy.size(); i += 2)
        if (xy[i] < lo.x() || xy[i] > hi.x() || xy[i + 1] < lo.y() || xy[i + 1] > hi.y()) {
          std::ostringstream os;
          os << "points[" << i / 2 << "] (" << xy[i] << ", " << xy[i + 1]
             << ") is outside the map (x in [" << lo.x() << ", " << hi.x() << "], y in ["
             << lo.y() << ", " << hi.y() << "])";
          throw ProtocolError(pc::kBadRequest, os.str());
        }
    }
    // The reply is written as text directly: building a JSON tree of N objects costs more than
    // the terrain queries themselves.
    OpResult r;
    std::string text;
    text.reserve(64 + 160 * (xy.size() / 2));
    text += "{\"generation\":" + std::to_string(m->generation) + ",\"results\":[";
    for (std::size_t i = 0; i + 1 < xy.size(); i += 2) {
      const double x = xy[i], y = xy[i + 1];
      const auto s = m->field->sample(x, y);
      const auto mg = m->field->safety_margin(x, y, foot_radius);
      const bool observed = m->field->observed(x, y);
      const bool safe =
          grid_map ? grid_map->safe(x, y, foot_radius) : (observed && mg.margin > 0.0);
      text += i ? ",{\"x\":" : "{\"x\":";
      protocol::append_json_number(text, x);
      text += ",\"y\":";
      protocol::append_json_number(text, y);
      text += ",\"height\":";
      protocol::append_json_number(text, s.height);
      text += ",\"gradient\":[";
      protocol::append_json_number(text, s.gradient.x());
      text += ',';
      protocol::append_json_number(text, s.gradient.y());
      text += "],\"safe\":";
      text += safe ? "true" : "false";
      text += ",\"margin\":";
      protocol::append_json_number(text, mg.margin);
      text += ",\"observed\":";
      text += observed ? "true}" : "false}";
    }
    text += "]}";
    queries_++;
    points_queried_ += xy.size() / 2;
    r.result_text = std::move(text);
    return r;
  }

  OpResult map_update(OpContext& ctx) {
    const json& h = ctx.request.header;
    const std::string mode = protocol::get_string(h, "mode", std::string("add"));
    if (mode != "add" && mode != "replace")
      throw ProtocolError(pc::kBadRequest,
                          "\"mode\" must be \"add\" or \"replace\", got '" + mode + "'");
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
      clouds_.clear();
      cloud_points_ = 0;
      next->source = "scene:" + name;
      next->stats = {{"kind", "analytic"}, {"edges", scene->edges().size()}};
      next->field = std::move(scene);
    } else if (has_dir) {
      const std::string dir = protocol::get_string(h, "terrain_dir", std::nullopt);
      const auto t0 = std::chrono::steady_clock::now();
      std::unique_ptr<terrain::TerrainMap> tm;
      try {
        tm = terrain::load_terrain_dir(terrain_dir_path(dir, "terrain_dir"));
      } catch (const perception::InputError& e) {
        throw ProtocolError(pc::kBadRequest, std::string("\"terrain_dir\": ") + e.what());
      }
      for (double r : radii_from(h)) tm->layer(r);
      clouds_.clear();
      cloud_points_ = 0;
      next->source = "terrain_dir:" + dir;
      next->stats = grid_stats(*tm);
      next->stats["load_s"] = seconds_since(t0);
      next->field = std::move(tm);
    } else {
      next->stats = fuse_cloud(ctx, *points, mode);
      next->source = "cloud";
      next->field = std::move(pending_field_);
    }
    ctx.check_stop();
    const auto gen = publish(next);
    updates_++;
    OpResult r;
    r.result = {{"generation", gen}, {"source", next->source}, {"stats", next->stats}};
    return r;
  }

  // A name of a file in the data folder (letters, digits, '_', '-'): never a path.
  static bool is_plain_name(const std::string& name) {
    return !name.empty() && name.size() <= 64 &&
           std::all_of(name.begin(), name.end(), [](char c) {
             return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
           });
  }

  // A request's gait: a name from the data folder. The server reads no gait file a client names
  // ("/etc/shadow" would otherwise be opened, and the error would tell whether it exists).
  static std::string gait_name(const json& h) {
    const std::string gait = protocol::get_string(h, "gait", std::string("crawl"));
    std::string names;
    for (const auto& n : planner::gait_names()) names += (names.empty() ? "" : ", ") + n;
    if (!is_plain_name(gait))
      throw ProtocolError(pc::kBadRequest, "\"gait\": a gait name (" + names +
                                               "); the server reads no gait files");
    return gait;
  }

  // A terrain directory a client names: only inside one of the server's --terrain-root folders
  // (after resolving symlinks and ".."), and named relative to it or absolutely.
  std::string terrain_dir_path(const std::string& requested, const std::string& field) const {
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

  // Extra safety-layer radii to precompute ("foot_radii": [r, ...]); the robot's is always there.
  std::vector<double> radii_from(const json& h) const {
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

  static json grid_stats(const terrain::TerrainMap& tm) {
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

  // Filters the cloud, adds it to (or replaces) the clouds of the current map, rebuilds the height
  // grid and the safety layers; leaves the field in pending_field_. Caller holds update_mu_.
  json fuse_cloud(OpContext& ctx, const protocol::Attachment& att, const std::string& mode) {
    const json& h = ctx.request.header;
    const auto t0 = std::chrono::steady_clock::now();
    perception::PointCloud cloud;
    cloud.points = protocol::read_points(att);  // rejects NaN / infinity, wrong shapes
    if (cloud.points.empty())
      throw ProtocolError(pc::kBadRequest, "attachment 'points' holds no points");
    if (h.contains("origin") && !h["origin"].is_null())
      cloud.sensor_origin = protocol::get_vector(h, "origin", 3);
    cloud.source = "map.update";
    const double resolution = protocol::get_number(h, "resolution", 0.02);
    if (resolution < 0.002 || resolution > 1)
      throw ProtocolError(pc::kBadRequest, "\"resolution\" must be within [0.002, 1] m");
    const std::vector<double> radii = radii_from(h);
    // The same cleaning as `terrastride map` unless the request says otherwise.
    perception::CloudFilterOptions fo = perception::default_map_cleaning();
    fo.voxel_size = static_cast<float>(protocol::get_number(h, "voxel", fo.voxel_size));
    if (!(fo.voxel_size >= 0) || fo.voxel_size > 1)
      throw ProtocolError(pc::kBadRequest, "\"voxel\" must be within [0, 1] m (0 = off)");
    const double outliers = protocol::get_number(h, "outlier_neighbours", fo.outlier_neighbours);
    if (!(outliers >= 0) || outliers > 200 || outliers != std::floor(outliers))
      throw ProtocolError(pc::kBadRequest, "\"outlier_neighbours\" must be an integer in [0, 200]");
    fo.outlier_neighbours = static_cast<int>(outliers);
    const double outlier_cell = protocol::get_number(h, "outlier_cell", fo.outlier_voxel);
    if (!(outlier_cell >= 0) || outlier_cell > 0.1)
      throw ProtocolError(pc::kBadRequest,
                          "\"outlier_cell\" must be within [0, 0.1] m (0 = per point)");
    fo.outlier_voxel = static_cast<float>(outlier_cell);
    try {
      cloud = perception::filter_cloud(cloud, fo);
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("cloud filter: ") + e.what());
    }
    ctx.check_stop();
    std::vector<perception::PointCloud> clouds;
    std::size_t total = cloud.points.size();
    if (mode == "add") {
      clouds = clouds_;
      total += cloud_points_;
    }
    if (total > kMaxMapPoints)
      throw ProtocolError(pc::kBadRequest, "map would hold " + std::to_string(total) +
                                               " points, above the limit of " +
                                               std::to_string(kMaxMapPoints) +
                                               "; send mode \"replace\" or a voxel size");
    clouds.push_back(std::move(cloud));
    terrain::HeightGridOptions go;
    go.resolution = resolution;
    std::unique_ptr<terrain::TerrainMap> tm;
    try {
      terrain::HeightGrid grid = terrain::build_height_grid(clouds, go);
      ctx.check_stop();
      tm = std::make_unique<terrain::TerrainMap>(std::move(grid), radii);
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("height grid: ") + e.what());
    }
    ctx.check_stop();
    // Commit the new cloud set only now that the map was built.
    clouds_ = std::move(clouds);
    cloud_points_ = total;
    json stats = grid_stats(*tm);
    stats["clouds"] = clouds_.size();
    stats["points"] = cloud_points_;
    stats["build_s"] = seconds_since(t0);
    pending_field_ = std::move(tm);
    return stats;
  }

  // Serialised with updates (a worker op, so the I/O thread never waits for this lock).
  OpResult map_clear(OpContext&) {
    std::lock_guard<std::mutex> lock(update_mu_);
    clouds_.clear();
    cloud_points_ = 0;
    const bool had = map() != nullptr;
    const auto gen = publish(nullptr);
    OpResult r;
    r.result = {{"generation", gen}, {"cleared", had}};
    return r;
  }

  // `terrastride plan` over the socket: terrain "current" (the published map, default), a scene
  // name or a terrain dir. A deadline becomes the solver's wall-clock budget.
  OpResult plan(OpContext& ctx) {
    const json& h = ctx.request.header;
    gait_name(h);  // a name from the data folder: the server reads no gait file a client names
    // The same reader and limits as `terrastride plan` (plan_request.hpp).
    PlanRequest req;
    try {
      req = read_plan_request(h, robot_);
    } catch (const RequestFieldError& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    const std::string& spec = req.terrain;
    planner::PlannerOptions& po = req.options;
    const double sample_dt = req.sample_dt;
    const std::string& samples_encoding = req.samples;
    const planner::WarmStart warm = req.warm_start();
    // Terrains: the optimiser needs a C2 field; exact scenes are checked as they are.
    std::shared_ptr<const MapSnapshot> snapshot;  // keeps the published map alive while planning
    std::shared_ptr<const SceneRaster> raster;
    std::unique_ptr<terrain::TerrainMap> smooth;
    const terrain::HeightField* plan_field = nullptr;
    const terrain::HeightField* check_field = nullptr;
    try {
      if (spec == "current") {
        snapshot = map();
        if (!snapshot) throw ProtocolError(pc::kNoMap, "plan on \"current\": no map loaded");
        if (const auto* sc = dynamic_cast<const terrain::Scene*>(snapshot->field.get())) {
          raster = scene_raster(snapshot->source.substr(snapshot->source.find(':') + 1));
          plan_field = raster->smooth.get();
          check_field = sc;
        } else {
          plan_field = check_field = snapshot->field.get();
        }
      } else {
        const auto names = terrain::scene_names();
        if (std::find(names.begin(), names.end(), spec) != names.end()) {
          raster = scene_raster(spec);
          plan_field = raster->smooth.get();
          check_field = raster->scene.get();
        } else {
          smooth = terrain::load_terrain_dir(terrain_dir_path(spec, "terrain"));
          plan_field = check_field = smooth.get();
        }
      }
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, "\"terrain\" " + spec + ": " + e.what());
    }
    json stance_corrections;
    try {
      check_stances_on_terrain(req, robot_, *check_field);
      stance_corrections = settle_stance_feet(&req, *plan_field);
    } catch (const RequestFieldError& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    ctx.check_stop();
    // Cancel, deadline and shutdown stop the solve within one Ipopt iteration (the planner polls
    // the token); the deadline also caps Ipopt's own wall-clock budget.
    po.should_stop = CancellationToken::as_callback(ctx.token);
    if (ctx.token->has_deadline()) {
      const double left =
          std::chrono::duration<double>(ctx.token->deadline() - std::chrono::steady_clock::now())
              .count();
      if (left <= 0) ctx.check_stop();
      po.max_time = po.max_time > 0 ? std::min(po.max_time, left) : left;
    }
    // The solve, the samples and the reply run in a child process (child_process.hpp): Debian's
    // MUMPS is not re-entrant, so two plans in one process crash it; as processes they run at
    // once, their memory goes back when they end, and cancel/deadline/shutdown kill them at once.
    auto work = [&]() -> OpResult {
      planner::PlanOutcome out;
      try {
        out = planner::plan_motion(robot_, *plan_field, *check_field, po, sample_dt, warm);
      } catch (const planner::GaitError& e) {
        throw ProtocolError(pc::kBadRequest, std::string("\"gait\": ") + e.what());
      } catch (const planner::RequestError& e) {
        throw ProtocolError(pc::kBadRequest, e.what());
      } catch (const std::invalid_argument& e) {
        throw ProtocolError(pc::kBadRequest, e.what());
      }
      ctx.check_stop();
      const double violation = out.solve.max_violation;
      if (!out.success && violation > 1e-3)
        throw ProtocolError(
            pc::kFailed,
            "plan: " +
                (out.message.empty() ? "status " + out.trajectory.solver.status : out.message) +
                " (max violation " + std::to_string(violation) + ")");
      out.trajectory.extra["terrain"] = spec;
      if (warm.previous) out.trajectory.extra["start_time"] = warm.shift;
      if (!stance_corrections.empty())
        out.trajectory.extra["start_state_corrections"] = stance_corrections;
      // The post-hoc checks `terrastride plan` runs, on what this server has: an exact scene
      // voxelised for the leg capsules; a scanned map without them (the server keeps no OctoMap).
      collision::CheckTerrain view;
      if (raster) {
        view = scene_check_terrain(*raster->scene, spec, robot_, out.trajectory, kPostHocVoxel);
      } else {
        view.field = check_field;
        view.description = spec + " (no OctoMap in the server: leg capsules not checked)";
      }
      const std::vector<std::string> failures =
          add_post_hoc_checks(robot_, view, &out.trajectory);
      OpResult r;
      if (samples_encoding == "attachment") {
        // The samples as one float32 table (see docs/protocol.md): building, printing and parsing
        // a JSON tree of a thousand samples costs tens of milliseconds; the table costs a copy.
        std::vector<planner::TrajectorySample> samples = std::move(out.trajectory.samples);
        out.trajectory.samples.clear();
        r.result = planner::plan_to_json(out.trajectory);
        r.attachments.push_back(samples_table(samples, out.trajectory.feet, &r.result));
      } else {
        r.result = planner::plan_to_json(out.trajectory);
      }
      // Success means a usable plan: solved, and every post-hoc check passed.
      r.result["success"] = out.success && failures.empty();
      r.result["checks_passed"] = failures.empty();
      r.result["max_violation"] = violation;
      if (!out.message.empty()) r.result["message"] = out.message;
      return r;
    };
    if (!options_.plan_in_child_process) return work();
    return run_in_child_process(ctx, work, plan_limits_, &plan_processes_);
  }

  // `terrastride check` over the socket: the post-hoc checks of a plan.json object against the
  // current map (or a scene). The server keeps no OctoMap, so the capsule (shin/thigh) checks do
  // not run here and their keys are absent, never faked.
  OpResult check(OpContext& ctx) {
    const json& h = ctx.request.header;
    const auto it = h.find("plan");
    if (it == h.end() || !it->is_object())
      throw ProtocolError(pc::kBadRequest, "check needs \"plan\": a plan.json object");
    planner::Trajectory traj;
    try {
      traj = planner::plan_from_json(*it, "plan");
    } catch (const std::exception& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    robot::RobotModel model = robot_;
    if (!traj.robot.empty() && traj.robot != robot_.name) {
      // A robot name from the data folder, never a path a client names (see gait_name).
      if (!is_plain_name(traj.robot))
        throw ProtocolError(pc::kBadRequest,
                            "plan.robot: a robot name (e.g. " + robot_.name +
                                "); the server reads no robot files a client names");
      try {
        model = robot::load_robot(robot::resolve_robot_path(traj.robot));
      } catch (const robot::RobotFileError& e) {
        throw ProtocolError(pc::kBadRequest, std::string("plan.robot: ") + e.what());
      }
    }
    const std::string spec = protocol::get_string(h, "terrain", std::string("current"));
    std::shared_ptr<const MapSnapshot> snapshot;
    std::unique_ptr<terrain::Scene> scene;
    collision::CheckTerrain terrain;
    if (spec == "current") {
      snapshot = map();
      if (!snapshot) throw ProtocolError(pc::kNoMap, "check on \"current\": no map loaded");
      terrain.field = snapshot->field.get();
      terrain.description = snapshot->source;
    } else {
      try {
        scene = terrain::make_scene(spec);
      } catch (const perception::InputError& e) {
        throw ProtocolError(pc::kBadRequest, std::string("\"terrain\": ") + e.what());
      }
      terrain.field = scene.get();
      terrain.description = "scene:" + spec;
    }
    ctx.check_stop();
    collision::CheckReport report;
    try {
      report = collision::run_checks(model, traj, terrain);
    } catch (const std::invalid_argument& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    OpResult r;
    r.result = {{"checks", report.keys()},
                {"failures", report.failures()},
                {"passed", report.passed()},
                {"terrain", terrain.description},
                {"wall_s", report.wall_s}};
    return r;
  }

  // Plan samples as a float32 attachment named "samples", one row per sample; the column names
  // go into result["samples"] = {"attachment", "columns", "rows"}.
  static protocol::Attachment samples_table(const std::vector<planner::TrajectorySample>& samples,
                                            const std::vector<std::string>& feet, json* result) {
    std::vector<std::string> columns{"t"};
    auto add3 = [&](const std::string& prefix) {
      for (const char* axis : {".x", ".y", ".z"}) columns.push_back(prefix + axis);
    };
    for (const char* field : {"position", "euler_zyx", "linear_velocity", "angular_velocity",
                              "linear_acceleration", "angular_acceleration"})
      add3(std::string("base.") + field);
    for (const auto& foot : feet) {
      for (const char* field : {"position", "velocity", "force"}) add3(foot + "." + field);
      columns.push_back(foot + ".contact");
    }
    protocol::Attachment a;
    a.name = "samples";
    a.shape = {samples.size(), columns.size()};
    std::vector<float> table;
    table.reserve(samples.size() * columns.size());
    auto put3 = [&](const Eigen::Vector3d& v) {
      for (int i = 0; i < 3; ++i) table.push_back(static_cast<float>(v[i]));
    };
    for (const auto& smp : samples) {
      table.push_back(static_cast<float>(smp.t));
      put3(smp.base.position);
      put3(smp.base.euler_zyx);
      put3(smp.base.linear_velocity);
      put3(smp.base.angular_velocity);
      put3(smp.base.linear_acceleration);
      put3(smp.base.angular_acceleration);
      for (std::size_t f = 0; f < feet.size(); ++f) {
        const planner::FootState& fs = smp.feet.at(f);
        put3(fs.position);
        put3(fs.velocity);
        put3(fs.force);
        table.push_back(fs.contact ? 1.0f : 0.0f);
      }
    }
    a.data.assign(reinterpret_cast<const char*>(table.data()), table.size() * sizeof(float));
    (*result)["samples"] = {{"attachment", a.name}, {"columns", columns}, {"rows", samples.size()}};
    return a;
  }

  // Scenes are immutable and made from their name alone, so a scene and its C2 rasterisation
  // (about 10 ms) are built once per name and shared by every plan on it.
  struct SceneRaster {
    std::shared_ptr<const terrain::Scene> scene;
    std::unique_ptr<terrain::TerrainMap> smooth;
  };
  std::shared_ptr<const SceneRaster> scene_raster(const std::string& name) {
    {
      std::lock_guard<std::mutex> lock(raster_mu_);
      const auto it = rasters_.find(name);
      if (it != rasters_.end()) return it->second;
    }
    auto r = std::make_shared<SceneRaster>();
    r->scene = terrain::make_scene(name);
    r->smooth = terrain::TerrainMap::from_scene(*r->scene, 0.02, {});
    std::lock_guard<std::mutex> lock(raster_mu_);
    return rasters_.emplace(name, std::move(r)).first->second;
  }

  OpResult unavailable(const std::string& op, const std::string& module) {
    throw ProtocolError(pc::kUnavailable,
                        op + ": the " + module + " is not built into this server yet");
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
    r.result = {{"slept_ms",
                 std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                     .count()}};
    return r;
  }

  const BackendOptions& options() const { return options_; }

  json plan_processes_json() const {
    return {{"isolated", options_.plan_in_child_process},
            {"memory_limit_bytes", plan_limits_.memory_bytes},
            {"started", plan_processes_.started.load()},
            {"running", plan_processes_.running.load()},
            {"stopped", plan_processes_.stopped.load()},
            {"died", plan_processes_.died.load()}};
  }

 private:
  BackendOptions options_;
  robot::RobotModel robot_;
  std::shared_ptr<const MapSnapshot> map_;
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<std::uint64_t> queries_{0}, points_queried_{0}, updates_{0};
  std::mutex update_mu_;
  std::mutex raster_mu_;
  std::map<std::string, std::shared_ptr<const SceneRaster>> rasters_;
  // Guarded by update_mu_: the clouds behind the current map ("add" rebuilds from all of them).
  std::vector<perception::PointCloud> clouds_;
  std::size_t cloud_points_ = 0;
  std::shared_ptr<const terrain::HeightField> pending_field_;
  ChildProcessLimits plan_limits_;
  ChildProcessStats plan_processes_;
};

std::shared_ptr<Backend> make_backend(const BackendOptions& options, OperationRegistry& registry) {
  auto b = std::make_shared<Backend>(options);
  Backend* p = b.get();
  // Each operation lists the request fields it reads: any other key is refused by name (a
  // misspelt "optimise_timing" would otherwise plan with the default silently).
  using Fields = std::vector<std::string>;
  registry.add({"map.query", OpKind::kInline,
                "height, gradient, safety margin for a batch of (x, y) points",
                [p](OpContext& c) { return p->map_query(c); }, Fields{"points", "foot_radius"}});
  registry.add({"map.update", OpKind::kWorker,
                "replace or extend the terrain map (scene, terrain dir or point cloud)",
                [p](OpContext& c) { return p->map_update(c); },
                Fields{"mode", "scene", "terrain_dir", "origin", "resolution", "voxel",
                       "outlier_neighbours", "outlier_cell", "foot_radii"}});
  registry.add({"map.clear", OpKind::kWorker, "drop the terrain map",
                [p](OpContext& c) { return p->map_clear(c); }, Fields{}});
  registry.add({"plan", OpKind::kWorker, "plan a motion (as `terrastride plan`)",
                [p](OpContext& c) { return p->plan(c); },
                Fields{"terrain", "gait", "cycles", "duration", "goal", "constraints",
                       "feasibility", "sample_dt", "samples", "optimize_timing", "max_time", "init",
                       "start_time", "start_state"}});
  registry.add({"check", OpKind::kWorker, "post-hoc checks of a plan (as `terrastride check`)",
                [p](OpContext& c) { return p->check(c); }, Fields{"plan", "terrain"}});
  if (options.debug_ops)
    registry.add({"debug.sleep", OpKind::kWorker, "test op: hold a worker for ms milliseconds",
                  [p](OpContext& c) { return p->debug_sleep(c); }, Fields{"ms"}});
  return b;
}

json backend_status(const Backend& backend) {
  return {{"map", backend.map_json()}, {"plan_processes", backend.plan_processes_json()}};
}

json backend_hello(const Backend& backend) {
  return {{"robot", backend.robot_json()}, {"map", backend.map_json()}};
}

}  // namespace terrastride::service
