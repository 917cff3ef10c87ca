// Fusing clouds into an OctoMap occupancy tree (terrain and collision consume the tree).
#pragma once

#include <octomap/OcTree.h>
#include <memory>
#include <string>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

struct OctoMapOptions {
  double resolution = 0.02;  // voxel edge, m; must be in [0.001, 10]
  double max_range = -1;     // rays longer than this are truncated (OctoMap semantics); < 0 = off
  // Cast one ray per distinct endpoint voxel instead of one per point (OctoMap's "discretize").
  // On by default: robot scans put many points in each 2 cm voxel, and this is ~5x faster on a
  // dense 1 M-point scan (bench_perception). The occupied voxels are identical; free-space rays end
  // at voxel centres instead of the exact points.
  bool discretize = true;
};

// Builds a tree from all clouds. Clouds with a sensor origin are inserted with ray casting
// (insertPointCloud: free space carved from the origin to each hit, hit voxels occupied). Clouds
// without an origin are inserted as occupied endpoints only, without carving: with no known ray
// there is no evidence about free space, and inventing an origin would carve through real
// obstacles. Throws InputError for an absurd resolution (not within [0.001, 10] m).
std::unique_ptr<octomap::OcTree> build_octomap(const std::vector<PointCloud>& clouds,
                                               const OctoMapOptions& options);

// Inserts one cloud into an existing tree with the rules above; updates inner occupancy afterwards.
// Non-finite points are skipped; a point or origin outside the tree's addressable cube
// (resolution * 2^15 around 0) is an InputError naming the cloud.
void insert_into_octomap(octomap::OcTree& tree, const PointCloud& cloud, double max_range = -1,
                         bool discretize = true);

// Writes the tree as a binary .bt atomically (temp + rename). Throws InputError on failure.
void write_octomap(const octomap::OcTree& tree, const std::string& path);

}  // namespace terrastride::perception
