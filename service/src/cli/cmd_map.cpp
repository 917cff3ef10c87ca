// `terrastride map`: clouds -> cleaned clouds -> OctoMap + height grid -> smoothed field and
// foothold-safety layers, written atomically as DIR/terrain.json, DIR/octomap.bt, DIR/layers/*.npy.
// The work is terrain::build_terrain_map and terrain::write_terrain_dir (map_build.hpp); this file
// reads the flags, names them in errors and prints the summary.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

#include "pasteable.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/bag_clouds.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/perception/sensor_pose.hpp"
#include "terrastride/perception/tf_buffer.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride::service {
namespace {

using nlohmann::json;

struct MapOptions {
  std::vector<std::string> clouds;
  std::string origin;
  // Sensor poses and the up direction of cloud files (terrain::CloudPoseOptions).
  std::string viewpoint;  // "", "pose" or "origin"
  std::string sensor_pose;
  std::string poses;
  std::string sensor_frame = "body";
  std::string up = "check";
  double max_tilt = terrain::CloudPoseOptions{}.max_tilt_deg;
  double resolution = terrain::HeightGridOptions{}.resolution;
  std::vector<double> foot_radii = terrain::MapBuildOptions{}.foot_radii;
  double octomap_resolution = terrain::default_map_octomap().resolution;
  // Rays longer than this are cut there (OctoMap's maxrange: free space carved up to it, the far
  // hit not marked). 0 = off, the default (terrain::default_map_octomap).
  double octomap_max_range = 0.0;
  double voxel = perception::default_map_cleaning().voxel_size;
  int outlier_k = perception::default_map_cleaning().outlier_neighbours;
  double outlier_stddev = perception::default_map_cleaning().outlier_stddev;
  // Outlier removal judges cells of this size by their centroids (0 = every point, as PCL's
  // StatisticalOutlierRemoval does on its own): per-point removal costs ~2.5 us a point.
  double outlier_voxel = perception::default_map_cleaning().outlier_voxel;
  double max_step = terrain::SafetyOptions{}.max_step;
  double max_slope = terrain::SafetyOptions{}.max_slope;
  std::string out;
  bool json = false;
  bool resolution_given = false;  // an OctoMap's grid is at its voxel size unless --resolution
  // Bags (.mcap, .db3, .bag).
  std::vector<std::string> topics;
  std::string frame;
  std::optional<double> start, end;
  int every = 1;
  // Points kept per grid cell over all of a recording's clouds (terrain::BagStreamOptions): memory
  // follows the map, not the file; 0 = keep every point.
  size_t max_cell_points = 256;
  bool list = false;
};

// Stage progress on stderr, only for a terminal and only for inputs large enough to wait for.
class MapProgress {
 public:
  explicit MapProgress(bool enabled) : enabled_(enabled) {}
  void stage(const std::string& what) {
    if (!enabled_) return;
    std::cerr << "\r\033[K[map] " << what << std::flush;
  }
  void done() {
    if (enabled_) std::cerr << "\r\033[K" << std::flush;
  }

 private:
  bool enabled_;
};

std::string fmt(double v, int precision = 3) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << v;
  return os.str();
}

bool pose_flags_given(const MapOptions& o) {
  return !o.viewpoint.empty() || !o.sensor_pose.empty() || !o.poses.empty() ||
         o.sensor_frame != "body" || o.up != "check" ||
         o.max_tilt != terrain::CloudPoseOptions{}.max_tilt_deg;
}

