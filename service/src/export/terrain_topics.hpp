// The terrain's Foxglove topics (docs/export.md): the height/margin grid, the overhead clearance,
// the walkable relief as a triangle mesh coloured by safety margin, the occupied voxels, the
// input clouds and the sensor poses. Every message stays under kMessageBudget bytes of JSON.
#pragma once

#include <string>
#include <vector>

#include "export/foxglove_json.hpp"
#include "report/report.hpp"

namespace terrastride::service::foxglove {

// Largest message an export writes (JSON bytes): a file whose messages stay below this opens on a
// laptop in Foxglove and Lichtblick (a 33 MB message stalls their 3-D panel for minutes).
constexpr size_t kMessageBudget = 3500000;

struct TerrainTopicStats {
  size_t voxels = 0;  // cubes on /terrain/voxels
  size_t voxel_messages = 0;
  size_t relief_triangles = 0;
  size_t relief_cells = 0;     // grid cells the mesh covers (before merging flat blocks)
  size_t grid_decimation = 1;  // /terrain/grid's cell is this many map cells
  size_t points = 0;           // on /terrain/points
  size_t points_in = 0;        // of the clouds read, before decimation
  size_t sensor_frames = 0;
};

// /terrain/grid (heights and margins), /terrain/overhead and /terrain/overhangs (with
// overhangs), /terrain/relief, /terrain/voxels (with an OctoMap), all at t = 0.
// `foot_radius` picks the safety layer the relief is coloured by.
TerrainTopicStats publish_terrain(Publisher& pub, const Clock& clock,
                                  const report::TerrainView& view, double foot_radius,
                                  size_t max_voxels);

// Where the clouds were taken from and when (terrain.json "inputs": "PATH[:TOPIC@SEC.NSEC]", the
// sensor pose and how the cloud was placed), in time order.
struct SensorInput {
  std::string path;
  bool has_stamp = false;
  uint64_t stamp_ns = 0;
  bool has_origin = false;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  bool has_orientation = false;
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  // "pose" when recorded
  std::string pose_source;  // "viewpoint", "origin", "poses", "sensor-pose" ("" unrecorded)
  std::string up_from;      // how up was found ("levelled by ...", "... checked ...", "z ...")
};
std::vector<SensorInput> sensor_inputs(const nlohmann::json& terrain_info);

// The clouds to draw: `files` (a `--terrain` of cloud files, read as `terrastride map` reads them
// by default) and, of a map folder's `recorded` inputs, the files still on disk (placed as the
// map placed them: its recorded pose, origin or VIEWPOINT and up) and, with `bag_frame`, the bags'
// clouds (placed in that frame by the bag's tf).
struct CloudInputs {
  std::vector<std::string> files;
  std::vector<SensorInput> recorded;
  std::string bag_frame;
};

// /terrain/points: the clouds' points in the map frame, through the map's default cleaning and a
// voxel grid coarse enough to leave at most `max_points`; /tf frames sensor_<i> at each of
// `sensors`' poses and `sensor` moving to each stamped one. A recorded input that no longer reads
// as it did is a warning on /log, not an error: the points are an aid, the map is the terrain.
void publish_clouds(Publisher& pub, const Clock& clock, const CloudInputs& clouds,
                    const std::vector<SensorInput>& sensors, size_t max_points,
                    TerrainTopicStats* stats);

}  // namespace terrastride::service::foxglove
