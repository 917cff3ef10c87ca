// The map stage of the pipeline as library calls: cloud files -> cleaned clouds -> OctoMap and
// height grid -> smoothed field and foothold-safety layers, and the folder `terrastride map --out
// DIR` writes (DIR/terrain.json, DIR/octomap.bt, DIR/layers/*.npy). `terrastride map`, the demo,
// the report from clouds and the socket's map.update build their maps with this one call.
#pragma once

#include <octomap/OcTree.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/bag_clouds.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/perception/sensor_pose.hpp"
#include "terrastride/perception/support_plane.hpp"
#include "terrastride/terrain/height_grid.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::terrain {

// How a cloud file was placed in the world (terrain.json: "inputs"[k]["pose"] and ["up"]).
struct CloudPlacement {
  // Where the pose came from: "sensor-pose", "poses" (a poses file's line), "viewpoint" (a PCD's
  // VIEWPOINT as the sensor pose), "viewpoint position" (--viewpoint origin), "origin"
  // (--origin) or "none".
  std::string source = "none";
  perception::SensorPose pose;  // the file's frame -> world, the optical rotation included
  bool position_known = false;  // else the sensor is taken at the file frame's origin
  bool rotation_known = false;  // else the up direction was checked or levelled (unless --up z)
  // A VIEWPOINT's rotation is applied, but checked like an unknown one (unless --up z) when the
  // file lacks the writer's marker: `plane` is then set too.
  bool optical = false;   // --sensor-frame optical: pose is the body's
  size_t poses_line = 0;  // the poses file's line, for "poses"
  // The dominant plane, for a cloud without a known rotation (not with --up z).
  std::optional<perception::SupportPlane> plane;
  bool levelled = false;  // --up auto rotated the cloud about the sensor: plane normal -> +z
  Eigen::Quaterniond levelling = Eigen::Quaterniond::Identity();
};

// A cloud file read for a map, as terrain.json lists it under "inputs".
struct CloudFile {
  std::string path;       // as given
  size_t points = 0;      // points in the file, finite or not
  size_t non_finite = 0;  // of those, dropped because a coordinate was not finite
  std::optional<CloudPlacement> placement;  // cloud files (not bags or OctoMaps)
};

// inputs[k]["pose"] and ["up"] of terrain.json for one placement (also in `map --json`).
nlohmann::json placement_json(const CloudPlacement& placement);

// Where a map's clouds came from, for terrain.json ("inputs", "statistics", "timings").
struct MapSources {
  std::vector<CloudFile> files;  // one per cloud given to build_terrain_map, in order
  double read_s = 0.0;
  // terrain.json's total_s counts from here (the start of reading).
  std::chrono::steady_clock::time_point started = std::chrono::steady_clock::now();
};

struct MapInput {
  std::vector<perception::PointCloud> clouds;
  MapSources sources;
};

// Which way is up for a cloud whose orientation nobody gave (no --sensor-pose, no poses file line,
// no VIEWPOINT rotation):
//   kCheck  the default: the cloud's dominant plane (perception::estimate_support_plane, seen
//           from the sensor, or from the file frame's origin when no position is known) must be
//           within max_tilt_deg of level with the sensor above it, else the cloud is refused
//           naming the tilt, the sensor's height and the options that fix it. A cloud with no
//           dominant plane (too few points, none holding 15 % of them) is mapped as it is, with
//           the reason in terrain.json.
//   kAuto   the cloud is rotated about its sensor so that the plane's normal (towards the
//           sensor) is +z; a cloud with no dominant plane is refused.
//   kZ      z is up, unchecked.
// A cloud placed by a VIEWPOINT that lacks terrastride's marker is checked as under kCheck (also
// with kAuto; not with kZ): its rotation is applied as PCL means it, and the refusal says what
// the points look like without it (--viewpoint origin).
enum class UpMode { kCheck, kAuto, kZ };

// How read_map_clouds places cloud files in the world.
struct CloudPoseOptions {
  perception::ViewpointUse viewpoint = perception::ViewpointUse::kDefault;  // --viewpoint
  // --origin: the points are world-frame, this is every cloud's sensor position (any VIEWPOINT
  // is ignored). Not with sensor_pose or poses.
  std::optional<Eigen::Vector3d> origin;
  std::optional<perception::SensorPose> sensor_pose;  // --sensor-pose: every cloud's pose
  std::vector<perception::PoseLine> poses;            // --poses: one per cloud, by path
  std::string poses_file;                             // named in errors
  perception::SensorFrame sensor_frame = perception::SensorFrame::kBody;  // --sensor-frame
  UpMode up = UpMode::kCheck;
  double max_tilt_deg = 20.0;
  perception::SupportPlaneOptions plane;
};

// Reads cloud files (PCD, PLY, XYZ, NPY) in the order given and places each in the world: its
// pose from `poses` (sensor_pose, a poses line, else the VIEWPOINT; --sensor-frame optical
// composes the optical frame's rotation), then the up check or levelling of `poses.up`. Files
// are read on up to one thread per core; `before_file(k)`, when set, is called before file k is
// read (progress), one call at a time, from the reading thread. Throws perception::InputError
// naming the first failing file (and the poses file's line).
MapInput read_map_clouds(const std::vector<std::string>& paths, const CloudPoseOptions& poses,
                         const std::function<void(size_t)>& before_file = {});