// The pose and up flags of cloud files (the poses file is read here, before any cloud).
terrain::CloudPoseOptions pose_options(const MapOptions& o) {
  terrain::CloudPoseOptions p;
  if (!o.origin.empty()) p.origin = Eigen::Vector3d(parse_numbers(o.origin, 3, "--origin"));
  if (o.viewpoint == "pose") {
    p.viewpoint = perception::ViewpointUse::kPose;
  } else if (o.viewpoint == "origin") {
    p.viewpoint = perception::ViewpointUse::kPosition;
  } else if (!o.viewpoint.empty()) {
    throw CommandError("--viewpoint: '" + o.viewpoint + "' is not 'pose' or 'origin'");
  }
  if (o.sensor_frame == "optical") {
    p.sensor_frame = perception::SensorFrame::kOptical;
  } else if (o.sensor_frame != "body") {
    throw CommandError("--sensor-frame: '" + o.sensor_frame + "' is not 'body' or 'optical'");
  }
  if (o.up == "auto") {
    p.up = terrain::UpMode::kAuto;
  } else if (o.up == "z") {
    p.up = terrain::UpMode::kZ;
  } else if (o.up != "check") {
    throw CommandError("--up: '" + o.up + "' is not 'check', 'auto' or 'z'");
  }
  if (!std::isfinite(o.max_tilt) || o.max_tilt < 0 || o.max_tilt > 90)
    throw CommandError("--max-tilt: must be in [0, 90] degrees");
  p.max_tilt_deg = o.max_tilt;
  try {
    if (!o.sensor_pose.empty())
      p.sensor_pose = perception::parse_sensor_pose(o.sensor_pose, "--sensor-pose");
  } catch (const perception::InputError& e) {
    throw CommandError(e.what());
  }
  try {
    if (!o.poses.empty()) {
      p.poses = perception::read_poses_file(o.poses);
      p.poses_file = o.poses;
    }
  } catch (const perception::InputError& e) {
    throw CommandError("--poses " + std::string(e.what()));
  }
  if (p.origin && (p.sensor_pose || !p.poses.empty()))
    throw CommandError(
        "--origin: world-frame points with a sensor position; it cannot go with "
        "--sensor-pose or --poses, which give the pose of the points' frame");
  if (p.sensor_pose && !p.poses.empty())
    throw CommandError("--sensor-pose and --poses both give the clouds' poses: use one");
  if (p.origin && p.sensor_frame == perception::SensorFrame::kOptical)
    throw CommandError(
        "--sensor-frame optical: the points are in a camera's optical frame, but "
        "--origin takes them as world-frame; give --sensor-pose instead");
  return p;
}

// Checks every flag before anything is read; returns the clouds' pose options.
terrain::CloudPoseOptions check_flags(const MapOptions& o) {
  if (o.clouds.empty()) throw CommandError("no input clouds given");
  if (!std::isfinite(o.resolution) || o.resolution < 0.002 || o.resolution > 1.0)
    throw CommandError("--resolution: " + std::to_string(o.resolution) +
                       " m is outside the accepted range [0.002, 1] m");
  const double octo_res = o.octomap_resolution;
  if (!std::isfinite(octo_res) || octo_res < 0.005 || octo_res > 1.0)
    throw CommandError("--octomap-resolution: must be in [0.005, 1] m");
  if (!std::isfinite(o.octomap_max_range) || o.octomap_max_range < 0)
    throw CommandError("--octomap-max-range: " + std::to_string(o.octomap_max_range) +
                       " m is not a finite number >= 0 (0 = no limit)");
  if (o.foot_radii.empty()) throw CommandError("--foot-radius: at least one radius is needed");
  for (double r : o.foot_radii)
    if (!std::isfinite(r) || r < 0 || r > 0.5)
      throw CommandError("--foot-radius: " + std::to_string(r) + " m is outside [0, 0.5] m");
  if (!(o.voxel >= 0) || !std::isfinite(o.voxel))
    throw CommandError("--voxel: must be >= 0 (0 = off)");
  if (o.outlier_k < 0) throw CommandError("--outlier-k: must be >= 0 (0 = off)");
  if (!(o.outlier_voxel >= 0) || !std::isfinite(o.outlier_voxel))
    throw CommandError("--outlier-voxel: must be >= 0 (0 = judge every point)");
  if (!(o.max_step > 0) || !(o.max_slope > 0))
    throw CommandError("--max-step/--max-slope: must be positive");
  terrain::CloudPoseOptions poses = pose_options(o);
  if (o.out.empty()) throw CommandError("--out: an output directory is required");
  {
    const std::filesystem::path parent =
        std::filesystem::absolute(std::filesystem::path(o.out)).parent_path();
    if (!std::filesystem::is_directory(parent))
      throw CommandError("--out: parent directory '" + parent.string() + "' does not exist");
  }
  // Before reading and fusing the clouds (seconds to minutes): an existing folder that is not an
  // earlier output (e.g. the folder of the scans themselves) or an unwritable one fails now.
  try {
    perception::check_output_dir(o.out, terrain::map_output_kind());
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }
  return poses;
}

