// The occupancy map the post-hoc leg-collision check runs against (DESIGN.md, Post-hoc checks).
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

// Reads an OctoMap binary (.bt) file. Throws std::runtime_error naming the path when it cannot be
// read or holds no tree.
std::shared_ptr<octomap::OcTree> read_octomap(const std::string& path);

}  // namespace terrastride::collision