// Places points held in memory (the socket's `points` attachment) as read_map_clouds places a
// file's: poses.sensor_pose or poses.origin, poses.sensor_frame and poses.up (a poses file does
// not apply); `name` names the cloud in errors. Returns the placed cloud and how in *placement.
perception::PointCloud place_map_points(std::vector<Eigen::Vector3f> points,
                                        const std::string& name, const CloudPoseOptions& poses,
                                        CloudPlacement* placement);
// As above with CloudPoseOptions{.origin = origin}.
MapInput read_map_clouds(const std::vector<std::string>& paths,
                         const std::optional<Eigen::Vector3d>& origin,
                         const std::function<void(size_t)>& before_file = {});

// The stages of build_terrain_map: cleaning, then the height grid and the safety layers; the
// OctoMap is built beside both.
enum class MapStage { kClean, kGrid, kOctoMap };

// A stage of build_terrain_map refused its options or its data (the message names the problem):
// stage() tells the caller which of its options to name.
class MapBuildError : public perception::InputError {
 public:
  MapBuildError(MapStage stage, const std::string& message)
      : perception::InputError(message), stage_(stage) {}
  MapStage stage() const { return stage_; }

 private:
  MapStage stage_;
};

// The OctoMap `terrastride map` builds: 5 cm voxels, rays not cut. Ray casting cost grows with
// range / voxel size; 2 cm was measured against 5 cm (2026-11-22, 2 cores under load): 10-15x the
// OctoMap time on every shipped scan (0.05-0.1 s -> 0.6-1.3 s for data/scans, 0.2 -> 1.7 s for
// 1 M points), ~10x the octomap.bt size, and 4.6 s / 0.4 GB -> 17-26 s / 1.8 GB for
// ../shared/scans/octomap/scan.xyz; so 5 cm stays the default and finer voxels are an option for
// small scans. Far rays are kept: the height grid cannot tell which far returns matter, so
// dropping them (max_range) stays the caller's choice.
perception::OctoMapOptions default_map_octomap();

struct MapBuild;

struct MapBuildOptions {
  // Applied to each cloud on its own (outlier statistics are per cloud); nullopt: the clouds are
  // fused as given.
  std::optional<perception::CloudFilterOptions> cleaning = perception::default_map_cleaning();
  HeightGridOptions grid;
  std::vector<double> foot_radii{0.02, 0.05, 0.10};  // safety layers computed up front
  SafetyOptions safety;
  // nullopt: no OctoMap (a map kept in memory for queries and plans needs none).
  std::optional<perception::OctoMapOptions> octomap = default_map_octomap();
  // Clouds an earlier build cleaned (its `clouds`), fused first and not cleaned again, e.g. a
  // map that grows by one cloud at a time. Not owned; must outlive the call.
  const std::vector<perception::PointCloud>* cleaned_before = nullptr;
  // Called on the calling thread as kClean and kGrid begin, with the build so far (at kGrid:
  // `kept` and `points_kept` are known). It may throw to abandon the build (a cancelled request,
  // a point budget): the OctoMap thread is stopped and joined, and the exception propagates.
  std::function<void(MapStage, const MapBuild&)> on_stage;
};

struct MapBuild {
  std::unique_ptr<TerrainMap> map;
  std::unique_ptr<octomap::OcTree> octree;  // null without MapBuildOptions::octomap
  std::optional<perception::OctoMapOptions> octomap_options;  // what built `octree`
  // What the grid was built from: the cleaned_before clouds, then the new ones cleaned.
  std::vector<perception::PointCloud> clouds;
  std::vector<size_t> kept;  // per new cloud: points left after cleaning
  size_t points_kept = 0;    // the sum of `kept`
  struct Timings {
    double clean_s = 0.0;
    double grid_s = 0.0;
    double safety_s = 0.0;
    double octomap_s = 0.0;  // the OctoMap's own work, not its waits for cleaned clouds
  } timings;
};

// Cleans every cloud, builds the OctoMap, the height grid, the smoothed field and the safety
// layers. The clouds are cleaned in parallel (one per core; every result lands in its own slot,
// hence the same map as in order); the OctoMap's thread inserts cloud k, in input order, as soon
// as it is cleaned, so a core left without a cloud to clean works on the OctoMap meanwhile, while
// this thread builds the grid and the layers. Rays go to one point per OctoMap voxel (a voxel-grid
// filtered copy): ray casting is the expensive part, and the occupied voxels are the same.
// Throws MapBuildError: kClean for cleaning options the filter refuses or when no point is left,
// kGrid for the grid and safety options (resolution, radii), kOctoMap for the OctoMap's options
// or a cloud outside its addressable cube. The first failing stage in that order is reported.
MapBuild build_terrain_map(std::vector<perception::PointCloud> clouds,
                           const MapBuildOptions& options = {});

