// The terrain's Foxglove topics (terrain_topics.hpp).
#include "export/terrain_topics.hpp"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <regex>

#include "terrastride/perception/bag_clouds.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride::service::foxglove {

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// One float field of a grid message: its name, the value of fine cell k, and how a coarse cell
// of several fine ones sums them up (the worst for a margin: its minimum; the top for a height).
struct GridField {
  std::string name;
  std::function<float(size_t)> value;
  bool take_min = false;
};

// A foxglove.Grid of `fields` over the view, each cell `k` x `k` of the view's (k chosen so that
// the message stays under the budget; 1 on ordinary maps).
json grid_message(const Clock& clock, const report::TerrainView& view,
                  const std::vector<GridField>& fields, size_t* decimation) {
  const size_t stride = 4 * fields.size();
  const double raw_budget = 0.7 * kMessageBudget;  // base64 makes 4 bytes of 3
  size_t k = 1;
  while (static_cast<double>(view.nx / k + 1) * (view.ny / k + 1) * stride > raw_budget) ++k;
  const int cx = static_cast<int>((view.nx + k - 1) / k),
            cy = static_cast<int>((view.ny + k - 1) / k);
  std::string data(static_cast<size_t>(cx) * cy * stride, '\0');
  for (int J = 0; J < cy; ++J)
    for (int I = 0; I < cx; ++I) {
      char* cell = data.data() + (static_cast<size_t>(J) * cx + I) * stride;
      for (size_t f = 0; f < fields.size(); ++f) {
        float v = kNaN;
        for (int i = I * static_cast<int>(k); i < std::min(view.nx, (I + 1) * static_cast<int>(k));
             ++i)
          for (int j = J * static_cast<int>(k);
               j < std::min(view.ny, (J + 1) * static_cast<int>(k)); ++j) {
            const float x = fields[f].value(view.index(i, j));
            if (!std::isfinite(x)) continue;
            v = std::isnan(v) ? x : fields[f].take_min ? std::min(v, x) : std::max(v, x);
          }
        std::memcpy(cell + 4 * f, &v, 4);
      }
    }
  json jfields = json::array();
  for (size_t f = 0; f < fields.size(); ++f)
    jfields.push_back({{"name", fields[f].name}, {"offset", 4 * f}, {"type", 7}});  // FLOAT32
  *decimation = k;
  const double cell = view.resolution * static_cast<double>(k);
  return {{"timestamp", clock.stamp(0)},
          {"frame_id", kMapFrame},
          {"pose", pose(Eigen::Vector3d(view.origin.x(), view.origin.y(), 0.0))},
          {"column_count", cx},
          {"cell_size", {{"x", cell}, {"y", cell}}},
          {"row_stride", cx * stride},
          {"cell_stride", stride},
          {"fields", jfields},
          {"data", base64(data)}};
}

bool has_overhead(const report::TerrainView& view) {
  return view.overhead.size() == view.height.size() && !view.overhead.empty();
}

void publish_grids(Publisher& pub, const Clock& clock, const report::TerrainView& view,
                   TerrainTopicStats* stats) {
  std::vector<GridField> fields{{"height", [&](size_t k) { return view.height[k]; }}};
  for (size_t r = 0; r < view.radii.size(); ++r) {
    char name[64];
    std::snprintf(name, sizeof name, "margin_r%.3f", view.radii[r]);
    fields.push_back({name, [&view, r](size_t k) { return view.margin[r][k]; }, true});
  }
  size_t k = 1;
  json grid = grid_message(clock, view, fields, &k);
  stats->grid_decimation = k;
  pub.publish(pub.channel("/terrain/grid", "foxglove.Grid",
                          {{"source", view.source},
                           {"kind", view.kind},
                           {"cell_m", std::to_string(view.resolution * k)},
                           {"decimation", std::to_string(k)}}),
              clock.ns(0), grid);
  if (!has_overhead(view)) return;
  // The overhead layer: the underside of the lowest overhang (world z) and the free height
  // beneath it above the walkable surface; NaN (uncoloured) where nothing is overhead.
  const auto overhead = [&](size_t c) {
    return std::isfinite(view.overhead[c]) ? view.overhead[c] : kNaN;
  };
  const std::vector<GridField> over{
      {"overhead", overhead, true},
      {"clearance", [&](size_t c) { return overhead(c) - view.height[c]; }, true}};
  json g = grid_message(clock, view, over, &k);
  pub.publish(pub.channel("/terrain/overhead", "foxglove.Grid",
                          {{"cell_m", std::to_string(view.resolution * k)}}),
              clock.ns(0), g);
  // In 3-D: a thin violet tile per cell at the overhang's underside, tiled 2 m x 2 m.
  std::map<std::pair<int, int>, json> tiles;
  for (int i = 0; i < view.nx; ++i)
    for (int j = 0; j < view.ny; ++j) {
      const float z = view.overhead[view.index(i, j)];
      if (!std::isfinite(z)) continue;
      const Eigen::Vector2d c = view.center(i, j);
      const auto key = std::make_pair(static_cast<int>(std::floor(c.x() / 2.0)),
                                      static_cast<int>(std::floor(c.y() / 2.0)));
      if (!tiles.count(key))
        tiles[key] = entity(
            clock, 0, "overhangs_" + std::to_string(key.first) + "_" + std::to_string(key.second));
      tiles[key]["cubes"].push_back(cube(Eigen::Vector3d(c.x(), c.y(), z),
                                         Eigen::Vector3d(view.resolution, view.resolution, 0.01),
                                         color(0.48, 0.17, 0.75, 0.6)));
    }
  std::vector<json> entities;
  for (auto& [key, e] : tiles) entities.push_back(std::move(e));
  publish_entities(pub, pub.channel("/terrain/overhangs", "foxglove.SceneUpdate"), clock.ns(0),
                   entities, kMessageBudget);
}

