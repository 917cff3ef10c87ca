// voxelise_boxes builds its OcTree top-down in its final, pruned form; it must be the very tree
// that inserting every solid voxel with OctoMap and pruning gives (the reference below): same
// nodes at the same depths, same values, same node count, hence the same FCL distances.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <tuple>
#include <vector>

#include "terrastride/collision/octree_terrain.hpp"

using namespace terrastride;
using namespace terrastride::collision;

namespace {

// The reference: OctoMap's own insertion of every voxel whose centre lies in a solid, then inner
// occupancy and pruning (what voxelise_boxes did before it built the tree directly).
std::shared_ptr<octomap::OcTree> reference_tree(double ground_z, const std::vector<terrain::Box>& boxes,
                                                const Eigen::Vector2d& lo, const Eigen::Vector2d& hi,
                                                const VoxeliseOptions& o) {
  const double res = o.resolution;
  auto range = [&](double a, double b) {
    return std::make_pair(static_cast<long>(std::ceil(a / res - 0.5)),
                          static_cast<long>(std::ceil(b / res - 0.5)) - 1);
  };
  auto tree = std::make_shared<octomap::OcTree>(res);
  const float occupied = tree->getClampingThresMaxLog();
  const auto [ix0, ix1] = range(lo.x(), hi.x());
  const auto [iy0, iy1] = range(lo.y(), hi.y());
  for (long ix = ix0; ix <= ix1; ++ix) {
    const double x = (ix + 0.5) * res;
    for (long iy = iy0; iy <= iy1; ++iy) {
      const double y = (iy + 0.5) * res;
      std::vector<std::pair<double, double>> spans;
      if (o.ground_thickness > 0) spans.emplace_back(ground_z - o.ground_thickness, ground_z);
      for (const auto& box : boxes)
        if (x >= box.lo.x() && x < box.hi.x() && y >= box.lo.y() && y < box.hi.y())
          spans.emplace_back(box.lo.z(), box.hi.z());
      for (const auto& [za, zb] : spans) {
        const auto [iz0, iz1] = range(za, zb);
        for (long iz = iz0; iz <= iz1; ++iz)
          tree->setNodeValue(octomap::point3d(x, y, (iz + 0.5) * res), occupied, true);
      }
    }
  }
  tree->updateInnerOccupancy();
  tree->prune();
  return tree;
}

// Every node (inner ones too) as (depth, key, log-odds, has children), in traversal order.
std::vector<std::tuple<unsigned, unsigned, unsigned, unsigned, float, bool>> nodes(
    const octomap::OcTree& t) {
  std::vector<std::tuple<unsigned, unsigned, unsigned, unsigned, float, bool>> out;
  for (auto it = t.begin_tree(), end = t.end_tree(); it != end; ++it) {
    const octomap::OcTreeKey k = it.getKey();
    out.emplace_back(it.getDepth(), k[0], k[1], k[2], it->getLogOdds(), t.nodeHasChildren(&*it));
  }
  return out;
}

void expect_same(const octomap::OcTree& a, const octomap::OcTree& b) {
  EXPECT_EQ(a.size(), b.size());
  EXPECT_EQ(a.getNumLeafNodes(), b.getNumLeafNodes());
  EXPECT_TRUE(nodes(a) == nodes(b));
}

}  // namespace

TEST(Voxelise, DirectTreeEqualsInsertedAndPrunedTreeOnPalletLikeBoxes) {
  const std::vector<terrain::Box> boxes = {
      {{0.30, -0.40, 0.0}, {1.10, 0.40, 0.15}},   // a pallet
      {{0.55, -0.10, 0.15}, {0.73, 0.27, 0.31}},  // something on it
      {{-0.5, 0.6, -0.2}, {-0.1, 0.9, 0.05}}};    // a block sunk in the ground
  VoxeliseOptions o;
  o.resolution = 0.01;
  const Eigen::Vector2d lo(-0.87, -0.93), hi(1.61, 1.04);
  expect_same(*voxelise_boxes(0.0, boxes, lo, hi, o), *reference_tree(0.0, boxes, lo, hi, o));
}

TEST(Voxelise, DirectTreeEqualsInsertedAndPrunedTreeOnRandomBoxes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0), size(0.01, 0.5);
  for (int trial = 0; trial < 6; ++trial) {
    std::vector<terrain::Box> boxes;
    for (int b = 0; b < 5; ++b) {
      const Eigen::Vector3d c(u(rng), u(rng), 0.2 * u(rng));
      const Eigen::Vector3d h(size(rng), size(rng), 0.5 * size(rng));
      boxes.push_back({c - h, c + h});
    }
    VoxeliseOptions o;
    o.resolution = trial % 2 ? 0.02 : 0.013;
    o.ground_thickness = trial % 3 == 0 ? 0.0 : 0.05;
    const double ground_z = 0.1 * u(rng);
    const Eigen::Vector2d lo(-1.2 + 0.1 * u(rng), -1.1), hi(1.3, 1.2 + 0.1 * u(rng));
    SCOPED_TRACE("trial " + std::to_string(trial));
    expect_same(*voxelise_boxes(ground_z, boxes, lo, hi, o),
                *reference_tree(ground_z, boxes, lo, hi, o));
  }
}

TEST(Voxelise, NothingSolidGivesAnEmptyTree) {
  VoxeliseOptions o;
  o.ground_thickness = 0.0;
  const auto t = voxelise_boxes(0.0, {}, Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 1), o);
  EXPECT_EQ(t->size(), 0u);
}