// An OctoMap file as a map's input (`terrastride map X.bt|X.ot`, `--terrain X.bt`): the tree as
// read, and its support surfaces as the one cloud the height grid is built from
// (perception::octree_support_cloud: the top voxel of every vertical run of occupied voxels that
// has no known-free voxel beneath it).
struct OctreeMapInput {
  std::unique_ptr<octomap::OcTree> tree;
  perception::PointCloud support;
  perception::OctreeSupportStats stats;
  MapSources sources;  // one "file": the OctoMap, with its support points
};

// Reads an OctoMap file (perception::read_octomap_file). Throws perception::InputError naming
// the file (not an OctoMap, a tree type that is not occupancy, truncated, no occupied voxel).
OctreeMapInput read_map_octomap(const std::string& path);

// The map of an OctoMap: the height grid and safety layers from `input.support`, and the tree
// itself as the build's OctoMap (unknown space stays unknown: nothing is re-inserted). Of
// `options`, the grid, foot radii and safety are used; grid.resolution <= 0 means the tree's
// resolution (one grid cell per voxel column, each voxel one sample: a cell needs one point).
// The support points are not cleaned (they are already a fused occupancy map) and no OctoMap is
// built. `input.tree` and `input.support` are moved from. Throws MapBuildError as
// build_terrain_map does.
MapBuild build_terrain_map_from_octree(OctreeMapInput& input, MapBuildOptions options);

// A robot's recording as a map's input (`terrastride map RUN.mcap|RUN.db3|RUN.bag --topic T
// --frame F`): the PointCloud2 messages of the topics, each placed in the fixed frame with its
// sensor origin at its stamp (perception::read_bag_clouds), in file order. `sources.files` has one
// entry per cloud ("PATH:TOPIC@STAMP"). Throws perception::InputError naming the file, topic and
// time.
struct BagMapInput {
  MapInput input;
  std::vector<perception::BagCloudStats> stats;  // per bag
};
BagMapInput read_map_bags(const std::vector<std::string>& paths,
                          const perception::BagCloudOptions& options,
                          const std::function<void(size_t bag, size_t clouds)>& progress = {});

// A recording streamed into a map's input (`terrastride map RUN --topic ...`): memory follows
// the map, not the file. Each cloud is cleaned as soon as it is read (filter_cloud with
// `cleaning`, per cloud as build_terrain_map does, on a second thread: reading and cleaning
// overlap, at most two raw clouds wait), then thinned to at most `max_cell_points` points per
// grid cell of `cell_size` over all clouds so far: a cell's first points are kept, later ones
// dropped and counted. A robot standing still, or driving over the same ground again, adds no
// memory once its cells are full; 0 keeps every point (memory then grows with the points kept,
// as before). The clouds come out cleaned: build them with MapBuildOptions::cleaning = nullopt.
struct BagStreamOptions {
  std::optional<perception::CloudFilterOptions> cleaning = perception::default_map_cleaning();
  double cell_size = 0.02;       // the grid's resolution
  size_t max_cell_points = 0;    // 0: no cap
};
struct StreamedBagInput {
  BagMapInput bags;             // cleaned (and thinned) clouds; sources count the points read
  double clean_s = 0.0;         // cleaning's own time (on its thread)
  size_t points_cleaned = 0;    // left after cleaning, before the cap
  size_t points_over_cap = 0;   // dropped by the cap
  size_t cells = 0;             // grid cells holding points
};
StreamedBagInput stream_map_bags(const std::vector<std::string>& paths,
                                 const perception::BagCloudOptions& options,
                                 const BagStreamOptions& stream,
                                 const std::function<void(size_t bag, size_t clouds)>& progress = {});

// What `terrastride map --out` writes, for perception::AtomicOutputDir: outputs of versions
// before the marker file are recognised by their names (every version wrote all three of
// terrain.json, octomap.bt and layers/, so a folder that merely holds a terrain.json is not taken
// for one).
perception::OutputDirKind map_output_kind();

// terrain.json for a build: the grid, layers, safety and statistics blocks of
// write_terrain_layers, the OctoMap (when there is one), the inputs and the timings.
nlohmann::json terrain_json(const MapBuild& build, const MapSources& sources);

// Writes the map folder `terrastride map` writes (terrain.json, octomap.bt when the build has an
// OctoMap, layers/*.npy) into a temporary folder beside `dir`, then renames it into place with
// its .terrastride-output marker (perception::AtomicOutputDir; an existing `dir` is replaced only
// when it is an earlier output). Returns terrain.json's document. Throws perception::InputError
// naming the path.
nlohmann::json write_terrain_dir(const MapBuild& build, const MapSources& sources,
                                 const std::string& dir);

// The figures `terrastride map --json` prints for a written map folder `dir` whose terrain.json
// is `terrain`.
nlohmann::json map_summary(const MapBuild& build, const nlohmann::json& terrain,
                           const std::string& dir);

// The OctoMap as octomap.bt holds it and every reader of a map folder sees it: each voxel
// occupied or free at the clamping thresholds (the build's log-odds are not saved). Checks run on
// this judge a map in memory exactly as they judge its folder.
std::shared_ptr<octomap::OcTree> octree_as_saved(const octomap::OcTree& tree);

}  // namespace terrastride::terrain