// Occupied voxels as cubes, one entity per 2 m x 2 m column of the map (split further when a
// column alone would pass the budget), packed into SceneUpdate messages under the budget.
void publish_voxels(Publisher& pub, const Clock& clock, const octomap::OcTree& tree,
                    size_t max_voxels, TerrainTopicStats* stats) {
  constexpr double kTile = 2.0;
  constexpr size_t kCubesPerEntity = 15000;  // ~150 bytes of JSON each
  std::map<std::pair<int, int>, std::vector<json>> tiles;
  double zmin = 0, zmax = 0, xmin = 0, ymin = 0, xmax = 0, ymax = 0;
  tree.getMetricMin(xmin, ymin, zmin);
  tree.getMetricMax(xmax, ymax, zmax);
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    if (!tree.isNodeOccupied(*it)) continue;
    if (stats->voxels >= max_voxels) break;
    const double s = it.getSize(), z = it.getZ();
    const double shade = std::clamp(0.4 + 0.6 * std::tanh(std::max(0.0, z - zmin)), 0.4, 1.0);
    tiles[{static_cast<int>(std::floor(it.getX() / kTile)),
           static_cast<int>(std::floor(it.getY() / kTile))}]
        .push_back(cube(Eigen::Vector3d(it.getX(), it.getY(), z), Eigen::Vector3d::Constant(s),
                        color(0.55 * shade, 0.45 * shade, 0.35 * shade, 0.85)));
    ++stats->voxels;
  }
  std::vector<json> entities;
  for (auto& [key, cubes] : tiles)
    for (size_t first = 0, part = 0; first < cubes.size(); first += kCubesPerEntity, ++part) {
      json e = entity(clock, 0,
                      "voxels_" + std::to_string(key.first) + "_" + std::to_string(key.second) +
                          "_" + std::to_string(part));
      const size_t last = std::min(cubes.size(), first + kCubesPerEntity);
      e["cubes"] = json(std::vector<json>(cubes.begin() + first, cubes.begin() + last));
      e["metadata"].push_back({{"key", "voxels"}, {"value", std::to_string(last - first)}});
      entities.push_back(std::move(e));
    }
  const uint16_t ch =
      pub.channel("/terrain/voxels", "foxglove.SceneUpdate",
                  {{"voxels", std::to_string(stats->voxels)}, {"tile_m", std::to_string(kTile)}});
  stats->voxel_messages = publish_entities(pub, ch, clock.ns(0), entities, kMessageBudget);
}

// ---- The relief: the walkable surface as triangles through the cell centres, coloured by the
// safety margin of the robot's foot; flat blocks of one colour merged into two triangles.

struct ReliefMesh {
  const report::TerrainView& view;
  size_t layer;  // margin layer the colours come from
  std::vector<std::vector<Eigen::Vector3d>> by_class = std::vector<std::vector<Eigen::Vector3d>>(4);
  size_t triangles = 0;

  static constexpr double kFlatTolerance = 0.005;  // m off the block's bilinear surface

