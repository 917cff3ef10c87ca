#include "terrastride/terrain/map_build.hpp"

#include <stdlib.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <exception>
#include <filesystem>
#include <mutex>
#include <sstream>
#include <thread>
#include <unordered_map>

#include "terrastride/perception/cloud_io.hpp"

namespace terrastride::terrain {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Runs body(k) for k in [0, n) on up to one thread per core. Each k must write only its own
// results. When calls fail, the exception of the lowest k is rethrown (the same error as a loop).
template <class Body>
void parallel_for(size_t n, const Body& body) {
  const size_t workers = std::min<size_t>(n, std::max(1u, std::thread::hardware_concurrency()));
  std::vector<std::exception_ptr> errors(n);
  std::atomic<size_t> next{0};
  const auto work = [&] {
    for (size_t k; (k = next.fetch_add(1)) < n;) {
      try {
        body(k);
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> threads;
  for (size_t w = 1; w < workers; ++w) threads.emplace_back(work);
  work();
  for (auto& th : threads) th.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
}

// The OctoMap of a build, on its own thread: the clouds cleaned before first, then each new cloud
// as soon as the cleaning marks it ready (in input order, as perception::build_octomap inserts).
class OctoMapThread {
 public:
  OctoMapThread(const perception::OctoMapOptions& options,
                const std::vector<perception::PointCloud>& before,
                const std::vector<perception::PointCloud>& clouds)
      : ready_(clouds.size(), 0) {
    thread_ = std::thread([this, options, &before, &clouds] { run(options, before, clouds); });
  }
  ~OctoMapThread() { stop(); }

  void mark_cleaned(size_t k) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ready_[k] = 1;
    }
    ready_cv_.notify_all();
  }
  // The build failed or was abandoned: the thread ends after the insertion under way, if any.
  void stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopped_ = true;
    }
    ready_cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  // Joins the thread; rethrows its failure, else hands over the tree.
  std::unique_ptr<octomap::OcTree> finish(double* seconds) {
    if (thread_.joinable()) thread_.join();
    *seconds = seconds_;
    if (error_) std::rethrow_exception(error_);
    return std::move(tree_);
  }

 private:
  void run(const perception::OctoMapOptions& options,
           const std::vector<perception::PointCloud>& before,
           const std::vector<perception::PointCloud>& clouds) {
    auto t0 = Clock::now();  // seconds_ counts the work, not the waits for cleaned clouds
    try {
      auto tree = perception::build_octomap({}, options);  // validates the options
      perception::CloudFilterOptions one_per_voxel;
      one_per_voxel.voxel_size = static_cast<float>(options.resolution);
      const auto insert = [&](const perception::PointCloud& cloud) {
        perception::insert_into_octomap(*tree, perception::filter_cloud(cloud, one_per_voxel),
                                        options.max_range, options.discretize);
      };
      for (const auto& cloud : before) {
        if (stopped()) return;
        insert(cloud);
      }
      for (size_t k = 0; k < clouds.size(); ++k) {
        {
          seconds_ += seconds_since(t0);
          std::unique_lock<std::mutex> lock(mutex_);
          ready_cv_.wait(lock, [&] { return ready_[k] || stopped_; });
          if (stopped_) return;  // the build failed or was abandoned: its error is reported
          t0 = Clock::now();
        }
        insert(clouds[k]);
      }
      tree_ = std::move(tree);
    } catch (const perception::InputError& e) {
      error_ = std::make_exception_ptr(MapBuildError(MapStage::kOctoMap, e.what()));
    } catch (...) {
      error_ = std::current_exception();
    }
    seconds_ += seconds_since(t0);
  }

  bool stopped() {
    std::lock_guard<std::mutex> lock(mutex_);
    return stopped_;
  }

  std::mutex mutex_;
  std::condition_variable ready_cv_;
  std::vector<char> ready_;
  bool stopped_ = false;
  std::unique_ptr<octomap::OcTree> tree_;
  std::exception_ptr error_;
  double seconds_ = 0.0;
  std::thread thread_;  // last: starts after every member it uses exists
};

std::string canonical_path(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path full = fs::absolute(fs::path(path), ec);
  if (ec) return path;
  const fs::path canonical = fs::weakly_canonical(full, ec);
  return (ec ? full.lexically_normal() : canonical).string();
}

std::string fixed(double v, int precision) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << v;
  return os.str();
}