// The flags as the map build's options (terrain::MapBuildOptions' defaults are the flags').
terrain::MapBuildOptions map_build_options(const MapOptions& o) {
  terrain::MapBuildOptions options;
  options.cleaning->voxel_size = static_cast<float>(o.voxel);
  options.cleaning->outlier_neighbours = o.outlier_k;
  options.cleaning->outlier_stddev = o.outlier_stddev;
  options.cleaning->outlier_voxel = static_cast<float>(o.outlier_voxel);
  options.grid.resolution = o.resolution;
  options.foot_radii = o.foot_radii;
  options.safety.max_step = o.max_step;
  options.safety.max_slope = o.max_slope;
  options.octomap->resolution = o.octomap_resolution;
  options.octomap->max_range = o.octomap_max_range > 0 ? o.octomap_max_range : -1.0;
  return options;
}

void print_summary(const MapOptions& o, const terrain::MapBuild& build, const json& terrain,
                   const json& summary) {
  const auto& g = build.map->grid();
  const json& timings = terrain["timings"];
  const json& statistics = terrain["statistics"];
  std::cout << "terrain map written to " << o.out << "\n"
            << "  points: " << statistics["points_in"].get<size_t>() << " in, "
            << statistics["non_finite"].get<size_t>() << " non-finite, " << build.points_kept
            << " kept after cleaning\n"
            << "  grid: " << g.geometry.nx << " x " << g.geometry.ny << " cells of "
            << g.geometry.resolution << " m, " << g.observed_cells << " observed ("
            << g.interpolated_cells << " of them interpolated), " << g.filled_cells
            << " filled, sensor noise "
            << (g.noise.estimated ? fmt(g.noise.sigma * 1000, 1) + " mm" : "not estimated")
            << ", smoothed over " << fmt(g.smoothing_length * 1000, 1) << " mm\n";
  // The safe fraction as terrain.json and the report define it: safe cells of observed cells.
  for (const auto& s : summary["safe"])
    std::cout << "  safe for foot radius " << s["radius"].get<double>()
              << " m: " << fmt(100.0 * s["safe_fraction"].get<double>(), 1)
              << " % of observed cells\n";
  if (g.overhang_cells > 0)
    std::cout << "  overhangs (overhead clearance layer): " << g.overhang_cells << " cells, "
              << g.overhang_unobserved_cells
              << " of them over unobserved ground (not walkable, not counted above)\n";
  if (summary["unreachable_cells"].get<size_t>() > 0)
    std::cout << "  unreachable levels: " << summary["unreachable_cells"].get<size_t>()
              << " observed cells on " << summary["unreachable_levels"].get<size_t>()
              << " levels no step of at most " << build.map->safety_options().max_climb
              << " m joins to the floor's (not safe, not counted above)\n";
  if (summary.contains("notes"))
    for (const auto& note : summary["notes"]) std::cout << "  note: " << note.get<std::string>() << "\n";
  // A map whose observed cells are all unsafe is most often a cloud placed wrong (z taken as up
  // on a tilted or upside-down cloud): it is written, but says so.
  bool any_safe = false;
  for (const auto& s : summary["safe"]) any_safe = any_safe || s["safe_fraction"].get<double>() > 0;
  if (g.observed_cells > 0 && !any_safe)
    std::cout << "  warning: no observed cell is safe for any foot radius, so no robot can stand "
                 "on this map; if the ground is not level in it, the cloud's orientation is "
                 "wrong: give the sensor's pose (--sensor-pose, --poses, --viewpoint) rather than "
                 "--up z\n";
  std::cout << "  time: read " << fmt(timings["read_s"]) << " s, clean " << fmt(timings["filter_s"])
            << " s, grid " << fmt(timings["grid_s"]) << " s, safety " << fmt(timings["safety_s"])
            << " s, OctoMap " << fmt(timings["octomap_s"]) << " s, write "
            << fmt(timings["write_s"]) << " s, total " << fmt(timings["total_s"]) << " s\n";
}