  // 0 unsafe (< 0), 1 within 2 cm, 2 safe, 3 margin unknown.
  int colour_class(int i, int j) const {
    const float m = view.margin[layer][view.index(i, j)];
    if (!std::isfinite(m)) return 3;
    return m < 0 ? 0 : m < 0.02 ? 1 : 2;
  }
  Eigen::Vector3d vertex(int i, int j) const {
    const Eigen::Vector2d c = view.center(i, j);
    return {c.x(), c.y(), view.height[view.index(i, j)]};
  }
  bool known(int i, int j) const { return std::isfinite(view.height[view.index(i, j)]); }
  void quad(int i0, int j0, int i1, int j1, int cls) {
    const Eigen::Vector3d a = vertex(i0, j0), b = vertex(i1, j0), c = vertex(i1, j1),
                          d = vertex(i0, j1);
    for (const Eigen::Vector3d& p : {a, b, c, a, c, d}) by_class[cls].push_back(p);
    triangles += 2;
  }
  // Whether the vertex block [i0, i1] x [j0, j1] is one flat surface of one colour.
  bool flat(int i0, int j0, int i1, int j1, int* cls) const {
    *cls = colour_class(i0, j0);
    const double h00 = vertex(i0, j0).z(), h10 = vertex(i1, j0).z(), h01 = vertex(i0, j1).z(),
                 h11 = vertex(i1, j1).z();
    for (int i = i0; i <= i1; ++i)
      for (int j = j0; j <= j1; ++j) {
        if (!known(i, j) || colour_class(i, j) != *cls) return false;
        const double u = double(i - i0) / (i1 - i0), v = double(j - j0) / (j1 - j0);
        const double bilinear =
            (1 - u) * (1 - v) * h00 + u * (1 - v) * h10 + (1 - u) * v * h01 + u * v * h11;
        if (std::abs(vertex(i, j).z() - bilinear) > kFlatTolerance) return false;
      }
    return true;
  }
  void block(int i0, int j0, int size) {
    const int i1 = std::min(i0 + size, view.nx - 1), j1 = std::min(j0 + size, view.ny - 1);
    if (i1 <= i0 || j1 <= j0) return;
    int cls = 0;
    if (size == 1) {
      if (!known(i0, j0) || !known(i1, j0) || !known(i0, j1) || !known(i1, j1)) return;
      cls = std::min(
          {colour_class(i0, j0), colour_class(i1, j0), colour_class(i0, j1), colour_class(i1, j1)});
      quad(i0, j0, i1, j1, cls);
      return;
    }
    if (flat(i0, j0, i1, j1, &cls)) {
      quad(i0, j0, i1, j1, cls);
      return;
    }
    const int half = size / 2;
    for (int di : {0, half})
      for (int dj : {0, half}) block(i0 + di, j0 + dj, half);
  }
};

void publish_relief(Publisher& pub, const Clock& clock, const report::TerrainView& view,
                    double foot_radius, TerrainTopicStats* stats) {
  if (view.radii.empty() || view.nx < 2 || view.ny < 2) return;
  size_t layer = 0;
  for (size_t r = 1; r < view.radii.size(); ++r)
    if (std::abs(view.radii[r] - foot_radius) < std::abs(view.radii[layer] - foot_radius))
      layer = r;
  constexpr int kTileCells = 64;  // a power of two: the blocks halve down to single cells
  const json colours[4] = {color(0.9, 0.1, 0.1), color(1.0, 0.75, 0.0), color(0.1, 0.75, 0.3),
                           color(0.55, 0.55, 0.6)};
  std::vector<json> entities;
  for (int ti = 0; ti < view.nx - 1; ti += kTileCells)
    for (int tj = 0; tj < view.ny - 1; tj += kTileCells) {
      ReliefMesh mesh{view, layer};
      mesh.block(ti, tj, kTileCells);
      if (mesh.triangles == 0) continue;
      stats->relief_triangles += mesh.triangles;
      json e = entity(clock, 0, "relief_" + std::to_string(ti) + "_" + std::to_string(tj));
      for (int c = 0; c < 4; ++c) {
        if (mesh.by_class[c].empty()) continue;
        json points = json::array();
        for (const auto& p : mesh.by_class[c]) points.push_back(vec3(p));
        e["triangles"].push_back({{"pose", pose(Eigen::Vector3d::Zero())},
                                  {"points", std::move(points)},
                                  {"color", colours[c]},
                                  {"colors", json::array()},
                                  {"indices", json::array()}});
      }
      entities.push_back(std::move(e));
    }
  stats->relief_cells = static_cast<size_t>(view.nx - 1) * (view.ny - 1);
  char radius[32];
  std::snprintf(radius, sizeof radius, "%.3f", view.radii[layer]);
  const uint16_t ch = pub.channel(
      "/terrain/relief", "foxglove.SceneUpdate",
      {{"coloured_by", std::string("margin_r") + radius},
       {"colours", "red: margin < 0 (unsafe), amber: < 2 cm, green: safe, grey: unknown"},
       {"flat_tolerance_m", std::to_string(ReliefMesh::kFlatTolerance)}});
  publish_entities(pub, ch, clock.ns(0), entities, kMessageBudget);
}

}  // namespace