// The pose of a cloud's points (CloudPoseOptions, first that applies): --sensor-pose, its poses
// line, --origin (position only), the file's VIEWPOINT; --sensor-frame optical composes the
// optical frame's rotation.
void resolve_pose(const perception::CloudFileRead& file, const std::string& path,
                  const CloudPoseOptions& o, const perception::PoseLine* line, CloudPlacement& pl) {
  if (o.sensor_pose) {
    pl.source = "sensor-pose";
    pl.pose = *o.sensor_pose;
    pl.position_known = pl.rotation_known = true;
  } else if (line) {
    pl.source = "poses";
    pl.pose = line->pose;
    pl.poses_line = line->line;
    pl.position_known = pl.rotation_known = true;
  } else if (o.origin) {
    pl.source = "origin";
    pl.pose.position = *o.origin;
    pl.position_known = true;
  } else if (const auto sensor = perception::file_sensor(file, path, o.viewpoint)) {
    pl.source = sensor->rotation_known ? "viewpoint" : "viewpoint position";
    pl.pose = sensor->pose;
    pl.position_known = true;
    pl.rotation_known = sensor->rotation_known;
  }
  if (o.sensor_frame == perception::SensorFrame::kOptical) {
    if (pl.source == "origin" || pl.source == "viewpoint position")
      throw perception::InputError(path +
                                   ": --sensor-frame optical needs the sensor's pose "
                                   "(the points are in its optical frame), but --origin and "
                                   "--viewpoint origin take the points as world-frame");
    pl.optical = true;
    pl.pose.orientation = (pl.pose.orientation * perception::optical_in_body()).normalized();
  }
}

// The refusal of a cloud whose dominant plane is not level (UpMode::kCheck, and every cloud
// placed by an unmarked VIEWPOINT).
[[noreturn]] void refuse_unlevel(const std::string& path, const CloudPlacement& pl,
                                 double max_tilt_deg) {
  const perception::SupportPlane& p = *pl.plane;
  std::string sensor = pl.position_known ? "the sensor"
                                         : "the sensor (taken at the frame's "
                                           "origin: no position given)";
  std::string where = p.tilt_deg > 90 ? " below it (looking up at it)" : " above it";
  std::string head = path + ": z does not look like up: the dominant plane (" +
                     fixed(100 * p.inlier_share, 0) + " % of the points) is tilted " +
                     fixed(p.tilt_deg, 1) + " deg from level (more than " + fixed(max_tilt_deg, 0) +
                     ") and " + sensor + " is " + fixed(p.sensor_height, 2) + " m" + where;
  if (pl.source == "viewpoint") {
    // The same plane in the file's own frame: what the points say without the VIEWPOINT.
    const Eigen::Vector3d raw = pl.pose.orientation.inverse() * p.normal();
    const double raw_tilt = std::acos(std::clamp(raw.z(), -1.0, 1.0)) * 180.0 / M_PI;
    const std::string origin =
        "--viewpoint origin (the points taken as written, the VIEWPOINT's position as the "
        "sensor's, its rotation not applied)";
    const std::string others =
        "give the sensor's pose (--sensor-pose, --poses), or level the cloud by that plane "
        "(--up auto, after the VIEWPOINT's rotation)";
    const std::string as_is =
        "--up z maps it with the VIEWPOINT's rotation applied, tilted as it is";
    // Level as written: world-frame points whose VIEWPOINT holds the sensor's pose, the common
    // case, so the flag that reads them so leads.
    const bool level_as_written = raw_tilt <= max_tilt_deg;
    throw perception::InputError(
        head +
        ", with the rotation of the file's VIEWPOINT applied (PCL's meaning: the points in "
        "the sensor frame, VIEWPOINT its pose); as written, that plane is " +
        fixed(raw_tilt, 1) + " deg from level" +
        (level_as_written
             ? ", so the points look already in the world frame: say " + origin +
                   ". Otherwise " + others + "; " + as_is
             : ". Either " + others + "; or, if the points are in the world frame, say " +
                   origin + "; " + as_is));
  }
  throw perception::InputError(
      head +
      ". A camera's points are often in its optical frame (z forward, y down). Give the sensor's "
      "pose (--sensor-pose X,Y,Z,QX,QY,QZ,QW, --poses FILE, or a PCD VIEWPOINT; --sensor-frame "
      "optical for an optical frame), level the cloud by that plane (--up auto), or take z as up "
      "anyway (--up z)");
}

