// `terrastride export`: a terrain, optionally a plan and its simulated execution, as one MCAP file
// that Foxglove and Lichtblick open and play (docs/export.md lists the topics). Messages use the
// published Foxglove schemas (@foxglove/schemas, vendored in foxglove_schemas.inc) with their
// documented JSON encoding (schema encoding "jsonschema", message encoding "json").
#pragma once

#include <limits>
#include <map>
#include <string>
#include <vector>

namespace terrastride::service::foxglove {

struct ExportOptions {
  std::vector<std::string>
      terrain;                // as `report --terrain`: a map folder, clouds, an OctoMap, a scene
  std::string plan;           // plan.json ("" none)
  std::string sim;            // `simulate --out` JSON ("" none); needs a plan
  std::string out;            // the .mcap file, written atomically
  double resolution = 0.02;   // grid cell for scenes and clouds
  std::vector<double> radii;  // safety layers (empty: the terrain's own, or 2/4/6 cm)
  std::string compression = "zstd";  // "zstd" or "none"
  size_t max_voxels = 2000000;       // occupied voxels drawn at most (tiled, see kMessageBudget)
  size_t max_points = 200000;        // input-cloud points drawn at most (a voxel grid thins them)
  // The export's clock: t = 0 of the terrain at this Unix time (s); NaN: the recording's first
  // cloud stamp when the map came from a bag, else kDefaultEpoch.
  double start_time = std::numeric_limits<double>::quiet_NaN();
  std::string bag_frame;  // the fixed frame to re-read a bag-built map's clouds in ("": not read)
  std::string layout;     // the Foxglove layout file ("": OUT without .mcap + ".layout.json")
};

// Unix time (s) of t = 0 when the inputs hold no recording time: 2025-01-01T00:00:00Z.
constexpr double kDefaultEpoch = 1735689600.0;

struct ExportSummary {
  std::map<std::string, size_t> messages_per_topic;
  size_t messages = 0;
  size_t chunks = 0;
  size_t bytes = 0;
  size_t voxels = 0;  // cubes in /terrain/voxels
  size_t voxel_messages = 0;
  size_t relief_triangles = 0, relief_cells = 0;
  size_t points = 0, points_in = 0;  // /terrain/points, and the clouds' points read
  size_t grid_decimation = 1;
  size_t logs = 0;             // messages on /log
  size_t largest_message = 0;  // bytes of JSON
  std::string largest_topic;
  double epoch_s = 0.0;  // Unix time of t = 0
  std::string layout;    // the layout file written
  size_t footholds = 0;
  size_t shin_contacts = 0;  // samples x legs whose shin touches an occupied voxel
  double duration_s = 0.0;   // of the plan (0 without one)
};

// Builds and writes the file. Throws CommandError naming the input at fault (missing or broken
// plan, a plan made for another terrain, a sim.json without a plan or of another plan, an
// unwritable --out); nothing is written then (the file appears whole or not at all).
ExportSummary export_foxglove(const ExportOptions& options);

}  // namespace terrastride::service::foxglove
