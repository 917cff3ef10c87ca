// The solid a terrain map is certain of (octree_terrain.hpp): the second half of the leg check's
// resolution-aware verdict.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/terrain/terrain_map.hpp"

namespace terrastride::collision {

std::shared_ptr<const CertainSolid> certain_solid_from_grid(const terrain::HeightGrid& grid,
                                                            const octomap::OcTree& octree,
                                                            const Eigen::Vector2d& lo,
                                                            const Eigen::Vector2d& hi,
                                                            const CertainSolidOptions& options) {
  const terrain::GridGeometry& g = grid.geometry;
  auto out = std::make_shared<CertainSolid>();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double sigma = std::max(0.0, grid.noise_sigma);
  out->noise_depth = options.noise_factor * sigma;
  const int e = std::max(0, options.erosion_cells);
  if (g.nx <= 0 || g.ny <= 0 || grid.elevation.size() != g.size()) return out;

  // Lowest plausible true surface height per cell (NaN: nothing known there).
  auto low = [&](size_t k) {
    if (grid.observed[k] == 0) return nan;  // hole-filled: a guess, never certain
    const double med = grid.elevation[k];
    if (grid.observed[k] != 1) return med - options.noise_factor * sigma;  // interpolated
    const double s = std::max(sigma, std::sqrt(std::max(0.0, double(grid.variance[k]))));
    return std::min(double(grid.min[k]), med - options.noise_factor * s);
  };

  const double res = g.resolution;
  const int i0 = std::max(0, static_cast<int>(std::floor((lo.x() - g.origin.x()) / res)));
  const int i1 = std::min(g.nx - 1, static_cast<int>(std::floor((hi.x() - g.origin.x()) / res)));
  const int j0 = std::max(0, static_cast<int>(std::floor((lo.y() - g.origin.y()) / res)));
  const int j1 = std::min(g.ny - 1, static_cast<int>(std::floor((hi.y() - g.origin.y()) / res)));
  const double voxel = octree.getResolution();
  size_t unconfirmed = 0;
  size_t cells = 0;
  for (int i = i0; i <= i1; ++i) {
    bool run_open = false;  // the last box is a run in this column i, ending at cell run_j
    int run_j = -1;
    double run_top = 0.0, run_top_max = 0.0;
    for (int j = j0; j <= j1; ++j) {
      const size_t k = g.index(i, j);
      if (grid.observed[k] != 1) continue;
      double top = std::numeric_limits<double>::infinity();
      bool known = true;
      for (int di = -e; di <= e && known; ++di) {
        for (int dj = -e; dj <= e && known; ++dj) {
          const int a = i + di, b = j + dj;
          if (a < 0 || b < 0 || a >= g.nx || b >= g.ny) {
            known = false;
            break;
          }
          const double l = low(g.index(a, b));
          if (std::isnan(l)) known = false;
          top = std::min(top, l);
        }
      }
      if (!known) continue;
      // The OctoMap must have seen this surface too: an occupied voxel at the cell's centre within
      // one voxel of its median height.
      const Eigen::Vector2d c = g.center(i, j);
      bool confirmed = false;
      for (double dz : {0.0, -voxel, voxel}) {
        const octomap::OcTreeNode* node =
            octree.search(c.x(), c.y(), double(grid.elevation[k]) + dz);
        if (node && octree.isNodeOccupied(node)) {
          confirmed = true;
          break;
        }
      }
      if (!confirmed) {
        ++unconfirmed;
        continue;
      }
      ++cells;
      const Eigen::Vector2d a = g.origin + res * Eigen::Vector2d(i, j);
      // Runs of cells along y whose tops agree within merge_tolerance share one box at the run's
      // lowest top (lower is the safe side): far fewer boxes for FCL on flat tops and ground.
      if (run_open && run_j == j - 1 && std::abs(top - run_top) <= options.merge_tolerance &&
          std::abs(top - run_top_max) <= options.merge_tolerance) {
        terrain::Box& b = out->boxes.back();
        run_top = std::min(run_top, top);
        run_top_max = std::max(run_top_max, top);
        b.hi.y() = a.y() + res;
        b.hi.z() = run_top;
        b.lo.z() = run_top - options.depth;
        run_j = j;
        continue;
      }
      out->boxes.push_back({Eigen::Vector3d(a.x(), a.y(), top - options.depth),
                            Eigen::Vector3d(a.x() + res, a.y() + res, top)});
      run_open = true;
      run_j = j;
      run_top = run_top_max = top;
    }
  }
  std::ostringstream d;
  d << "height grid (" << res * 100 << " cm cells, surface lowered by " << options.noise_factor
    << " sigma, sigma = " << sigma * 1000 << " mm, steps eroded by " << e
    << " cell) where the OctoMap confirms it; " << cells << " cells in " << out->boxes.size()
    << " boxes";
  if (unconfirmed) d << ", " << unconfirmed << " not confirmed by a voxel";
  out->source = d.str();
  return out;
}

std::shared_ptr<const CertainSolid> certain_solid_from_scene(const terrain::Scene& scene,
                                                             const Eigen::Vector2d& lo,
                                                             const Eigen::Vector2d& hi,
                                                             const CertainSolidOptions& options) {
  auto out = std::make_shared<CertainSolid>();
  const double gz = scene.ground_z();
  out->boxes.push_back({Eigen::Vector3d(lo.x(), lo.y(), gz - options.ground_thickness),
                        Eigen::Vector3d(hi.x(), hi.y(), gz)});
  for (const auto& b : scene.boxes()) {
    terrain::Box c = b;
    c.lo.head<2>() = c.lo.head<2>().cwiseMax(lo);
    c.hi.head<2>() = c.hi.head<2>().cwiseMin(hi);
    if ((c.lo.array() < c.hi.array()).all()) out->boxes.push_back(c);
  }
  out->source =
      "exact scene " + scene.name() + " (" + std::to_string(out->boxes.size()) + " boxes)";
  return out;
}

std::shared_ptr<const CertainSolid> certain_solid_for(const terrain::HeightField& field,
                                                      const octomap::OcTree& octree,
                                                      const Eigen::Vector2d& lo,
                                                      const Eigen::Vector2d& hi,
                                                      const CertainSolidOptions& options) {
  if (const auto* scene = dynamic_cast<const terrain::Scene*>(&field))
    return certain_solid_from_scene(*scene, lo, hi, options);
  if (const auto* map = dynamic_cast<const terrain::TerrainMap*>(&field))
    return certain_solid_from_grid(map->grid(), octree, lo, hi, options);
  return nullptr;
}

}  // namespace terrastride::collision
