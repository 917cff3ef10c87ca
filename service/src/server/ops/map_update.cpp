// map.update: replace or extend the terrain map from a scene, a terrain directory or a point
// cloud (float32 points in the world frame, or a serialised sensor_msgs/PointCloud2 with the
// sensor's pose); the new map is published atomically (queries see the old map or the new one).
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "server/backend.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/ros_messages.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride::service {

namespace pc = protocol::code;
using nlohmann::json;
using protocol::ProtocolError;

namespace {

// Points kept for "add" updates (the map is rebuilt from every cloud since the last replace).
constexpr std::size_t kMaxMapPoints = 20'000'000;

struct FusedMap {
  std::shared_ptr<const terrain::HeightField> field;
  std::shared_ptr<const octomap::OcTree> octree;
  json stats;
};

// Cleans the cloud and rebuilds the map from it, after the clouds of the current map for "add"
// (terrain::build_terrain_map: cleaning, height grid, safety layers, and the OctoMap that the
// post-hoc leg-capsule and trunk checks of a plan on this map need, as `terrastride map` builds
// it). Caller holds the backend's update mutex.
FusedMap fuse_cloud(Backend& backend, OpContext& ctx, perception::PointCloud cloud,
                    const std::string& mode) {
  const json& h = ctx.request.header;
  const auto t0 = std::chrono::steady_clock::now();
  // Refused before cleaning (which would take minutes on such a cloud), not only at the grid.
  if (cloud.points.size() > kMaxMapPoints)
    throw ProtocolError(pc::kBadRequest, "the cloud holds " + std::to_string(cloud.points.size()) +
                                             " points, above the map's limit of " +
                                             std::to_string(kMaxMapPoints));
  cloud.source = "map.update";
  terrain::MapBuildOptions options;
  options.grid.resolution = protocol::get_number(h, "resolution", 0.02);
  if (options.grid.resolution < 0.002 || options.grid.resolution > 1)
    throw ProtocolError(pc::kBadRequest, "\"resolution\" must be within [0.002, 1] m");
  options.foot_radii = backend.radii_from(h);
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
  options.cleaning = fo;
  CloudHistory& history = backend.clouds();
  const bool add = mode == "add";
  if (add) options.cleaned_before = &history.clouds;
  // Once the cloud is cleaned: a stop request, or a map above the point budget, ends the build
  // before the grid.
  std::size_t total = 0;
  options.on_stage = [&](terrain::MapStage stage, const terrain::MapBuild& so_far) {
    if (stage != terrain::MapStage::kGrid) return;
    ctx.check_stop();
    total = so_far.points_kept + (add ? history.points : 0);
    if (total > kMaxMapPoints)
      throw ProtocolError(pc::kBadRequest, "map would hold " + std::to_string(total) +
                                               " points, above the limit of " +
                                               std::to_string(kMaxMapPoints) +
                                               "; send mode \"replace\" or a voxel size");
  };
  std::vector<perception::PointCloud> clouds;
  clouds.push_back(std::move(cloud));
  terrain::MapBuild build;
  try {
    build = terrain::build_terrain_map(std::move(clouds), options);
  } catch (const terrain::MapBuildError& e) {
    throw ProtocolError(pc::kBadRequest,
                        std::string(e.stage() == terrain::MapStage::kClean ? "cloud filter: "
                                                                           : "height grid: ") +
                            e.what());
  }
  ctx.check_stop();
  // Commit the new cloud set only now that the map was built.
  history.clouds = std::move(build.clouds);
  history.points = total;
  FusedMap fused;
  fused.stats = grid_stats(*build.map);
  fused.stats["clouds"] = history.clouds.size();
  fused.stats["points"] = history.points;
  fused.stats["build_s"] = seconds_since(t0);
  fused.stats["octomap_resolution"] =
      build.octree ? json(build.octree->getResolution()) : json(nullptr);
  fused.field = std::move(build.map);
  fused.octree = std::move(build.octree);
  return fused;
}

// The placement fields both cloud attachments take: "up", "sensor_frame" and "pose".
terrain::CloudPoseOptions placement_options(const json& h) {
  terrain::CloudPoseOptions poses;
  poses.up = terrain::UpMode::kZ;
  const std::string up = protocol::get_string(h, "up", std::string("z"));
  if (up == "check") {
    poses.up = terrain::UpMode::kCheck;
  } else if (up == "auto") {
    poses.up = terrain::UpMode::kAuto;
  } else if (up != "z") {
    throw ProtocolError(pc::kBadRequest, "\"up\" must be \"z\", \"check\" or \"auto\", got '" +
                                             up + "'");
  }
  const std::string frame = protocol::get_string(h, "sensor_frame", std::string("body"));
  if (frame != "body" && frame != "optical")
    throw ProtocolError(pc::kBadRequest,
                        "\"sensor_frame\" must be \"body\" or \"optical\", got '" + frame + "'");
  if (frame == "optical") poses.sensor_frame = perception::SensorFrame::kOptical;
  if (h.contains("pose")) {
    const Eigen::VectorXd v = protocol::get_vector(h, "pose", 7);  // finite numbers
    perception::SensorPose pose;
    pose.position = v.head<3>();
    try {
      pose.orientation = perception::checked_quaternion(v[3], v[4], v[5], v[6], "\"pose\"");
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, e.what());
    }
    poses.sensor_pose = pose;
  }
  return poses;
}