// Places a cloud file's points in the world (resolve_pose, then the up check or levelling) and
// records how in `pl`; points a pose carries beyond float's range are dropped and counted in
// *non_finite.
perception::PointCloud place_cloud(perception::CloudFileRead file, const std::string& path,
                                   const CloudPoseOptions& o, const perception::PoseLine* line,
                                   CloudPlacement& pl, size_t* non_finite) {
  resolve_pose(file, path, o, line, pl);
  const bool file_marked = file.viewpoint_marked;
  perception::PointCloud cloud;
  cloud.source = path;
  cloud.points = std::move(file.points);
  const bool identity = pl.pose.orientation.isApprox(Eigen::Quaterniond::Identity(), 0.0) &&
                        pl.pose.position.isZero(0.0);
  // --origin and a VIEWPOINT read as a position take the points as they are.
  if (!identity && pl.source != "origin" && pl.source != "viewpoint position")
    *non_finite += perception::transform_points(cloud.points, pl.pose);
  if (pl.position_known) cloud.sensor_origin = pl.pose.position;
  if (o.up == UpMode::kZ) return cloud;
  // A pose the user gave, or terrastride's writer declared, is trusted. A VIEWPOINT without the
  // writer's marker is applied (PCL's meaning) but checked: real files carry VIEWPOINTs that are
  // not the pose of their points' frame (e.g. world-frame points with the sensor's pose).
  const bool trusted = pl.rotation_known && !(pl.source == "viewpoint" && !file_marked);
  if (trusted) return cloud;
  const Eigen::Vector3d sensor = pl.pose.position;
  pl.plane = perception::estimate_support_plane(cloud.points, sensor, o.plane);
  const perception::SupportPlane& plane = *pl.plane;
  // --up auto levels an unmarked VIEWPOINT's cloud too: its rotation applied, then the plane's.
  if (o.up == UpMode::kCheck) {
    if (plane.found && plane.tilt_deg > o.max_tilt_deg) refuse_unlevel(path, pl, o.max_tilt_deg);
    return cloud;
  }
  if (!plane.found)
    throw perception::InputError(path + ": --up auto cannot level this cloud: " + plane.problem +
                                 "; give the sensor's pose (--sensor-pose, --poses, a PCD "
                                 "VIEWPOINT) or take z as up (--up z)");
  // The smallest rotation taking the plane's normal to +z, about the sensor: heading is kept as
  // far as a rotation can, and the sensor stays where it was.
  pl.levelling = Eigen::Quaterniond::FromTwoVectors(plane.normal(), Eigen::Vector3d::UnitZ());
  pl.levelled = true;
  // About the sensor: p -> L (p - s) + s.
  *non_finite +=
      perception::transform_points(cloud.points, {sensor - pl.levelling * sensor, pl.levelling});
  if (cloud.points.empty())
    throw perception::InputError(path + ": no point is finite once levelled");
  return cloud;
}

}  // namespace