// The first-hour step after a map: where on it the robot can stand and go (to paste as printed).
void print_next_step(const MapOptions& o) {
  std::cout << "next: " << pasteable_program() << " regions --terrain " << shell_word(o.out)
            << "\n";
}

// One line per cloud file: where its pose came from and how its up direction was found.
void print_placements(const terrain::MapSources& sources) {
  for (const auto& f : sources.files) {
    if (!f.placement) continue;
    const terrain::CloudPlacement& pl = *f.placement;
    std::cout << "  " << f.path << ": ";
    if (pl.source == "none") {
      std::cout << "no sensor pose";
    } else {
      const Eigen::Vector3d& t = pl.pose.position;
      std::cout << "pose from " << (pl.source == "poses" ? "the poses file" : pl.source)
                << (pl.optical ? " (optical frame)" : "") << ", sensor at (" << fmt(t.x(), 2)
                << ", " << fmt(t.y(), 2) << ", " << fmt(t.z(), 2) << ")";
    }
    if (pl.rotation_known && !pl.plane) {
      std::cout << "\n";
      continue;
    }
    if (!pl.plane) {
      std::cout << "; z taken as up (--up z)\n";
      continue;
    }
    const perception::SupportPlane& p = *pl.plane;
    if (!p.found) {
      std::cout << "; up not checked: " << p.problem << "\n";
      continue;
    }
    std::cout << (pl.levelled ? "; levelled (--up auto): its " : "; up checked: ")
              << "dominant plane (" << fmt(100 * p.inlier_share, 0) << " % of the points) "
              << (pl.levelled ? "was " : "is ") << "tilted " << fmt(p.tilt_deg, 1)
              << " deg, the sensor " << fmt(p.sensor_height, 2) << " m "
              << (pl.levelled       ? "from"
                  : p.tilt_deg > 90 ? "below"
                                    : "above")
              << " it" << (pl.position_known ? "" : " (sensor taken at the frame's origin)")
              << "\n";
  }
}

// `map FILE.bt|FILE.ot`: the OctoMap's support surfaces (terrain::read_map_octomap) and the tree
// itself as the map's octomap.bt.
void run_map_octomap(const MapOptions& o) {
  if (o.clouds.size() != 1)
    throw CommandError("an OctoMap (" + o.clouds.front() +
                       ") is a whole map: give it alone, not with other inputs");
  if (!o.origin.empty())
    throw CommandError("--origin: an OctoMap keeps no rays; the option applies to point clouds");
  if (pose_flags_given(o))
    throw CommandError(
        "--viewpoint, --sensor-pose, --poses, --sensor-frame, --up and --max-tilt "
        "apply to cloud files, not to an OctoMap");
  terrain::OctreeMapInput input;
  try {
    input = terrain::read_map_octomap(o.clouds.front());
  } catch (const perception::InputError& e) {
    throw CommandError(e.what());
  }
  terrain::MapBuildOptions options = map_build_options(o);
  if (!o.resolution_given) options.grid.resolution = 0;  // the tree's voxel size
  terrain::MapBuild build;
  try {
    build = terrain::build_terrain_map_from_octree(input, options);
  } catch (const terrain::MapBuildError& e) {
    if (e.stage() == terrain::MapStage::kGrid)
      throw CommandError("--resolution/--foot-radius: " + std::string(e.what()));
    throw CommandError(e.what());
  }
  json meta;
  try {
    meta = terrain::write_terrain_dir(build, input.sources, o.out);
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }
  json summary = terrain::map_summary(build, meta, o.out);
  summary["octomap_input"] = {{"occupied_voxels", input.stats.occupied_voxels},
                              {"columns", input.stats.columns},
                              {"runs", input.stats.runs},
                              {"seen_beneath", input.stats.seen_beneath},
                              {"overhangs", input.stats.overhangs},
                              {"overhang_only_columns", input.stats.overhang_only_columns}};
  if (o.json) {
    std::cout << summary.dump() << "\n";
    return;
  }
  std::cout << "OctoMap " << o.clouds.front() << ": " << input.stats.occupied_voxels
            << " occupied voxels in " << input.stats.columns << " columns, "
            << input.stats.runs << " vertical runs, " << input.stats.overhangs
            << " of them overhangs with free space beneath (not support; "
            << input.stats.overhang_only_columns << " columns hold nothing else)\n";
  print_summary(o, build, meta, summary);
  print_next_step(o);
}