TerrainTopicStats publish_terrain(Publisher& pub, const Clock& clock,
                                  const report::TerrainView& view, double foot_radius,
                                  size_t max_voxels) {
  TerrainTopicStats stats;
  publish_grids(pub, clock, view, &stats);
  publish_relief(pub, clock, view, foot_radius, &stats);
  if (view.octree) publish_voxels(pub, clock, *view.octree, max_voxels, &stats);
  return stats;
}

std::vector<SensorInput> sensor_inputs(const nlohmann::json& info) {
  std::vector<SensorInput> out;
  if (!info.is_object() || !info.contains("inputs") || !info["inputs"].is_array()) return out;
  static const std::regex kStamp(R"(@(\d+)\.(\d{9})$)");
  for (const json& in : info["inputs"]) {
    if (!in.is_object() || !in.contains("path") || !in["path"].is_string()) continue;
    SensorInput s;
    s.path = in["path"].get<std::string>();
    std::smatch m;
    if (std::regex_search(s.path, m, kStamp)) {
      s.has_stamp = true;
      s.stamp_ns = std::stoull(m[1].str()) * 1000000000ull + std::stoull(m[2].str());
    }
    if (in.contains("origin") && in["origin"].is_array() && in["origin"].size() == 3) {
      s.has_origin = true;
      for (int a = 0; a < 3; ++a) s.origin[a] = in["origin"][a].get<double>();
    }
    if (in.contains("pose") && in["pose"].is_object())
      s.pose_source = in["pose"].value("source", std::string());
    if (in.contains("up") && in["up"].is_object())
      s.up_from = in["up"].value("from", std::string());
    const json* q =
        in.contains("pose") && in["pose"].is_object() && in["pose"].contains("orientation_xyzw")
            ? &in["pose"]["orientation_xyzw"]
            : nullptr;
    if (q && q->is_array() && q->size() == 4) {
      s.has_orientation = true;
      s.orientation = Eigen::Quaterniond((*q)[3].get<double>(), (*q)[0].get<double>(),
                                         (*q)[1].get<double>(), (*q)[2].get<double>())
                          .normalized();
    }
    out.push_back(s);
  }
  std::stable_sort(out.begin(), out.end(), [](const SensorInput& a, const SensorInput& b) {
    return a.has_stamp && b.has_stamp && a.stamp_ns < b.stamp_ns;
  });
  return out;
}

namespace {

// How the map placed a recorded input file: its pose (a --sensor-pose or a poses line, recorded
// with the optical frame already composed), its --origin, or its VIEWPOINT; and its up mode.
terrain::CloudPoseOptions recorded_placement(const SensorInput& in) {
  terrain::CloudPoseOptions o;
  if ((in.pose_source == "poses" || in.pose_source == "sensor-pose") && in.has_origin &&
      in.has_orientation)
    o.sensor_pose = perception::SensorPose{in.origin, in.orientation};
  else if (in.pose_source == "origin" && in.has_origin)
    o.origin = in.origin;
  if (in.up_from.rfind("levelled", 0) == 0)
    o.up = terrain::UpMode::kAuto;
  else if (in.up_from.find("checked") == std::string::npos && !in.up_from.empty())
    o.up = terrain::UpMode::kZ;
  return o;
}

// The clouds, each as `terrastride map` read it; `problems` gets the recorded inputs that no
// longer read.
std::vector<perception::PointCloud> read_clouds(const CloudInputs& in,
                                                std::vector<std::string>* problems) {
  std::vector<perception::PointCloud> out;
  if (!in.files.empty()) {
    try {
      out = terrain::read_map_clouds(in.files, std::nullopt).clouds;
    } catch (const std::exception& e) {
      throw CommandError(std::string("--terrain: ") + e.what());
    }
  }
  std::map<std::string, std::vector<std::string>> bag_topics;  // bag -> topics
  static const std::regex kBagInput(R"(^(.*):([^:@]+)@\d+\.\d+$)");
  for (const SensorInput& s : in.recorded) {
    std::smatch m;
    std::error_code ec;
    try {
      if (std::regex_match(s.path, m, kBagInput)) {
        auto& topics = bag_topics[m[1].str()];
        if (std::find(topics.begin(), topics.end(), m[2].str()) == topics.end())
          topics.push_back(m[2].str());
      } else if (std::filesystem::is_regular_file(s.path, ec)) {
        for (auto& c : terrain::read_map_clouds({s.path}, recorded_placement(s)).clouds)
          out.push_back(std::move(c));
      }
    } catch (const std::exception& e) {
      problems->push_back(e.what());
    }
  }
  for (const auto& [bag, topics] : bag_topics) {
    if (in.bag_frame.empty()) continue;
    perception::BagCloudOptions bo;
    bo.topics = topics;
    bo.fixed_frame = in.bag_frame;
    try {
      perception::read_bag_clouds(bag, bo,
                                  [&](perception::PointCloud&& c, const perception::BagCloudInfo&) {
                                    out.push_back(std::move(c));
                                  });
    } catch (const std::exception& e) {
      problems->push_back("--bag-frame " + in.bag_frame + ": " + e.what());
    }
  }
  return out;
}

}  // namespace