json placement_json(const CloudPlacement& pl) {
  const auto& q = pl.pose.orientation;
  json pose = {{"source", pl.source}};
  if (pl.position_known)
    pose["position"] = {pl.pose.position.x(), pl.pose.position.y(), pl.pose.position.z()};
  if (pl.rotation_known || pl.optical) pose["orientation_xyzw"] = {q.x(), q.y(), q.z(), q.w()};
  pose["sensor_frame"] = pl.optical ? "optical" : "body";
  if (pl.source == "poses") pose["poses_line"] = pl.poses_line;
  json up;
  if (pl.rotation_known && !pl.plane) {
    up = {{"from", "pose"}};
  } else if (!pl.plane) {
    up = {{"from", "z (--up z)"}};
  } else {
    const auto& p = *pl.plane;
    up = {{"from", pl.levelled         ? "levelled by the dominant plane (--up auto)"
                   : pl.rotation_known ? "pose, checked against the dominant plane"
                                       : "z, checked against the dominant plane"},
          {"method", "pcl::SACSegmentation (RANSAC, plane model) on a voxel-grid copy"},
          {"found", p.found},
          {"points_used", p.points_used},
          {"seconds", p.seconds},
          {"sensor_at_frame_origin", !pl.position_known}};
    if (p.found) {
      up["tilt_deg"] = p.tilt_deg;
      up["sensor_height"] = p.sensor_height;
      up["sensor_in_plane"] = p.sensor_in_plane;
      up["inlier_share"] = p.inlier_share;
      up["plane"] = {p.coefficients[0], p.coefficients[1], p.coefficients[2], p.coefficients[3]};
    } else {
      up["problem"] = p.problem;
    }
    if (pl.levelled) {
      const auto& l = pl.levelling;
      up["levelling_xyzw"] = {l.x(), l.y(), l.z(), l.w()};
    }
  }
  return {{"pose", pose}, {"up", up}};
}

namespace {

// The layers' block of terrain.json for a map kept in memory (a report from clouds), which must
// read as its folder's would. write_terrain_layers is the one description of the layers, and it
// describes them as it writes them: until terrain_map.hpp offers the description alone, the layers
// are written into a scratch folder that is removed at once (never read back).
json layers_json(const TerrainMap& map) {
  namespace fs = std::filesystem;
  std::string scratch = (fs::temp_directory_path() / "terrastride-layers-XXXXXX").string();
  if (!mkdtemp(scratch.data()))
    throw perception::InputError(scratch +
                                 ": cannot create a scratch folder: " + std::strerror(errno));
  struct Remove {
    std::string dir;
    ~Remove() {
      std::error_code ec;
      fs::remove_all(dir, ec);
    }
  } remove{scratch};
  return write_terrain_layers(map, scratch);
}

// Adds what terrain.json holds beyond the layers: the OctoMap, the inputs, the point counts and
// the timings (without write_s and total_s, which the writer adds).
void add_build_json(json& meta, const MapBuild& build, const MapSources& sources) {
  if (sources.files.size() != build.kept.size())
    throw std::invalid_argument("terrain.json: " + std::to_string(sources.files.size()) +
                                " cloud files for " + std::to_string(build.kept.size()) +
                                " clouds");
  if (build.octree) {
    meta["octomap"] = {{"file", "octomap.bt"},
                       {"resolution", build.octomap_options->resolution},
                       {"leaf_nodes", build.octree->getNumLeafNodes()}};
    if (build.octomap_options->max_range > 0)
      meta["octomap"]["max_range"] = build.octomap_options->max_range;
  }
  const size_t first_new = build.clouds.size() - build.kept.size();
  json inputs = json::array();
  size_t points_in = 0, non_finite = 0;
  for (size_t k = 0; k < sources.files.size(); ++k) {
    const CloudFile& f = sources.files[k];
    json in{{"path", f.path}, {"points", f.points}, {"non_finite", f.non_finite}};
    const auto& origin = build.clouds[first_new + k].sensor_origin;
    if (origin) in["origin"] = {origin->x(), origin->y(), origin->z()};
    if (f.placement) in.update(placement_json(*f.placement));
    in["kept"] = build.kept[k];
    inputs.push_back(in);
    points_in += f.points;
    non_finite += f.non_finite;
  }
  meta["inputs"] = inputs;
  meta["statistics"]["points_in"] = points_in;
  meta["statistics"]["non_finite"] = non_finite;
  meta["statistics"]["points_kept"] = build.points_kept;
  meta["statistics"]["noise_sigma"] = build.map->grid().noise_sigma;
  meta["timings"] = {{"read_s", sources.read_s},
                     {"filter_s", build.timings.clean_s},
                     {"grid_s", build.timings.grid_s},
                     {"safety_s", build.timings.safety_s},
                     {"octomap_s", build.timings.octomap_s}};
}

}  // namespace

