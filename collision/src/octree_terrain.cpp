#include "terrastride/collision/octree_terrain.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace terrastride::collision {
namespace {

std::string fmt(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// Index range [first, last] of voxels along one axis whose centres (i + 0.5) res lie in [a, b).
// OctoMap voxel i spans [i res, (i+1) res) in world coordinates, so centres are (i + 0.5) res.
std::pair<long, long> centre_range(double a, double b, double res) {
  const long first = static_cast<long>(std::ceil(a / res - 0.5));
  const long last = static_cast<long>(std::ceil(b / res - 0.5)) - 1;
  return {first, last};
}

}  // namespace

std::shared_ptr<octomap::OcTree> voxelise_boxes(double ground_z,
                                                const std::vector<terrain::Box>& boxes,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options) {
  const double res = options.resolution;
  if (!std::isfinite(res) || res < 1e-3 || res > 1.0)
    throw std::invalid_argument("voxel resolution " + fmt(res) + " m is outside [0.001, 1] m");
  if (!std::isfinite(options.ground_thickness) || options.ground_thickness < 0)
    throw std::invalid_argument("ground thickness " + fmt(options.ground_thickness) +
                                " m must be finite and >= 0");
  if (!lo.allFinite() || !hi.allFinite() || !(lo.array() < hi.array()).all())
    throw std::invalid_argument("voxelisation rectangle [" + fmt(lo.x()) + ", " + fmt(hi.x()) +
                                "] x [" + fmt(lo.y()) + ", " + fmt(hi.y()) + "] is empty");
  // A rectangle this large at this resolution would take minutes and gigabytes: refuse it.
  const double columns = (hi - lo).prod() / (res * res);
  if (columns > 5e7)
    throw std::invalid_argument("voxelisation rectangle of " + fmt((hi - lo).prod()) + " m² at " +
                                fmt(res) + " m is too large");
  for (size_t b = 0; b < boxes.size(); ++b) {
    if (!boxes[b].lo.allFinite() || !boxes[b].hi.allFinite() ||
        !(boxes[b].lo.array() < boxes[b].hi.array()).all())
      throw std::invalid_argument("box " + std::to_string(b) + " has lo >= hi or is not finite");
  }

  auto tree = std::make_shared<octomap::OcTree>(res);
  const float occupied = tree->getClampingThresMaxLog();
  const auto [ix0, ix1] = centre_range(lo.x(), hi.x(), res);
  const auto [iy0, iy1] = centre_range(lo.y(), hi.y(), res);
  std::vector<std::pair<double, double>> spans;  // solid z intervals [a, b) of one column
  for (long ix = ix0; ix <= ix1; ++ix) {
    const double x = (ix + 0.5) * res;
    for (long iy = iy0; iy <= iy1; ++iy) {
      const double y = (iy + 0.5) * res;
      spans.clear();
      if (options.ground_thickness > 0)
        spans.emplace_back(ground_z - options.ground_thickness, ground_z);
      for (const auto& box : boxes) {
        if (x >= box.lo.x() && x < box.hi.x() && y >= box.lo.y() && y < box.hi.y())
          spans.emplace_back(box.lo.z(), box.hi.z());
      }
      for (const auto& [za, zb] : spans) {
        const auto [iz0, iz1] = centre_range(za, zb, res);
        for (long iz = iz0; iz <= iz1; ++iz) {
          // Lazy: inner nodes are updated once at the end instead of on every insertion.
          tree->setNodeValue(octomap::point3d(x, y, (iz + 0.5) * res), occupied, true);
        }
      }
    }
  }
  tree->updateInnerOccupancy();
  // Merging identical children leaves big solid blocks as single nodes: smaller and faster for FCL.
  tree->prune();
  return tree;
}

std::shared_ptr<octomap::OcTree> voxelise_scene(const terrain::Scene& scene,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options) {
  return voxelise_boxes(scene.ground_z(), scene.boxes(), lo, hi, options);
}

std::shared_ptr<octomap::OcTree> read_octomap(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open the OctoMap file");
  auto tree = std::make_shared<octomap::OcTree>(0.1);
  // OctoMap announces every binary read on std::cerr ("Reading binary octree type OcTree"); our
  // commands keep stderr for their own messages, so its chatter goes nowhere while it reads.
  std::streambuf* const cerr_buffer = std::cerr.rdbuf(nullptr);
  bool read_ok = false;
  try {
    read_ok = tree->readBinary(in);
  } catch (...) {
    std::cerr.rdbuf(cerr_buffer);
    throw;
  }
  std::cerr.rdbuf(cerr_buffer);
  if (!read_ok)
    throw std::runtime_error(path + ": not a readable OctoMap binary (.bt) file");
  if (tree->size() == 0) throw std::runtime_error(path + ": the OctoMap holds no voxels");
  return tree;
}

}  // namespace terrastride::collision