std::string stamp_text(int64_t ns) { return perception::format_stamp(ns); }

// `map RUN.mcap --list`: what the bag holds, to choose --topic and --frame.
void list_bags(const MapOptions& o) {
  json all = json::array();
  for (const auto& path : o.clouds) {
    perception::BagListing l;
    try {
      l = perception::list_bag(path);
    } catch (const perception::InputError& e) {
      throw CommandError(e.what());
    }
    json topics = json::array();
    for (const auto& t : l.topics)
      topics.push_back({{"topic", t.name},
                        {"type", t.type},
                        {"encoding", t.encoding},
                        {"messages", t.messages},
                        {"first_log_time", t.messages ? stamp_text(t.first_log_ns) : ""},
                        {"last_log_time", t.messages ? stamp_text(t.last_log_ns) : ""},
                        {"frames", std::vector<std::string>(t.frames.begin(), t.frames.end())}});
    json entry = {{"path", path},     {"format", l.format}, {"topics", topics},
                  {"tf", l.tf_links}, {"frames", l.frames}, {"damage", l.damage.problems}};
    all.push_back(entry);
    if (o.json) continue;
    std::cout << path << " (" << l.format << ")\n";
    for (const auto& t : l.topics) {
      std::cout << "  " << t.name << "  " << t.type << "  " << t.messages << " messages";
      if (t.messages)
        std::cout << ", " << fmt(static_cast<double>(t.last_log_ns - t.first_log_ns) * 1e-9, 3)
                  << " s from " << stamp_text(t.first_log_ns);
      if (!t.frames.empty()) {
        std::cout << ", frames";
        for (const auto& f : t.frames) std::cout << " " << f;
      }
      std::cout << "\n";
    }
    std::cout << "  tf:" << (l.tf_links.empty() ? " none" : "") << "\n";
    for (const auto& link : l.tf_links) std::cout << "    " << link << "\n";
    for (const auto& d : l.damage.problems) std::cout << "  damaged: " << d << "\n";
  }
  if (o.json) std::cout << (all.size() == 1 ? all[0] : all).dump() << "\n";
}