MapInput read_map_clouds(const std::vector<std::string>& paths, const CloudPoseOptions& poses,
                         const std::function<void(size_t)>& before_file) {
  if (poses.origin && (poses.sensor_pose || !poses.poses.empty()))
    throw perception::InputError(
        "--origin gives world-frame points and a position only; it cannot go with --sensor-pose "
        "or --poses, which give the sensor frame's pose");
  if (poses.sensor_pose && !poses.poses.empty())
    throw perception::InputError("--sensor-pose and --poses both give the clouds' poses: use one");
  if (!(poses.max_tilt_deg >= 0 && poses.max_tilt_deg <= 180))
    throw perception::InputError("the largest tilt must be in [0, 180] degrees");
  MapInput input;
  const auto t0 = Clock::now();
  input.sources.started = t0;
  // Each cloud's poses-file line, matched by canonical path before any file is read.
  std::vector<const perception::PoseLine*> lines(paths.size(), nullptr);
  if (!poses.poses.empty()) {
    for (size_t k = 0; k < paths.size(); ++k) {
      const std::string key = canonical_path(paths[k]);
      for (const auto& line : poses.poses)
        if (line.resolved == key) lines[k] = &line;
      if (!lines[k])
        throw perception::InputError(paths[k] + ": no pose for it in " + poses.poses_file +
                                     " (a line 'PATH X Y Z QX QY QZ QW'; relative paths are "
                                     "relative to the poses file's folder)");
    }
  }
  // One file per core at a time: parsing a PCD is CPU-bound (the 1 M-point scan's three files,
  // read_s 0.15 s of the map command one after the other). Each file writes its own slot; the
  // error of the first failing file in the given order is the one thrown, as a loop would.
  std::vector<perception::PointCloud> clouds(paths.size());
  std::vector<CloudFile> files(paths.size());
  std::mutex progress_mutex;
  parallel_for(paths.size(), [&](size_t k) {
    if (before_file) {
      std::lock_guard<std::mutex> lock(progress_mutex);
      before_file(k);
    }
    perception::CloudFileRead file = perception::read_cloud_file(paths[k]);
    files[k] = {paths[k], file.stats.points_in_file, file.stats.non_finite, CloudPlacement{}};
    clouds[k] = place_cloud(std::move(file), paths[k], poses, lines[k], *files[k].placement,
                            &files[k].non_finite);
    if (clouds[k].points.empty())
      throw perception::InputError(paths[k] + ": no point is finite once placed by its pose");
  });
  input.sources.files = std::move(files);
  input.clouds = std::move(clouds);
  input.sources.read_s = seconds_since(t0);
  return input;
}

perception::PointCloud place_map_points(std::vector<Eigen::Vector3f> points,
                                        const std::string& name, const CloudPoseOptions& poses,
                                        CloudPlacement* placement) {
  if (poses.origin && poses.sensor_pose)
    throw perception::InputError(name + ": \"origin\" gives world-frame points, \"pose\" the pose "
                                 "of the points' frame: give one");
  perception::CloudFileRead file;
  file.points = std::move(points);
  CloudPlacement pl;
  size_t dropped = 0;
  perception::PointCloud cloud = place_cloud(std::move(file), name, poses, nullptr, pl, &dropped);
  if (cloud.points.empty())
    throw perception::InputError(name + ": no point is finite once placed by its pose");
  if (placement) *placement = std::move(pl);
  return cloud;
}

MapInput read_map_clouds(const std::vector<std::string>& paths,
                         const std::optional<Eigen::Vector3d>& origin,
                         const std::function<void(size_t)>& before_file) {
  CloudPoseOptions poses;
  poses.origin = origin;
  return read_map_clouds(paths, poses, before_file);
}

perception::OctoMapOptions default_map_octomap() {
  perception::OctoMapOptions o;
  o.resolution = 0.05;
  o.max_range = -1.0;
  return o;
}