// The float32 attachment "points": world-frame points with an optional "origin", or points in
// the frame whose pose "pose" [x, y, z, qx, qy, qz, qw] gives ("sensor_frame": "optical" when
// they are in a camera's optical frame and the pose is its body's); "up" as `terrastride map
// --up`, "z" by default (the attachment's points have always been world-frame). Placed by
// terrain::place_map_points, as `map` places a cloud file; *info gets the placement.
perception::PointCloud cloud_from_points(const json& h, const protocol::Attachment& att,
                                         json* info) {
  if (h.contains("frame") || h.contains("encoding"))
    throw ProtocolError(pc::kBadRequest, "\"frame\" and \"encoding\" go with a \"pointcloud2\" "
                                         "attachment, not with \"points\"");
  std::vector<Eigen::Vector3f> points = protocol::read_points(att);  // rejects NaN, bad shapes
  if (points.empty()) throw ProtocolError(pc::kBadRequest, "attachment 'points' holds no points");
  terrain::CloudPoseOptions poses = placement_options(h);
  if (h.contains("origin") && !h["origin"].is_null())
    poses.origin = protocol::get_vector(h, "origin", 3);
  try {
    terrain::CloudPlacement placement;
    perception::PointCloud cloud =
        terrain::place_map_points(std::move(points), "attachment 'points'", poses, &placement);
    *info = terrain::placement_json(placement);
    return cloud;
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
}

// The uint8 attachment "pointcloud2": a sensor_msgs/PointCloud2 as its driver serialised it (ROS
// 2 CDR with its 4-byte encapsulation header, or ROS 1), decoded by the bag reader's decoder (any
// field layout with float32/float64 x, y, z; NaN points, an organised cloud's misses, dropped and
// counted), placed in the world frame with "pose" [x, y, z, qx, qy, qz, qw], the pose of the
// cloud's frame (the sensor) in the world (its position is the sensor origin for ray casting),
// "sensor_frame" and "up" as the "points" attachment takes them (terrain::place_map_points).
perception::PointCloud cloud_from_pointcloud2(const json& h, const protocol::Attachment& att,
                                              json* info) {
  if (h.contains("origin"))
    throw ProtocolError(pc::kBadRequest, "a \"pointcloud2\" attachment takes \"pose\" (the "
                                         "sensor's position and orientation), not \"origin\"");
  const std::string_view bytes = protocol::read_bytes(att);
  const std::string encoding = protocol::get_string(h, "encoding", std::string("cdr"));
  if (encoding != "cdr" && encoding != "ros1")
    throw ProtocolError(pc::kBadRequest,
                        "\"encoding\" must be \"cdr\" (ROS 2) or \"ros1\", got '" + encoding + "'");
  if (!h.contains("pose"))
    throw ProtocolError(pc::kBadRequest,
                        "a \"pointcloud2\" attachment needs \"pose\": [x, y, z, qx, qy, qz, qw], "
                        "the pose of the cloud's frame (the sensor) in the map's frame");
  const terrain::CloudPoseOptions poses = placement_options(h);
  perception::DecodedCloud decoded;
  try {
    decoded = perception::decode_pointcloud2(
        bytes, encoding == "ros1" ? perception::MessageEncoding::kRos1
                                  : perception::MessageEncoding::kCdr);
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, std::string("attachment 'pointcloud2': ") + e.what());
  }
  // tf2 frame names carry no leading slash (ROS 1 drivers' often do).
  std::string frame_id = decoded.frame_id;
  if (!frame_id.empty() && frame_id.front() == '/') frame_id.erase(0, 1);
  if (h.contains("frame")) {
    std::string frame = protocol::get_string(h, "frame", std::nullopt);
    if (!frame.empty() && frame.front() == '/') frame.erase(0, 1);
    if (frame != frame_id)
      throw ProtocolError(pc::kBadRequest, "attachment 'pointcloud2' is in frame '" + frame_id +
                                               "', but \"frame\" says '" + frame +
                                               "' (the pose is that frame's)");
  }
  if (decoded.points.empty())
    throw ProtocolError(pc::kBadRequest, "attachment 'pointcloud2' holds no finite points (" +
                                             std::to_string(decoded.points_in) + " points, " +
                                             std::to_string(decoded.non_finite) +
                                             " NaN or infinite)");
  perception::PointCloud cloud;
  terrain::CloudPlacement placement;
  try {
    cloud = terrain::place_map_points(std::move(decoded.points), "attachment 'pointcloud2'", poses,
                                      &placement);
  } catch (const perception::InputError& e) {
    throw ProtocolError(pc::kBadRequest, e.what());
  }
  *info = {{"frame", frame_id},
           {"stamp", static_cast<double>(decoded.stamp_ns) * 1e-9},
           {"width", decoded.width},
           {"height", decoded.height},
           {"points", cloud.points.size()},
           {"non_finite", decoded.non_finite}};
  info->update(terrain::placement_json(placement));  // "pose" and "up", as for "points"
  return cloud;
}

