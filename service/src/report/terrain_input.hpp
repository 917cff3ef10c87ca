// Turning the report's --terrain argument into a TerrainView: a folder written by `terrastride
// map`, point-cloud files (mapped in memory by terrain::build_terrain_map, as `terrastride map`
// maps them), or a scene name (the exact analytic terrain).
#pragma once

#include <Eigen/Core>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "report/report.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::service::report {

struct TerrainInputOptions {
  std::vector<double> radii;  // safety radii asked for (empty: the terrain's own, or 2/4/6 cm)
  double foot_radius = 0.02;  // the robot's, always drawn
  double resolution = 0.02;   // for scenes and clouds
  std::optional<Eigen::Vector3d> origin;  // sensor origin of every cloud (overrides the files')
  // Region a scene is voxelised over for the leg-capsule check (plans' extent); empty = none.
  bool voxelise_scene = true;
  Eigen::Vector2d voxel_lo = Eigen::Vector2d::Zero();
  Eigen::Vector2d voxel_hi = Eigen::Vector2d::Zero();
};

TerrainView load_terrain_view(const std::vector<std::string>& inputs,
                              const TerrainInputOptions& options);

// The view of a map (kind "map", no source yet): its grid and the safety layers of
// safety_radii(options.radii, the map's radii, options.foot_radius), its OctoMap as its folder
// holds it (null: none), and `info`, its terrain.json. Maps built in memory (the demo's, clouds
// mapped for a report) and maps read from a folder are drawn alike.
TerrainView map_view(std::shared_ptr<const terrain::TerrainMap> map,
                     std::shared_ptr<const octomap::OcTree> octree, nlohmann::json info,
                     const TerrainInputOptions& options);

// The radii to draw: the requested ones (or the terrain's own, or 2/4/6 cm), plus the robot's foot
// radius, sorted and without duplicates.
std::vector<double> safety_radii(const std::vector<double>& requested,
                                 const std::vector<double>& terrain_radii, double foot_radius);

}  // namespace terrastride::service::report