MapBuild build_terrain_map(std::vector<perception::PointCloud> clouds,
                           const MapBuildOptions& options) {
  MapBuild build;
  build.octomap_options = options.octomap;
  const std::vector<perception::PointCloud> none;
  const std::vector<perception::PointCloud>& before =
      options.cleaned_before ? *options.cleaned_before : none;

  if (options.on_stage) options.on_stage(MapStage::kClean, build);
  auto t = Clock::now();
  std::optional<OctoMapThread> octomap;
  if (options.octomap) octomap.emplace(*options.octomap, before, clouds);
  try {
    parallel_for(clouds.size(), [&](size_t k) {
      if (options.cleaning) {
        try {
          clouds[k] = perception::filter_cloud(clouds[k], *options.cleaning);
        } catch (const perception::InputError& e) {
          throw MapBuildError(MapStage::kClean, e.what());
        }
      }
      if (octomap) octomap->mark_cleaned(k);
    });
  } catch (...) {
    if (octomap) octomap->stop();  // it must not wait for clouds that will not come
    throw;
  }
  size_t points = 0;
  for (const auto& c : before) points += c.points.size();
  for (const auto& c : clouds) {
    build.kept.push_back(c.points.size());
    build.points_kept += c.points.size();
  }
  points += build.points_kept;
  build.timings.clean_s = seconds_since(t);
  if (points == 0) {
    if (octomap) octomap->stop();
    throw MapBuildError(MapStage::kClean, "no points left after cleaning the input clouds");
  }

  // The grid reads the clouds while the OctoMap's thread does: they move into the build only
  // after it ends.
  std::vector<perception::PointCloud> fused;
  if (!before.empty()) {
    fused = before;
    fused.insert(fused.end(), clouds.begin(), clouds.end());
  }
  const std::vector<perception::PointCloud>& grid_input = before.empty() ? clouds : fused;
  std::exception_ptr map_error;
  try {
    if (options.on_stage) options.on_stage(MapStage::kGrid, build);
    t = Clock::now();
    try {
      HeightGrid grid = build_height_grid(grid_input, options.grid);
      build.timings.grid_s = seconds_since(t);
      t = Clock::now();
      build.map = std::make_unique<TerrainMap>(std::move(grid), options.foot_radii, options.safety);
      build.timings.safety_s = seconds_since(t);
    } catch (const perception::InputError& e) {
      throw MapBuildError(MapStage::kGrid, e.what());
    }
  } catch (...) {
    map_error = std::current_exception();
    if (octomap) octomap->stop();
  }
  if (octomap) {
    std::unique_ptr<octomap::OcTree> tree;
    std::exception_ptr octomap_error;
    try {
      tree = octomap->finish(&build.timings.octomap_s);
    } catch (...) {
      octomap_error = std::current_exception();
    }
    if (map_error) std::rethrow_exception(map_error);
    if (octomap_error) std::rethrow_exception(octomap_error);
    build.octree = std::move(tree);
  } else if (map_error) {
    std::rethrow_exception(map_error);
  }
  build.clouds = before.empty() ? std::move(clouds) : std::move(fused);
  return build;
}

BagMapInput read_map_bags(const std::vector<std::string>& paths,
                          const perception::BagCloudOptions& options,
                          const std::function<void(size_t, size_t)>& progress) {
  BagMapInput out;
  const auto t0 = Clock::now();
  out.input.sources.started = t0;
  for (size_t b = 0; b < paths.size(); ++b) {
    perception::BagCloudStats stats;
    perception::read_bag_clouds(
        paths[b], options,
        [&](perception::PointCloud&& cloud, const perception::BagCloudInfo& info) {
          out.input.sources.files.push_back(
              {cloud.source, info.points_in, info.non_finite, std::nullopt});
          out.input.clouds.push_back(std::move(cloud));
          if (progress) progress(b, out.input.clouds.size());
        },
        &stats);
    out.stats.push_back(std::move(stats));
  }
  out.input.sources.read_s = seconds_since(t0);
  return out;
}

