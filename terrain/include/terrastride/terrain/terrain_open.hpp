// Opening the terrain a user names: one call for every command, the server, the report and the
// export. A spec is a scene name (the exact analytic terrain, docs/design.md §11), a folder
// written by `terrastride map` (terrain.json), an OctoMap file (.bt/.ot, mapped in memory as
// `terrastride map FILE.bt` maps it) or, when the caller accepts them, point-cloud files mapped in
// memory with `map`'s defaults.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace octomap {
class OcTree;
}

namespace terrastride::terrain {

// A spec that names no terrain, or one that cannot be read. what() is "INPUT: problem", or the
// problem alone when a cloud reader's message names its file already (input() empty);
// grid_options() says the problem lies in the grid's options (the cloud resolution or a radius),
// not in the input itself.
class TerrainOpenError : public std::runtime_error {
 public:
  TerrainOpenError(const std::string& input, const std::string& problem, bool grid_options = false)
      : std::runtime_error(input.empty() ? problem : input + ": " + problem),
        input_(input),
        grid_options_(grid_options) {}
  const std::string& input() const { return input_; }
  bool grid_options() const { return grid_options_; }

 private:
  std::string input_;
  bool grid_options_;
};

struct TerrainOpenOptions {
  // A scene also as the 2 cm C² B-spline map of its raster (what the optimiser plans on).
  bool smooth_scene = false;
  // Point-cloud files are mapped in memory (else a file that is no OctoMap is refused with
  // `file_hint`).
  bool clouds = false;
  std::string file_hint = "not a terrain folder, an OctoMap file or a scene name";
  // A map folder's octomap.bt (the scan's occupancy map), read when the folder has one.
  bool folder_octomap = true;
  double cloud_resolution = 0.02;                // grid cell of clouds mapped in memory (m)
  std::optional<Eigen::Vector3d> cloud_origin;   // every cloud's sensor origin, when given
};

struct OpenedTerrain {
  std::string spec;  // the inputs, comma-separated
  std::string kind;  // "scene", "map" (a folder), "octomap" or "clouds"
  std::shared_ptr<const Scene> scene;    // scene: the exact terrain
  std::shared_ptr<const TerrainMap> map;  // map, octomap, clouds; a scene's with smooth_scene
  // The occupancy map: an OctoMap file's own tree, the one built from clouds, or a folder's
  // octomap.bt; null for scenes and folders without one.
  std::shared_ptr<const octomap::OcTree> octree;
  // What terrain.json says of the map (a folder's own file; built ones describe their build);
  // a scene's name and description.
  nlohmann::json info = nlohmann::json::object();
};

// Throws TerrainOpenError naming the input; several inputs are clouds only.
OpenedTerrain open_terrain(const std::vector<std::string>& inputs,
                           const TerrainOpenOptions& options = {});

// True when `path` is a folder written by `terrastride map` (holds terrain.json).
bool is_terrain_folder(const std::string& path);

}  // namespace terrastride::terrain