// `map RUN.mcap --topic T --frame F`: the clouds of a recording, placed by its tf.
terrain::MapInput read_bags(const MapOptions& o, MapProgress& progress, json* bag_json,
                            double* clean_s) {
  if (!o.origin.empty())
    throw CommandError("--origin: a bag's clouds take their origins from its tf (--frame)");
  if (pose_flags_given(o))
    throw CommandError(
        "--viewpoint, --sensor-pose, --poses, --sensor-frame, --up and --max-tilt "
        "apply to cloud files; a bag's clouds are placed by its tf (--frame)");
  if (o.topics.empty())
    throw CommandError("--topic: which PointCloud2 topic(s) to map? (`terrastride map " +
                       o.clouds.front() + " --list` shows them)");
  if (o.frame.empty())
    throw CommandError("--frame: the fixed frame to map in (e.g. odom or map; `--list` shows the "
                       "tf frames)");
  if (o.every < 1) throw CommandError("--every: must be >= 1");
  perception::BagCloudOptions options;
  options.topics = o.topics;
  options.fixed_frame = o.frame;
  options.start = o.start;
  options.end = o.end;
  options.every = o.every;
  // Each cloud is cleaned as it is read and thinned per grid cell, so memory follows the map.
  terrain::BagStreamOptions stream;
  stream.cleaning = map_build_options(o).cleaning;
  stream.cell_size = o.resolution;
  stream.max_cell_points = o.max_cell_points;
  terrain::StreamedBagInput streamed;
  try {
    streamed = terrain::stream_map_bags(o.clouds, options, stream, [&](size_t b, size_t clouds) {
      if (clouds % 50 == 0)
        progress.stage("reading and cleaning " + o.clouds[b] + ": " + std::to_string(clouds) +
                       " clouds");
    });
  } catch (const perception::InputError& e) {
    throw CommandError(e.what());
  }
  *clean_s = streamed.clean_s;
  terrain::BagMapInput& in = streamed.bags;
  *bag_json = json::array();
  for (size_t b = 0; b < in.stats.size(); ++b) {
    const auto& st = in.stats[b];
    json topics = json::object();
    for (const auto& [name, t] : st.topics)
      topics[name] = {{"messages", t.messages},     {"used", t.used},
                      {"outside_window", t.outside_window}, {"skipped_every", t.skipped_every},
                      {"points_in", t.points_in},   {"non_finite", t.non_finite}};
    bag_json->push_back({{"path", o.clouds[b]},
                         {"format", st.format},
                         {"frame", o.frame},
                         {"topics", topics},
                         {"transforms", st.transforms},
                         {"static_transforms", st.static_transforms},
                         {"skipped", st.damage.problems},
                         {"skipped_bytes", st.damage.skipped_bytes}});
  }
  // Over all bags: what the per-cell cap dropped (0 when nothing was re-observed that often).
  for (json& b : *bag_json)
    b["stream"] = {{"points_cleaned", streamed.points_cleaned},
                   {"points_over_cell_cap", streamed.points_over_cap},
                   {"max_cell_points", o.max_cell_points},
                   {"cells", streamed.cells}};
  return std::move(in.input);
}

void print_bag_summary(const json& bags) {
  for (const auto& b : bags) {
    std::cout << b["path"].get<std::string>() << " (" << b["format"].get<std::string>()
              << "), in frame " << b["frame"].get<std::string>() << ":\n";
    for (const auto& [name, t] : b["topics"].items())
      std::cout << "  " << name << ": " << t["used"].get<size_t>() << " of "
                << t["messages"].get<size_t>() << " clouds used (" << t["outside_window"].get<size_t>()
                << " outside the time window, " << t["skipped_every"].get<size_t>()
                << " skipped by --every), " << t["points_in"].get<size_t>() << " points, "
                << t["non_finite"].get<size_t>() << " non-finite dropped\n";
    for (const auto& d : b["skipped"]) std::cout << "  skipped: " << d.get<std::string>() << "\n";
  }
}