StreamedBagInput stream_map_bags(const std::vector<std::string>& paths,
                                 const perception::BagCloudOptions& options,
                                 const BagStreamOptions& stream,
                                 const std::function<void(size_t, size_t)>& progress) {
  if (!(stream.cell_size > 0)) throw perception::InputError("cell size must be > 0");
  StreamedBagInput out;
  BagMapInput& in = out.bags;
  const auto t0 = Clock::now();
  in.input.sources.started = t0;
  // The cleaning thread: takes raw clouds in order, cleans, thins, appends to the input.
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<perception::PointCloud> waiting;  // raw clouds, oldest first
  bool reading_done = false, stop = false;
  std::exception_ptr clean_error;
  std::unordered_map<uint64_t, uint32_t> cell_points;
  const auto cell_key = [&](const Eigen::Vector3f& p) {
    const auto index = [&](float v) {
      const double i = std::floor(static_cast<double>(v) / stream.cell_size);
      return static_cast<uint32_t>(static_cast<int64_t>(std::clamp(i, -2147483648.0, 2147483647.0)) +
                                   2147483648LL);
    };
    return (static_cast<uint64_t>(index(p.x())) << 32) | index(p.y());
  };
  std::thread cleaner([&] {
    for (;;) {
      perception::PointCloud cloud;
      {
        std::unique_lock<std::mutex> lock(mutex);
        changed.wait(lock, [&] { return !waiting.empty() || reading_done || stop; });
        if (stop || waiting.empty()) return;
        cloud = std::move(waiting.front());
        waiting.erase(waiting.begin());
      }
      changed.notify_all();  // room for the reader
      try {
        const auto t = Clock::now();
        if (stream.cleaning) cloud = perception::filter_cloud(cloud, *stream.cleaning);
        out.points_cleaned += cloud.points.size();
        if (stream.max_cell_points > 0) {
          size_t kept = 0;
          for (const Eigen::Vector3f& p : cloud.points) {
            uint32_t& n = cell_points[cell_key(p)];
            if (n >= stream.max_cell_points) continue;
            ++n;
            cloud.points[kept++] = p;
          }
          out.points_over_cap += cloud.points.size() - kept;
          cloud.points.resize(kept);
          cloud.points.shrink_to_fit();
        }
        out.clean_s += seconds_since(t);
        std::lock_guard<std::mutex> lock(mutex);
        in.input.clouds.push_back(std::move(cloud));
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        clean_error = std::current_exception();
        stop = true;
        changed.notify_all();
        return;
      }
    }
  });
  const auto finish = [&](bool abandon) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      reading_done = true;
      stop = stop || abandon;
    }
    changed.notify_all();
    cleaner.join();
  };
  try {
    for (size_t b = 0; b < paths.size(); ++b) {
      perception::BagCloudStats stats;
      perception::read_bag_clouds(
          paths[b], options,
          [&](perception::PointCloud&& cloud, const perception::BagCloudInfo& info) {
            in.input.sources.files.push_back(
                {cloud.source, info.points_in, info.non_finite, std::nullopt});
            std::unique_lock<std::mutex> lock(mutex);
            changed.wait(lock, [&] { return waiting.size() < 2 || stop; });
            if (clean_error) std::rethrow_exception(clean_error);
            waiting.push_back(std::move(cloud));
            lock.unlock();
            changed.notify_all();
            if (progress) progress(b, in.input.sources.files.size());
          },
          &stats);
      in.stats.push_back(std::move(stats));
    }
  } catch (...) {
    finish(/*abandon=*/true);
    if (clean_error) std::rethrow_exception(clean_error);
    throw;
  }
  finish(/*abandon=*/false);
  if (clean_error) std::rethrow_exception(clean_error);
  out.cells = cell_points.size();
  in.input.sources.read_s = seconds_since(t0);
  return out;
}

OctreeMapInput read_map_octomap(const std::string& path) {
  OctreeMapInput input;
  const auto t0 = Clock::now();
  input.sources.started = t0;
  input.tree = perception::read_octomap_file(path);
  input.support = perception::octree_support_cloud(*input.tree, path, &input.stats);
  input.sources.files.push_back({path, input.support.points.size(), 0, std::nullopt});
  input.sources.read_s = seconds_since(t0);
  return input;
}

