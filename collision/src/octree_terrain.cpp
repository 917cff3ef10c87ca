#include "terrastride/collision/octree_terrain.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "terrastride/perception/octomap_input.hpp"

namespace terrastride::collision {
namespace {

std::string shortest(double v) {
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

// One column of solid voxels: its x and y keys and its runs [first, last] of occupied z keys.
struct SolidColumn {
  int kx, ky;
  std::vector<std::pair<int, int>> runs;
};

// An OcTree built directly in its final form. Setting every solid voxel as a leaf (setNodeValue,
// lazily), then updateInnerOccupancy() and prune() gave this very tree: every node that exists is
// occupied (leaves at the clamping maximum, inner nodes the maximum of their children), and prune
// turns every cube whose voxels are all solid into one leaf (the root excepted), bottom-up until a
// level collapses nothing. Built top-down instead, a cube that is all solid becomes a leaf without
// its voxels ever being created: on a pallet scene most of the voxels lie in such cubes, and the
// per-voxel insertions and the pruning cost about a tenth of a `plan` process (one descent of 16
// levels per voxel). Same nodes, same values, same node count (tests/collision compares the two).
class SolidTree : public octomap::OcTree {
 public:
  using octomap::OcTree::OcTree;

  void fill(std::vector<SolidColumn> columns, float value) {
    if (columns.empty()) return;
    columns_ = std::move(columns);
    kx0_ = ky0_ = std::numeric_limits<int>::max();
    int kx1 = std::numeric_limits<int>::min(), ky1 = kx1;
    for (const auto& c : columns_) {
      kx0_ = std::min(kx0_, c.kx);
      ky0_ = std::min(ky0_, c.ky);
      kx1 = std::max(kx1, c.kx);
      ky1 = std::max(ky1, c.ky);
    }
    nx_ = kx1 - kx0_ + 1;
    ny_ = ky1 - ky0_ + 1;
    index_.assign(static_cast<size_t>(nx_) * ny_, -1);
    for (size_t i = 0; i < columns_.size(); ++i)
      index_[static_cast<size_t>(columns_[i].kx - kx0_) * ny_ + (columns_[i].ky - ky0_)] =
          static_cast<int>(i);
    value_ = value;
    root = new octomap::OcTreeNode();
    ++tree_size;
    size_changed = true;
    root->setLogOdds(value_);
    build(root, 0, 0, 0, 0);
    columns_.clear();
    index_.clear();
  }

 private:
  enum class Fill { empty, partial, full };

  // Children of the node at `depth` whose cube starts at keys (kx, ky, kz): one per non-empty
  // octant (OctoMap's child order: bit 0 x, bit 1 y, bit 2 z); all-solid octants below the root
  // stay leaves, the others are built further.
  void build(octomap::OcTreeNode* node, unsigned depth, int kx, int ky, int kz) {
    const int half = 1 << (tree_depth - depth - 1);
    for (unsigned i = 0; i < 8; ++i) {
      const int cx = kx + ((i & 1) ? half : 0), cy = ky + ((i & 2) ? half : 0),
                cz = kz + ((i & 4) ? half : 0);
      const Fill f = classify(cx, cy, cz, half);
      if (f == Fill::empty) continue;
      octomap::OcTreeNode* child = createNodeChild(node, i);
      child->setLogOdds(value_);
      if (f == Fill::partial) build(child, depth + 1, cx, cy, cz);
    }
  }

  Fill classify(int kx, int ky, int kz, int size) const {
    const int ax = std::max(kx, kx0_), bx = std::min(kx + size, kx0_ + nx_);
    const int ay = std::max(ky, ky0_), by = std::min(ky + size, ky0_ + ny_);
    if (ax >= bx || ay >= by) return Fill::empty;
    bool any = false;
    // Columns of the cube outside the solid's key rectangle are empty.
    bool all = ax == kx && bx == kx + size && ay == ky && by == ky + size;
    const int z1 = kz + size - 1;
    for (int x = ax; x < bx; ++x) {
      for (int y = ay; y < by; ++y) {
        const int c = index_[static_cast<size_t>(x - kx0_) * ny_ + (y - ky0_)];
        bool covered = false, touched = false;
        if (c >= 0) {
          for (const auto& [first, last] : columns_[c].runs) {
            if (last < kz || first > z1) continue;
            touched = true;
            if (first <= kz && last >= z1) covered = true;
            // Runs are disjoint and not adjacent: if this first run to meet the cube's z range
            // does not cover it, the cube is not all solid, whatever the others do.
            break;
          }
        }
        any = any || touched;
        all = all && covered;
        if (any && !all) return Fill::partial;
      }
    }
    return all ? Fill::full : (any ? Fill::partial : Fill::empty);
  }

  std::vector<SolidColumn> columns_;
  std::vector<int> index_;  // column index by (kx - kx0_) * ny_ + (ky - ky0_), -1 none
  int kx0_ = 0, ky0_ = 0, nx_ = 0, ny_ = 0;
  float value_ = 0.0f;
};

}  // namespace

std::shared_ptr<octomap::OcTree> voxelise_boxes(double ground_z,
                                                const std::vector<terrain::Box>& boxes,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options) {
  const double res = options.resolution;
  if (!std::isfinite(res) || res < 1e-3 || res > 1.0)
    throw std::invalid_argument("voxel resolution " + shortest(res) + " m is outside [0.001, 1] m");
  if (!std::isfinite(options.ground_thickness) || options.ground_thickness < 0)
    throw std::invalid_argument("ground thickness " + shortest(options.ground_thickness) +
                                " m must be finite and >= 0");
  if (!lo.allFinite() || !hi.allFinite() || !(lo.array() < hi.array()).all())
    throw std::invalid_argument("voxelisation rectangle [" + shortest(lo.x()) + ", " + shortest(hi.x()) +
                                "] x [" + shortest(lo.y()) + ", " + shortest(hi.y()) + "] is empty");
  // A rectangle this large at this resolution would take minutes and gigabytes: refuse it.
  const double columns = (hi - lo).prod() / (res * res);
  if (columns > 5e7)
    throw std::invalid_argument("voxelisation rectangle of " + shortest((hi - lo).prod()) + " m² at " +
                                shortest(res) + " m is too large");
  for (size_t b = 0; b < boxes.size(); ++b) {
    if (!boxes[b].lo.allFinite() || !boxes[b].hi.allFinite() ||
        !(boxes[b].lo.array() < boxes[b].hi.array()).all())
      throw std::invalid_argument("box " + std::to_string(b) + " has lo >= hi or is not finite");
  }

  // The occupied voxels' keys, column by column (keys as OctoMap's setNodeValue(point3d) computes
  // them, out-of-range points skipped as it skips them).
  SolidTree* tree = new SolidTree(res);
  std::shared_ptr<octomap::OcTree> owner(tree);
  const float occupied = tree->getClampingThresMaxLog();
  const auto [ix0, ix1] = centre_range(lo.x(), hi.x(), res);
  const auto [iy0, iy1] = centre_range(lo.y(), hi.y(), res);
  std::vector<std::pair<double, double>> spans;  // solid z intervals [a, b) of one column
  std::vector<SolidColumn> solid_columns;
  std::vector<int> z_keys;
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
      z_keys.clear();
      int kx = -1, ky = -1;
      for (const auto& [za, zb] : spans) {
        const auto [iz0, iz1] = centre_range(za, zb, res);
        for (long iz = iz0; iz <= iz1; ++iz) {
          octomap::OcTreeKey key;
          if (!tree->coordToKeyChecked(octomap::point3d(x, y, (iz + 0.5) * res), key)) continue;
          kx = key[0];
          ky = key[1];
          z_keys.push_back(key[2]);
        }
      }
      if (z_keys.empty()) continue;
      std::sort(z_keys.begin(), z_keys.end());
      SolidColumn column{kx, ky, {}};
      for (const int kz : z_keys) {
        if (!column.runs.empty() && kz <= column.runs.back().second + 1)
          column.runs.back().second = std::max(column.runs.back().second, kz);
        else
          column.runs.emplace_back(kz, kz);
      }
      solid_columns.push_back(std::move(column));
    }
  }
  tree->fill(std::move(solid_columns), occupied);
  return owner;
}

std::shared_ptr<octomap::OcTree> voxelise_scene(const terrain::Scene& scene,
                                                const Eigen::Vector2d& lo,
                                                const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& options) {
  return voxelise_boxes(scene.ground_z(), scene.boxes(), lo, hi, options);
}

std::shared_ptr<octomap::OcTree> read_octomap(const std::string& path) {
  // perception's reader walks the body before OctoMap reads it: a corrupt octomap.bt in a terrain
  // folder is an error naming it, not a stack overflow in OctoMap's recursive reader. It also
  // prints nothing (OctoMap's file readers announce every read on std::cerr).
  return perception::read_octomap_file(path);
}

}  // namespace terrastride::collision