void run_map(MapOptions o) {
  // `map --poses FILE` alone maps the clouds the poses file names.
  if (o.clouds.empty() && !o.poses.empty() && !o.list) {
    try {
      for (const auto& line : perception::read_poses_file(o.poses))
        o.clouds.push_back(line.resolved);
    } catch (const perception::InputError& e) {
      throw CommandError("--poses " + std::string(e.what()));
    }
  }
  const bool any_bag = std::any_of(o.clouds.begin(), o.clouds.end(), perception::is_bag_file);
  if (any_bag && !std::all_of(o.clouds.begin(), o.clouds.end(), perception::is_bag_file))
    throw CommandError("bags (.mcap, .db3, .bag) cannot be mixed with cloud files or OctoMaps");
  if (!any_bag && (o.list || !o.topics.empty() || !o.frame.empty() || o.start || o.end ||
                   o.every != 1 || o.max_cell_points != MapOptions{}.max_cell_points))
    throw CommandError("--list, --topic, --frame, --start, --end, --every and --max-cell-points "
                       "apply to bags (.mcap, .db3, .bag, a rosbag2 folder)");
  if (o.list) {
    if (o.clouds.empty()) throw CommandError("no input bag given");
    list_bags(o);
    return;
  }
  if (!o.clouds.empty() && std::any_of(o.clouds.begin(), o.clouds.end(), perception::is_octomap_file)) {
    check_flags(o);
    run_map_octomap(o);
    return;
  }
  const terrain::CloudPoseOptions poses = check_flags(o);
  size_t file_bytes = 0;
  for (const auto& c : o.clouds) {
    std::error_code ec;
    const auto s = std::filesystem::file_size(c, ec);
    if (!ec) file_bytes += s;
  }
  MapProgress progress(isatty(STDERR_FILENO) && file_bytes > 8u * 1024 * 1024);

  terrain::MapInput input;
  json bags;
  double bag_clean_s = 0.0;
  if (any_bag) {
    input = read_bags(o, progress, &bags, &bag_clean_s);
  } else {
    try {
      input = terrain::read_map_clouds(o.clouds, poses, [&](size_t k) {
        progress.stage("reading " + o.clouds[k] + " (" + std::to_string(k + 1) + "/" +
                       std::to_string(o.clouds.size()) + ")");
      });
    } catch (const perception::InputError& e) {
      throw CommandError(e.what());
    }
  }

  terrain::MapBuildOptions options = map_build_options(o);
  if (any_bag) options.cleaning.reset();  // cleaned as they were read
  const size_t n_clouds = input.clouds.size();
  options.on_stage = [&](terrain::MapStage stage, const terrain::MapBuild&) {
    if (stage == terrain::MapStage::kClean)
      progress.stage("cleaning " + std::to_string(n_clouds) + " cloud(s) and building the OctoMap");
    else
      progress.stage("height grid, foothold safety and OctoMap");
  };
  terrain::MapBuild build;
  try {
    build = terrain::build_terrain_map(std::move(input.clouds), options);
  } catch (const terrain::MapBuildError& e) {
    if (e.stage() == terrain::MapStage::kGrid)
      throw CommandError("--resolution/--foot-radius: " + std::string(e.what()));
    throw CommandError(e.what());
  }

  if (any_bag) build.timings.clean_s = bag_clean_s;
  progress.stage("writing " + o.out);
  json meta;
  try {
    meta = terrain::write_terrain_dir(build, input.sources, o.out);
  } catch (const perception::InputError& e) {
    throw CommandError("--out: " + std::string(e.what()));
  }
  progress.done();

  json summary = terrain::map_summary(build, meta, o.out);
  if (any_bag) summary["bags"] = bags;
  if (!any_bag) {
    json placements = json::array();
    for (const auto& f : input.sources.files) {
      json entry = {{"path", f.path}};
      if (f.placement) entry.update(terrain::placement_json(*f.placement));
      placements.push_back(entry);
    }
    summary["inputs"] = placements;
  }
  if (o.json) {
    std::cout << summary.dump() << "\n";
    return;
  }
  if (any_bag) print_bag_summary(bags);
  print_summary(o, build, meta, summary);
  if (!any_bag) print_placements(input.sources);
  print_next_step(o);
}

}  // namespace