void publish_clouds(Publisher& pub, const Clock& clock, const CloudInputs& clouds,
                    const std::vector<SensorInput>& sensors, size_t max_points,
                    TerrainTopicStats* stats) {
  // The sensor poses (origins, and orientations where terrain.json has them) as frames
  // sensor_<i>, and a
  // frame `sensor` that moves to each cloud's origin at its stamp.
  json frames = json::array();
  std::vector<std::pair<uint64_t, Eigen::Vector3d>> moving;
  for (size_t i = 0; i < sensors.size(); ++i) {
    if (!sensors[i].has_origin) continue;
    frames.push_back(transform(clock, 0, kMapFrame, "sensor_" + std::to_string(i),
                               sensors[i].origin, sensors[i].orientation));
    if (sensors[i].has_stamp) moving.emplace_back(sensors[i].stamp_ns, sensors[i].origin);
  }
  if (!frames.empty()) {
    const uint16_t tf = pub.channel("/tf", "foxglove.FrameTransforms");
    pub.publish(tf, clock.ns(0), {{"transforms", frames}});
    // The recording's stamps relative to its first: t = 0 is that stamp, or --start-time.
    uint64_t first = UINT64_MAX;
    for (const auto& m : moving) first = std::min(first, m.first);
    for (const auto& [ns, origin] : moving) {
      const double t = 1e-9 * static_cast<double>(ns - first);
      pub.publish(tf, clock.ns(t),
                  {{"transforms", json::array({transform(clock, t, kMapFrame, "sensor", origin,
                                                         Eigen::Quaterniond::Identity())})}});
    }
    stats->sensor_frames = frames.size();
  }
  std::vector<std::string> problems;
  perception::PointCloud merged;
  for (auto& c : read_clouds(clouds, &problems))
    merged.points.insert(merged.points.end(), c.points.begin(), c.points.end());
  for (const auto& p : problems)
    pub.publish(pub.channel("/log", "foxglove.Log"), clock.ns(0),
                log_message(clock, 0, 3, "export", "the map's cloud is not drawn: " + p));
  stats->points_in = merged.points.size();
  if (merged.points.empty()) return;
  // The map's own cleaning, then a voxel grid (PCL) coarse enough for the budget.
  perception::PointCloud kept =
      perception::filter_cloud(merged, perception::default_map_cleaning());
  double leaf = 0.0;
  while (kept.points.size() > max_points) {
    leaf = leaf == 0.0 ? 0.01 : 1.5 * leaf;
    perception::CloudFilterOptions grid;
    grid.voxel_size = static_cast<float>(leaf);
    kept = perception::filter_cloud(kept, grid);
  }
  std::string data(kept.points.size() * 12, '\0');
  for (size_t i = 0; i < kept.points.size(); ++i)
    std::memcpy(data.data() + 12 * i, kept.points[i].data(), 12);
  stats->points = kept.points.size();
  json fields = json::array();
  for (int a = 0; a < 3; ++a)
    fields.push_back({{"name", std::string(1, "xyz"[a])}, {"offset", 4 * a}, {"type", 7}});
  const uint16_t ch = pub.channel("/terrain/points", "foxglove.PointCloud",
                                  {{"points_read", std::to_string(stats->points_in)},
                                   {"points", std::to_string(stats->points)},
                                   {"voxel_leaf_m", std::to_string(leaf)},
                                   {"budget", std::to_string(max_points)}});
  pub.publish(ch, clock.ns(0),
              {{"timestamp", clock.stamp(0)},
               {"frame_id", kMapFrame},
               {"pose", pose(Eigen::Vector3d::Zero())},
               {"point_stride", 12},
               {"fields", fields},
               {"data", base64(data)}});
}

}  // namespace terrastride::service::foxglove