OpResult map_update(Backend& backend, OpContext& ctx) {
  const json& h = ctx.request.header;
  const std::string mode = protocol::get_string(h, "mode", std::string("add"));
  if (mode != "add" && mode != "replace")
    throw ProtocolError(pc::kBadRequest,
                        "\"mode\" must be \"add\" or \"replace\", got '" + mode + "'");
  const bool has_scene = h.contains("scene");
  const bool has_dir = h.contains("terrain_dir");
  const auto* points = ctx.request.find("points");
  const auto* pointcloud2 = ctx.request.find("pointcloud2");
  if (int(has_scene) + int(has_dir) + int(points != nullptr) + int(pointcloud2 != nullptr) != 1)
    throw ProtocolError(pc::kBadRequest,
                        "map.update needs exactly one source: \"scene\" (a scenario name), "
                        "\"terrain_dir\" (a `terrastride map` output), a float32 attachment "
                        "\"points\" of shape [N, 3] with \"origin\", or a uint8 attachment "
                        "\"pointcloud2\" (a serialised sensor_msgs/PointCloud2) with \"pose\"");
  // A cloud is decoded and checked before the update lock: a bad one never waits for, or holds
  // up, another update.
  json cloud_info;
  std::optional<perception::PointCloud> cloud;
  if (points) cloud = cloud_from_points(h, *points, &cloud_info);
  if (pointcloud2) cloud = cloud_from_pointcloud2(h, *pointcloud2, &cloud_info);
  // Updates are serialised; queries never wait.
  std::lock_guard<std::mutex> lock(backend.update_mutex());
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
    backend.clouds().clear();
    next->source = "scene:" + name;
    next->stats = {{"kind", "analytic"}, {"edges", scene->edges().size()}};
    next->field = std::move(scene);
  } else if (has_dir) {
    const std::string dir = protocol::get_string(h, "terrain_dir", std::nullopt);
    const auto t0 = std::chrono::steady_clock::now();
    // The map and the scan's occupancy map, when the folder has one (`terrastride map` writes
    // it), for the post-hoc leg and trunk checks; without it a plan's capsules and trunk are not
    // checked (as `terrastride plan --terrain DIR`), which its post_hoc.terrain says.
    terrain::OpenedTerrain opened;
    try {
      opened = backend.open_terrain_dir(dir, "terrain_dir", /*octomap=*/true);
    } catch (const perception::InputError& e) {
      throw ProtocolError(pc::kBadRequest, std::string("\"terrain_dir\": ") + e.what());
    }
    const std::shared_ptr<const terrain::TerrainMap> tm = opened.map;
    for (double r : backend.radii_from(h)) tm->layer(r);
    next->octree = opened.octree;
    backend.clouds().clear();
    next->source = "terrain_dir:" + dir;
    next->stats = grid_stats(*tm);
    next->stats["octomap_resolution"] =
        next->octree ? json(next->octree->getResolution()) : json(nullptr);
    next->stats["load_s"] = seconds_since(t0);
    next->field = tm;
  } else {
    FusedMap fused = fuse_cloud(backend, ctx, std::move(*cloud), mode);
    next->stats = std::move(fused.stats);
    if (pointcloud2) next->stats["pointcloud2"] = std::move(cloud_info);
    if (points) next->stats["placement"] = std::move(cloud_info);
    next->source = pointcloud2 ? "pointcloud2" : "cloud";
    next->field = std::move(fused.field);
    next->octree = std::move(fused.octree);
  }
  ctx.check_stop();
  const auto gen = backend.publish(next);
  backend.count_update();
  OpResult r;
  r.result = {{"generation", gen}, {"source", next->source}, {"stats", next->stats}};
  return r;
}

}  // namespace

void add_map_update_operation(Backend& backend, OperationRegistry& registry) {
  Backend* b = &backend;
  registry.add({"map.update", OpKind::kWorker,
                "replace or extend the terrain map (scene, terrain dir or point cloud)",
                [b](OpContext& c) { return map_update(*b, c); },
                std::vector<std::string>{"mode", "scene", "terrain_dir", "origin", "pose",
                                         "sensor_frame", "up", "frame", "encoding",
                                         "resolution", "voxel",
                                         "outlier_neighbours", "outlier_cell", "foot_radii"},
                std::vector<std::string>{"points", "pointcloud2"}});
}

}  // namespace terrastride::service
