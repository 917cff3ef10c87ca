#include "report/terrain_input.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/point_cloud.hpp"
#include "terrastride/service/cli.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "terrastride/terrain/terrain_open.hpp"

namespace terrastride::service::report {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

void fill_from_map(TerrainView& view, std::shared_ptr<const terrain::TerrainMap> map,
                   const std::vector<double>& radii) {
  const terrain::HeightGrid& grid = map->grid();
  view.origin = grid.geometry.origin;
  view.resolution = grid.geometry.resolution;
  view.nx = grid.geometry.nx;
  view.ny = grid.geometry.ny;
  const size_t cells = grid.geometry.size();
  view.height.assign(cells, std::numeric_limits<float>::quiet_NaN());
  view.observed = grid.observed;
  // Unobserved cells hold conservatively filled heights in the map; the report shows them as
  // unknown (a gap), not as ground that was seen.
  for (size_t k = 0; k < cells; ++k)
    if (grid.observed[k]) view.height[k] = grid.elevation[k];
  view.overhead = grid.overhead;
  view.unreachable_cells = map->levels().unreachable_cells;
  view.radii = radii;
  view.margin.clear();
  view.safe_fraction.clear();
  for (double r : radii) {
    view.margin.push_back(map->layer(r).margin);
    view.safe_fraction.push_back(map->layer(r).safe_fraction());
  }
  view.field = map;
}

}  // namespace

std::vector<double> safety_radii(const std::vector<double>& requested,
                                 const std::vector<double>& terrain_radii, double foot_radius) {
  std::vector<double> radii = requested;
  if (radii.empty()) radii = terrain_radii;
  if (radii.empty()) radii = {0.02, 0.04, 0.06};
  radii.push_back(foot_radius);
  for (double r : radii)
    if (!(r > 0.0) || r > 1.0 || !std::isfinite(r))
      throw CommandError("--foot-radius: " + std::to_string(r) + " is not a radius in (0, 1] m");
  std::sort(radii.begin(), radii.end());
  std::vector<double> out;
  for (double r : radii)
    if (out.empty() || std::abs(out.back() - r) > 1e-9) out.push_back(r);
  return out;
}

void rasterize_field(TerrainView& view, const terrain::HeightField& field,
                     const std::vector<double>& radii) {
  const size_t cells = static_cast<size_t>(view.nx) * view.ny;
  view.height.assign(cells, std::numeric_limits<float>::quiet_NaN());
  view.observed.assign(cells, 0);
  view.overhead.clear();
  view.radii = radii;
  view.margin.assign(radii.size(),
                     std::vector<float>(cells, std::numeric_limits<float>::quiet_NaN()));
  for (int i = 0; i < view.nx; ++i) {
    for (int j = 0; j < view.ny; ++j) {
      const Eigen::Vector2d c = view.center(i, j);
      const size_t k = view.index(i, j);
      view.height[k] = static_cast<float>(field.height(c.x(), c.y()));
      view.observed[k] = field.observed(c.x(), c.y()) ? 1 : 0;
      const double overhead = field.overhead(c.x(), c.y());
      if (std::isfinite(overhead)) {
        if (view.overhead.empty())
          view.overhead.assign(cells, std::numeric_limits<float>::infinity());
        view.overhead[k] = static_cast<float>(overhead);
      }
      for (size_t r = 0; r < radii.size(); ++r)
        view.margin[r][k] = static_cast<float>(field.safety_margin(c.x(), c.y(), radii[r]).margin);
    }
  }
}

TerrainView load_terrain_view(const std::vector<std::string>& inputs,
                              const TerrainInputOptions& options) {
  if (inputs.empty()) throw CommandError("--terrain: no terrain given");
  const auto t0 = Clock::now();
  // The one opening of a terrain (terrain::open_terrain); clouds are mapped in memory as
  // `terrastride map` maps them (its defaults, this report's --resolution and --origin) and
  // described as that folder's terrain.json would describe them.
  terrain::TerrainOpenOptions open;
  open.clouds = true;
  open.cloud_resolution = options.resolution;
  open.cloud_origin = options.origin;
  terrain::OpenedTerrain opened;
  try {
    opened = terrain::open_terrain(inputs, open);
  } catch (const terrain::TerrainOpenError& e) {
    if (e.grid_options()) throw CommandError("--resolution/--foot-radius: " + std::string(e.what()));
    if (e.input().empty()) throw CommandError(e.what());
    throw CommandError(std::string("--terrain ") + e.what());
  }
  TerrainView view;
  if (opened.kind == "scene") {
    const terrain::Scene& scene = *opened.scene;
    view.kind = "scene";
    view.resolution = options.resolution;
    view.origin = scene.min_corner();
    const Eigen::Vector2d size = scene.max_corner() - scene.min_corner();
    view.nx = std::max(1, static_cast<int>(std::ceil(size.x() / options.resolution - 1e-9)));
    view.ny = std::max(1, static_cast<int>(std::ceil(size.y() / options.resolution - 1e-9)));
    rasterize_field(view, scene, safety_radii(options.radii, {}, options.foot_radius));
    view.field = opened.scene;
    view.info = opened.info;
    view.info["note"] = "exact analytic terrain: heights and safety margins are exact, sharp edges";
    if (options.voxelise_scene && (options.voxel_hi - options.voxel_lo).minCoeff() > 0) {
      view.octree = collision::voxelise_scene(scene, options.voxel_lo, options.voxel_hi);
      view.info["octomap"] = "voxelised from the scene's boxes (no scan)";
    }
  } else {
    view = map_view(opened.map, opened.octree, std::move(opened.info), options);
    // "map" (a folder), "octomap" or "clouds": what the page says the terrain came from.
    view.kind = opened.kind;
  }
  view.source = opened.spec;
  view.build_s = std::chrono::duration<double>(Clock::now() - t0).count();
  return view;
}

TerrainView map_view(std::shared_ptr<const terrain::TerrainMap> map,
                     std::shared_ptr<const octomap::OcTree> octree, nlohmann::json info,
                     const TerrainInputOptions& options) {
  TerrainView view;
  view.kind = "map";
  fill_from_map(view, map, safety_radii(options.radii, map->radii(), options.foot_radius));
  view.octree = std::move(octree);
  view.info = std::move(info);
  return view;
}

}  // namespace terrastride::service::report