void add_map_command(CLI::App& app) {
  auto o = std::make_shared<MapOptions>();
  CLI::App* cmd = app.add_subcommand(
      "map",
      "Build a terrain map from point clouds (PCD, PLY, XYZ, NPY), ROS bags (.mcap, .db3, .bag "
      "or a rosbag2 folder with metadata.yaml: --topic, --frame) or an OctoMap (.bt, .ot): "
      "OctoMap, height grid, smoothed field and foothold-safety layers in DIR");
  cmd->add_option("clouds", o->clouds,
                  "Input clouds, bags or an OctoMap (clouds may come from --poses instead)");
  cmd->add_option("--origin", o->origin,
                  "Sensor position X,Y,Z for all clouds, whose points are in the world frame "
                  "(any PCD VIEWPOINT is ignored)");
  cmd->add_option("--viewpoint", o->viewpoint,
                  "How a PCD VIEWPOINT is read: 'pose' (PCL's meaning: the points are in the "
                  "sensor frame, VIEWPOINT is its pose, world = R p + t) or 'origin' (world-frame "
                  "points, VIEWPOINT the sensor position only: files of terrastride before the "
                  "sensor-frame writer). Default: pose, but a VIEWPOINT with a position and no "
                  "rotation in a file without terrastride's marker is refused as ambiguous");
  cmd->add_option("--sensor-pose", o->sensor_pose,
                  "The pose of the clouds' frame in the world, X,Y,Z,QX,QY,QZ,QW (ROS tf order: "
                  "static_transform_publisher's x y z qx qy qz qw; world = R p + t); overrides "
                  "a VIEWPOINT");
  cmd->add_option("--poses", o->poses,
                  "A file of poses, one cloud a line: 'PATH X Y Z QX QY QZ QW' ('#' comments; "
                  "relative paths from the file's folder); without positional clouds, maps the "
                  "clouds it names");
  cmd->add_option("--sensor-frame", o->sensor_frame,
                  "'optical': the points are in a camera's optical frame (REP 103: z forward, x "
                  "right, y down) and the pose given is the camera body's (x forward, z up)")
      ->capture_default_str();
  cmd->add_option("--up", o->up,
                  "For clouds whose orientation nobody gave: 'check' refuses one whose dominant "
                  "plane is more than --max-tilt from level or above the sensor; 'auto' levels "
                  "it by that plane (PCL RANSAC); 'z' takes z as up unchecked")
      ->capture_default_str();
  cmd->add_option("--max-tilt", o->max_tilt,
                  "--up check: the largest tilt of the dominant plane (degrees)")
      ->capture_default_str();
  cmd->add_option("--resolution", o->resolution,
                  "Height grid cell size (m); an OctoMap input's default is its voxel size")
      ->capture_default_str();
  cmd->add_option("--foot-radius", o->foot_radii,
                  "Foot radius for the safety layers (m); repeat or comma-separate for several")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--octomap-resolution", o->octomap_resolution, "OctoMap voxel size (m)")
      ->capture_default_str();
  cmd->add_option("--octomap-max-range", o->octomap_max_range,
                  "Cut OctoMap rays at this range (m): faster on long-range scans, but hits "
                  "beyond it are not marked occupied; 0 = no limit")
      ->capture_default_str();
  cmd->add_option("--voxel", o->voxel, "Voxel-grid downsampling of the input (m); 0 = off")
      ->capture_default_str();
  cmd->add_option("--outlier-k", o->outlier_k, "Statistical outlier removal neighbours (0 = off)")
      ->capture_default_str();
  cmd->add_option("--outlier-stddev", o->outlier_stddev, "Statistical outlier removal threshold")
      ->capture_default_str();
  cmd->add_option("--outlier-voxel", o->outlier_voxel,
                  "Outlier removal judges cells of this size (m) by their centroids and keeps or "
                  "drops their points together; 0 = judge every point (slow on dense clouds)")
      ->capture_default_str();
  cmd->add_option("--max-step", o->max_step, "Largest raw step in a safe foot disk (m)")
      ->capture_default_str();
  cmd->add_option("--max-slope", o->max_slope, "Largest slope (tan) of a safe foothold")
      ->capture_default_str();
  cmd->add_option("--out", o->out, "Output directory (required unless --list)");
  cmd->add_option("--topic", o->topics,
                  "Bags: a sensor_msgs/PointCloud2 topic to map; repeat for several")
      ->delimiter(',');
  cmd->add_option("--frame", o->frame,
                  "Bags: the fixed frame the clouds are placed in (by /tf and /tf_static at each "
                  "cloud's stamp, interpolated), e.g. odom or map");
  cmd->add_option("--start", o->start,
                  "Bags: first log time to use, s from the bag's first message (or since the "
                  "epoch when >= 1e9)");
  cmd->add_option("--end", o->end, "Bags: last log time to use (as --start)");
  cmd->add_option("--every", o->every, "Bags: use every N-th cloud of each topic")
      ->capture_default_str();
  cmd->add_option("--max-cell-points", o->max_cell_points,
                  "Bags: points kept per grid cell over the whole recording (first come; later "
                  "ones dropped and counted), so memory follows the map, not the file; 0 = all")
      ->capture_default_str();
  cmd->add_flag("--list", o->list,
                "Bags: print the topics, types, message counts, cloud frames and tf links, and "
                "map nothing");
  cmd->add_flag("--json", o->json, "Print the summary as one JSON object");
  cmd->callback([o, cmd] {
    o->resolution_given = cmd->count("--resolution") > 0;
    run_map(*o);
  });
}

}  // namespace terrastride::service
