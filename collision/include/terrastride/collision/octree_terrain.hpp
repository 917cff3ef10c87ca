// The occupancy map the post-hoc leg-collision check runs against (docs/design.md §8.3).
//
// A mapped terrain brings the OctoMap of its scan (DIR/octomap.bt): the check uses the voxels that
// were actually observed, not the smoothed height field, so smoothing cannot hide a real edge. An
// analytic scene has no scan, so its boxes and ground are voxelised into an OcTree and the very
// same FCL check runs on it.
#pragma once

#include <octomap/OcTree.h>
#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "terrastride/terrain/height_field.hpp"
#include "terrastride/terrain/height_grid.hpp"
#include "terrastride/terrain/scenes.hpp"

namespace terrastride::collision {

struct VoxeliseOptions {
  double resolution = 0.01;  // voxel edge (m); scene surfaces are exact to half of it
  // How deep below ground_z the ground slab is filled (m). A few voxels suffice: a leg is a chain
  // hanging from a hip above the ground, so any part of it below the surface crosses the slab.
  double ground_thickness = 0.05;
};

// Occupancy tree of solid boxes on a ground plane, restricted to the xy rectangle [lo, hi] (boxes
// are clipped to it). A voxel is occupied when its centre lies inside the ground slab [ground_z -
// ground_thickness, ground_z) or inside a box. Solids are filled, not just their skins, so a
// capsule buried inside a box still collides. Throws std::invalid_argument for a bad resolution, an
// empty rectangle or an inverted box.
std::shared_ptr<octomap::OcTree> voxelise_boxes(double ground_z,
                                                const std::vector<terrain::Box>& boxes,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options = {});

// Same for a scene (its ground plane and boxes) over [lo, hi].
std::shared_ptr<octomap::OcTree> voxelise_scene(const terrain::Scene& scene,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options = {});

// ---- What the map is certain of (the resolution-aware verdict of the leg check) ----
//
// An occupied voxel only says that some surface point lies somewhere inside it: a scanned top
// surface's voxels stand up to one voxel above the true surface, and mixed pixels at edges add
// voxels in free air. Touching an occupied voxel is therefore not a collision at the map's
// resolution, only a possible one. The check also asks a second question: does the capsule reach
// into solid the map is *certain* of? That solid is a set of axis-aligned boxes, built from a
// finer, point-based estimate of the surface than the voxels:
//  - a scanned map: the height grid of the same cleaned points (DIR/layers, default 2 cm cells).
//    A cell contributes the column below a lower bound of the true surface there: the minimum,
//    over the cell and its 8 neighbours, of each cell's lowest plausible surface height
//    (min(lowest support point, median - noise_factor * max(sigma_grid, sigma_cell))). Taking the
//    neighbourhood minimum erodes steps by one cell, because a cell whose median says "top" may be
//    cut by an edge anywhere inside it. Only cells measured themselves (observed = 1) with all 8
//    neighbours measured or interpolated contribute, and only where the OctoMap confirms the
//    surface (an occupied voxel at the cell's centre within one voxel of its median height):
//    hole-filled cells, overhangs the grid sees beneath, and voxels in free air are never certain.
//  - an analytic scene: its exact boxes and a ground slab.
// The true clearance lies between the distance to the occupied voxels (a lower bound: every
// measured point lies inside one) and the distance to the certain solid (an upper bound up to the
// noise allowance).
struct CertainSolid {
  std::vector<terrain::Box> boxes;
  std::string source;  // how it was made, for reports
  // How far above the true surface the map's sensor noise alone puts occupied voxels
  // (noise_factor sigma of the map it was made from; 0 for exact scenes): a body that deep into
  // voxels but clear of the solid touches noise, not the terrain (detail::deep_contact_depth).
  double noise_depth = 0.0;
};

struct CertainSolidOptions {
  double noise_factor = 3.0;      // sensor noise allowance below a cell's median, in sigmas
  int erosion_cells = 1;          // neighbourhood radius of the minimum (cells)
  double depth = 0.2;             // how far below its top a cell's column of solid reaches (m)
  double ground_thickness = 0.2;  // scenes: thickness of the ground slab (m)
  // Neighbouring cells (along y) whose tops differ by at most this share one box at the lower
  // top: a slightly smaller certain solid, far fewer boxes (m).
  double merge_tolerance = 0.002;
};

// Certain solid of a scanned map over the xy rectangle [lo, hi] (see above).
std::shared_ptr<const CertainSolid> certain_solid_from_grid(
    const terrain::HeightGrid& grid, const octomap::OcTree& octree, const Eigen::Vector2d& lo,
    const Eigen::Vector2d& hi, const CertainSolidOptions& options = {});

// Certain solid of an exact scene over [lo, hi]: its boxes (clipped) and the ground slab.
std::shared_ptr<const CertainSolid> certain_solid_from_scene(
    const terrain::Scene& scene, const Eigen::Vector2d& lo, const Eigen::Vector2d& hi,
    const CertainSolidOptions& options = {});

// The certain solid for a check terrain: a terrain::Scene gives its exact boxes, a
// terrain::TerrainMap its height grid confirmed by `octree`; any other field gives null (the check
// then counts every voxel contact as a collision, as before).
std::shared_ptr<const CertainSolid> certain_solid_for(const terrain::HeightField& field,
                                                      const octomap::OcTree& octree,
                                                      const Eigen::Vector2d& lo,
                                                      const Eigen::Vector2d& hi,
                                                      const CertainSolidOptions& options = {});

// Reads an OctoMap binary (.bt) file. Throws std::runtime_error naming the path when it cannot be
// read or holds no tree.
std::shared_ptr<octomap::OcTree> read_octomap(const std::string& path);

}  // namespace terrastride::collision
