#include "terrastride/terrain/terrain_open.hpp"

#include <filesystem>
#include <fstream>

#include "terrastride/perception/json_input.hpp"
#include "terrastride/perception/octomap_input.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/terrain/map_build.hpp"

namespace terrastride::terrain {
namespace {

namespace fs = std::filesystem;

OpenedTerrain open_scene(const std::string& name, const TerrainOpenOptions& options) {
  OpenedTerrain t;
  t.kind = "scene";
  std::shared_ptr<Scene> scene = make_scene(name);
  // A 2 cm C2 B-spline of the rasterised scene for the optimiser; checks on the exact scene.
  if (options.smooth_scene) t.map = TerrainMap::from_scene(*scene, 0.02, {});
  t.info = {{"scene", scene->name()}, {"description", scene->describe()}};
  t.scene = std::move(scene);
  return t;
}

OpenedTerrain open_folder(const std::string& dir, const TerrainOpenOptions& options) {
  OpenedTerrain t;
  t.kind = "map";
  t.map = load_terrain_dir(dir);
  std::ifstream meta{(fs::path(dir) / "terrain.json").string()};
  try {
    t.info = perception::parse_json_input(meta);
  } catch (const std::exception&) {
    t.info = nlohmann::json::object();  // load_terrain_dir read what it needs from it
  }
  const fs::path bt = fs::path(dir) / "octomap.bt";
  std::error_code ec;
  if (options.folder_octomap && fs::exists(bt, ec))
    t.octree = std::shared_ptr<const octomap::OcTree>(perception::read_octomap_file(bt.string()));
  return t;
}

// Mapped in memory with `terrastride map`'s defaults for an OctoMap (the grid at its own voxel
// size); its own tree is the occupancy map.
OpenedTerrain open_octomap(const std::string& path) {
  OpenedTerrain t;
  t.kind = "octomap";
  OctreeMapInput input = read_map_octomap(path);
  MapBuildOptions map_options;
  map_options.grid.resolution = 0;
  MapBuild build = build_terrain_map_from_octree(input, map_options);
  t.info = terrain_json(build, input.sources);
  t.octree = octree_as_saved(*build.octree);
  t.map = std::move(build.map);
  return t;
}

// Mapped in memory as `terrastride map` maps them (its defaults, the caller's resolution and
// origin); described as that folder's terrain.json would describe them.
OpenedTerrain open_clouds(const std::vector<std::string>& inputs,
                          const TerrainOpenOptions& options) {
  for (const auto& in : inputs) {
    std::error_code ec;
    if (fs::is_directory(in, ec))
      throw TerrainOpenError(in, "a folder without terrain.json (not written by `terrastride map`)");
    if (!fs::exists(in, ec))
      throw TerrainOpenError(in, "no such file, folder or scene (scenes: " + scene_names_text() +
                                     ")");
  }
  OpenedTerrain t;
  t.kind = "clouds";
  MapInput input;
  MapBuild build;
  try {
    input = read_map_clouds(inputs, options.cloud_origin);
    MapBuildOptions map_options;
    map_options.grid.resolution = options.cloud_resolution;
    build = build_terrain_map(std::move(input.clouds), map_options);
  } catch (const MapBuildError& e) {
    throw TerrainOpenError("", e.what(), e.stage() == MapStage::kGrid);
  } catch (const perception::InputError& e) {
    throw TerrainOpenError("", e.what());  // the reader's message names the file
  }
  t.info = terrain_json(build, input.sources);
  t.octree = octree_as_saved(*build.octree);
  t.map = std::move(build.map);
  return t;
}

OpenedTerrain open_one(const std::string& spec, const TerrainOpenOptions& options) {
  std::error_code ec;
  if (fs::is_directory(spec, ec)) {
    if (!options.clouds || is_terrain_folder(spec)) return open_folder(spec, options);
  } else if (perception::is_octomap_file(spec) && fs::exists(spec, ec)) {
    return open_octomap(spec);
  } else if (!fs::exists(spec, ec) && is_scene_name(spec)) {
    return open_scene(spec, options);
  } else if (!options.clouds) {
    if (fs::exists(spec, ec)) throw TerrainOpenError(spec, options.file_hint);
    throw TerrainOpenError(spec, "neither a terrain directory nor a scene name (scenes: " +
                                     scene_names_text() + ")");
  }
  return open_clouds({spec}, options);
}

}  // namespace

bool is_terrain_folder(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec) && fs::exists(fs::path(path) / "terrain.json", ec);
}

OpenedTerrain open_terrain(const std::vector<std::string>& inputs,
                           const TerrainOpenOptions& options) {
  if (inputs.empty()) throw TerrainOpenError("terrain", "none given");
  if (inputs.size() > 1 && !options.clouds)
    throw TerrainOpenError(inputs[1], "one terrain only (a folder, an OctoMap or a scene)");
  OpenedTerrain t;
  try {
    t = inputs.size() == 1 ? open_one(inputs[0], options) : open_clouds(inputs, options);
  } catch (const TerrainOpenError&) {
    throw;
  } catch (const perception::InputError& e) {
    // The readers' messages name the file already.
    throw TerrainOpenError(inputs.size() == 1 ? inputs[0] : "terrain", e.what());
  } catch (const std::invalid_argument& e) {
    throw TerrainOpenError(inputs.size() == 1 ? inputs[0] : "terrain", e.what());
  }
  for (const auto& in : inputs) t.spec += (t.spec.empty() ? "" : ", ") + in;
  return t;
}

}  // namespace terrastride::terrain