MapBuild build_terrain_map_from_octree(OctreeMapInput& input, MapBuildOptions options) {
  if (!input.tree) throw std::invalid_argument("build_terrain_map_from_octree: no tree");
  const double res = input.tree->getResolution();
  if (!(options.grid.resolution > 0)) options.grid.resolution = res;
  options.grid.input_voxel = res;
  options.grid.min_cell_points = 1;
  options.grid.min_support_points = 1;
  options.cleaning.reset();
  options.octomap.reset();
  options.cleaned_before = nullptr;
  std::vector<perception::PointCloud> clouds;
  clouds.push_back(std::move(input.support));
  MapBuild build = build_terrain_map(std::move(clouds), options);
  perception::OctoMapOptions as_read;
  as_read.resolution = res;
  build.octomap_options = as_read;
  build.octree = std::move(input.tree);
  return build;
}

perception::OutputDirKind map_output_kind() {
  return {"map",
          {"terrain.json", "octomap.bt", "layers/"},
          {"terrain.json", "octomap.bt", "layers/", "layers/*.npy"},
          {}};
}

json terrain_json(const MapBuild& build, const MapSources& sources) {
  json meta = layers_json(*build.map);
  add_build_json(meta, build, sources);
  meta["timings"]["total_s"] = seconds_since(sources.started);
  return meta;
}

json write_terrain_dir(const MapBuild& build, const MapSources& sources, const std::string& dir) {
  const auto t = Clock::now();
  perception::AtomicOutputDir out(dir, map_output_kind());
  json meta = write_terrain_layers(*build.map, out.path());
  if (build.octree) perception::write_octomap(*build.octree, out.path() + "/octomap.bt");
  add_build_json(meta, build, sources);
  meta["timings"]["write_s"] = seconds_since(t);
  meta["timings"]["total_s"] = seconds_since(sources.started);
  perception::write_file_atomically(out.path() + "/terrain.json", meta.dump(2) + "\n");
  out.commit();
  return meta;
}

json map_summary(const MapBuild& build, const json& terrain, const std::string& dir) {
  const HeightGrid& g = build.map->grid();
  json safe = json::array();
  for (const auto& r : terrain["safety"]["radii"])
    safe.push_back({{"radius", r["radius"]}, {"safe_fraction", r["safe_fraction"]}});
  json summary = {{"out", dir},
                  {"points_in", terrain["statistics"]["points_in"]},
                  {"points_kept", build.points_kept},
                  {"cells", g.geometry.size()},
                  {"grid", {g.geometry.nx, g.geometry.ny}},
                  {"resolution", g.geometry.resolution},
                  {"observed_cells", g.observed_cells},
                  {"interpolated_cells", g.interpolated_cells},
                  {"noise_sigma", g.noise_sigma},
                  {"noise_estimated", g.noise.estimated},
                  {"smoothing_length", g.smoothing_length},
                  // safe[].safe_fraction is SafetyLayer::safe_fraction(): safe cells over
                  // walkable observed (measured or interpolated) cells, unreachable levels apart.
                  {"safe_fraction_of",
                   "observed_cells + interpolated_cells - unreachable_cells"},
                  {"safe", safe},
                  {"overhang_cells", g.overhang_cells},
                  {"overhang_cells_over_unobserved_ground", g.overhang_unobserved_cells},
                  {"unreachable_cells", build.map->levels().unreachable_cells},
                  {"unreachable_levels", build.map->levels().unreachable_levels},
                  {"timings", terrain["timings"]}};
  if (!g.notes.empty()) summary["notes"] = g.notes;  // the noise note first when there is one
  return summary;
}

std::shared_ptr<octomap::OcTree> octree_as_saved(const octomap::OcTree& tree) {
  // The node bits of octomap.bt (perception::write_octomap writes the same from the root), read
  // as collision::read_octomap reads the file.
  std::stringstream bits(std::ios::in | std::ios::out | std::ios::binary);
  if (tree.getRoot()) tree.writeBinaryNode(bits, tree.getRoot());
  auto saved = std::make_shared<octomap::OcTree>(tree.getResolution());
  if (tree.getRoot()) saved->readBinaryData(bits);
  return saved;
}

}  // namespace terrastride::terrain
