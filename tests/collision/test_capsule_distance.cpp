// capsule_octree_distance (collision/src/fcl_distance.hpp) skips octree nodes that a lower bound
// on their distance to the capsule shows cannot lower the best distance; it must return exactly
// (bit for bit) what fcl::distance returns for the same tree, capsule, pose and seed, on a
// voxelised scene (pruned blocks and single voxels) and on a map OctoMap from a real scan, for
// capsules clear of, touching and inside the voxels, with and without a seed.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

#include "../../collision/src/fcl_distance.hpp"
#include "terrastride/collision/octree_terrain.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/terrain/scenes.hpp"
#include "../perception/test_util.hpp"

using namespace terrastride;

namespace {

double fcl_distance(const fcl::OcTree<double>& tree, const fcl::Capsule<double>& capsule,
                    const fcl::Transform3d& pose, double seed) {
  fcl::DistanceRequest<double> request;
  fcl::DistanceResult<double> result;
  result.min_distance = seed;
  fcl::distance(&tree, fcl::Transform3d::Identity(), &capsule, pose, request, result);
  return result.min_distance;
}

// Random capsules (radius 1-4 cm, 2-15 cm long, any orientation) with centres in `lo`..`hi`;
// counts the queries whose distance is positive, zero or negative and below the seed.
void expect_same_as_fcl(const octomap::OcTree& octree, const Eigen::Vector3d& lo,
                        const Eigen::Vector3d& hi, unsigned seed, int queries) {
  const std::shared_ptr<const octomap::OcTree> view(std::shared_ptr<const octomap::OcTree>(),
                                                    &octree);
  const fcl::OcTree<double> tree(view);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int near = 0, touching = 0;
  for (int k = 0; k < queries; ++k) {
    const fcl::Capsule<double> capsule(0.01 + 0.03 * u(rng), 0.02 + 0.13 * u(rng));
    fcl::Transform3d pose = fcl::Transform3d::Identity();
    pose.translation() = lo + (hi - lo).cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
    pose.linear() = Eigen::Quaterniond(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5)
                        .normalized()
                        .toRotationMatrix();
    // Seeds as the leg check uses them: the cutoff, or a bound just above the distance.
    const double cutoff = 0.1;
    const double plain = fcl_distance(tree, capsule, pose, cutoff);
    ASSERT_EQ(collision::detail::capsule_octree_distance(tree, capsule, pose, cutoff), plain)
        << "query " << k;
    if (plain > 0 && plain < cutoff) {
      ++near;
      const double bound = plain + 1e-6 + 0.01 * u(rng);
      ASSERT_EQ(collision::detail::capsule_octree_distance(tree, capsule, pose, bound),
                fcl_distance(tree, capsule, pose, bound))
          << "query " << k << " seeded";
    }
    touching += plain <= 0;
  }
  EXPECT_GT(near, queries / 10) << "the queries must come near the voxels";
  EXPECT_GT(touching, queries / 50) << "and into them";
}

TEST(CapsuleOctreeDistance, SameAsFclOnAVoxelisedScene) {
  const auto scene = terrain::make_scene("pallet_15");
  const auto octree = collision::voxelise_scene(*scene, Eigen::Vector2d(-0.5, -0.8),
                                                Eigen::Vector2d(1.5, 0.8));
  expect_same_as_fcl(*octree, Eigen::Vector3d(-0.4, -0.7, -0.05), Eigen::Vector3d(1.4, 0.7, 0.3),
                     1, 1500);
}

TEST(CapsuleOctreeDistance, SameAsFclOnAScannedMap) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  const auto cloud = perception::read_cloud(
      perception::test::scan("anybotics_samples/grid_map_pcl_input_cloud.pcd"));
  perception::OctoMapOptions o;
  o.resolution = 0.02;
  const auto octree = perception::build_octomap({cloud}, o);
  // Capsules over the scanned patch (the OctoMap also holds the free space its rays crossed).
  Eigen::Vector3f lo = cloud.points.front(), hi = lo;
  for (const auto& p : cloud.points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  expect_same_as_fcl(*octree, lo.cast<double>() - Eigen::Vector3d(0, 0, 0.02),
                     hi.cast<double>() + Eigen::Vector3d(0, 0, 0.06), 2, 1500);
}

}  // namespace
