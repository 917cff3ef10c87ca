// OctoMap fusion: free space is carved along rays from the sensor origin, hits are occupied.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iterator>
#include <sstream>

#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "test_util.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;
using test::scan;
using test::ScratchDir;

// Node state at a point: 1 occupied, 0 free, -1 unknown.
int state(const octomap::OcTree& tree, const Eigen::Vector3d& p) {
  const octomap::OcTreeNode* n = tree.search(p.x(), p.y(), p.z());
  if (n == nullptr) return -1;
  return tree.isNodeOccupied(n) ? 1 : 0;
}

// A 1 m x 1 m patch of floor at z = 0 seen from 1.5 m above.
PointCloud floor_patch(bool with_origin) {
  PointCloud c;
  c.source = "floor";
  for (int i = 0; i < 50; ++i) {
    for (int j = 0; j < 50; ++j)
      c.points.emplace_back(-0.5f + 0.02f * i + 0.01f, -0.5f + 0.02f * j + 0.01f, 0.001f);
  }
  if (with_origin) c.sensor_origin = Eigen::Vector3d(0, 0, 1.5);
  return c;
}

TEST(OctoMap, RaysCarveFreeSpaceAndHitsAreOccupied) {
  OctoMapOptions o;
  o.discretize = false;  // one ray per point, OctoMap's exact semantics
  const auto tree = build_octomap({floor_patch(true)}, o);
  EXPECT_DOUBLE_EQ(tree->getResolution(), 0.02);
  const Eigen::Vector3d origin(0, 0, 1.5);
  const Eigen::Vector3d hit(0.31, -0.19, 0.001);
  EXPECT_EQ(state(*tree, hit), 1);
  // Voxels along the ray from the origin to that hit are free.
  for (double t : {0.1, 0.4, 0.7, 0.9}) {
    SCOPED_TRACE(t);
    EXPECT_EQ(state(*tree, origin + t * (hit - origin)), 0);
  }
  // Beyond the hit (under the floor) and off to the side nothing was observed.
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0.31, -0.19, -0.1)), -1);
  EXPECT_EQ(state(*tree, Eigen::Vector3d(3, 3, 1)), -1);
}

TEST(OctoMap, DiscretizedInsertionAgreesOnOccupiedVoxels) {
  OctoMapOptions exact;
  exact.discretize = false;
  const auto a = build_octomap({floor_patch(true)}, exact);
  const auto b = build_octomap({floor_patch(true)}, {});  // discretized by default
  EXPECT_EQ(state(*b, Eigen::Vector3d(0.15, -0.1, 0.75)), 0);
  size_t occupied = 0;
  for (auto it = a->begin_leafs(); it != a->end_leafs(); ++it) {
    if (!a->isNodeOccupied(*it)) continue;
    ++occupied;
    const octomap::OcTreeNode* n = b->search(it.getKey());
    ASSERT_NE(n, nullptr);
    EXPECT_TRUE(b->isNodeOccupied(n));
  }
  EXPECT_GE(occupied, 2500u);  // every one of the 50 x 50 floor points has its own voxel
}

TEST(OctoMap, WithoutOriginOnlyEndpointsAreMarked) {
  const auto tree = build_octomap({floor_patch(false)}, {});
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0.31, -0.19, 0.001)), 1);
  // No ray, no free space: above the floor stays unknown.
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0.15, -0.1, 0.75)), -1);
  size_t free_leaves = 0;
  for (auto it = tree->begin_leafs(); it != tree->end_leafs(); ++it) {
    free_leaves += !tree->isNodeOccupied(*it);
  }
  EXPECT_EQ(free_leaves, 0u);
}

TEST(OctoMap, MaxRangeTruncatesRays) {
  OctoMapOptions o;
  o.max_range = 1.0;  // the floor is 1.5 m away: rays end in free space, no hits
  const auto tree = build_octomap({floor_patch(true)}, o);
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0, 0, 1.0)), 0);
  EXPECT_NE(state(*tree, Eigen::Vector3d(0.31, -0.19, 0.001)), 1);
}

TEST(OctoMap, SeveralCloudsFuseAndLaterFreeEvidenceClearsStaleHits) {
  // An obstacle seen once at z = 0.5 ...
  PointCloud first;
  first.source = "first";
  first.sensor_origin = Eigen::Vector3d(0, 0, 1.5);
  first.points = {{0.01f, 0.01f, 0.51f}};
  // ... then repeatedly seen through by rays to the floor behind it.
  std::vector<PointCloud> clouds = {first};
  for (int k = 0; k < 5; ++k) clouds.push_back(floor_patch(true));
  const auto tree = build_octomap(clouds, {});
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0.01, 0.01, 0.51)), 0);
  EXPECT_EQ(state(*tree, Eigen::Vector3d(0.01, 0.01, 0.001)), 1);
}

TEST(OctoMap, RealScanFromOrigin) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  PointCloud c = read_cloud(scan("octomap/scan.xyz"), Eigen::Vector3d::Zero());
  OctoMapOptions o;
  o.resolution = 0.2;
  o.discretize = true;
  const auto tree = build_octomap({c}, o);
  EXPECT_GT(tree->getNumLeafNodes(), 1000u);
  // Halfway to a scan point is free; the point itself (about 4.9 m away) is occupied.
  EXPECT_EQ(state(*tree, 0.5 * c.points[0].cast<double>()), 0);
  EXPECT_EQ(state(*tree, c.points[0].cast<double>()), 1);
}

TEST(OctoMap, WriteBinaryRoundTrip) {
  ScratchDir dir;
  const auto tree = build_octomap({floor_patch(true)}, {});
  write_octomap(*tree, dir.file("octomap.bt"));
  octomap::OcTree back(dir.file("octomap.bt"));
  EXPECT_DOUBLE_EQ(back.getResolution(), 0.02);
  EXPECT_EQ(back.size(), tree->size());
  EXPECT_EQ(state(back, Eigen::Vector3d(0.31, -0.19, 0.001)), 1);
}

// write_octomap writes exactly the bytes of OctoMap's own writeBinaryConst, without the
// "Writing N nodes to output stream... done." the Debian library prints to stderr.
TEST(OctoMap, WriteBinaryMatchesOctoMapBytesAndIsQuiet) {
  TERRASTRIDE_REQUIRE_SHARED_SCANS();
  ScratchDir dir;
  PointCloud c = read_cloud(scan("octomap/scan.xyz"), Eigen::Vector3d::Zero());
  OctoMapOptions o;
  o.resolution = 0.2;
  const auto tree = build_octomap({c}, o);
  testing::internal::CaptureStderr();
  write_octomap(*tree, dir.file("octomap.bt"));
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  std::ostringstream want(std::ios::binary);
  testing::internal::CaptureStderr();  // the library's own writer is the noisy one
  ASSERT_TRUE(tree->writeBinaryConst(want));
  testing::internal::GetCapturedStderr();
  std::ifstream in(dir.file("octomap.bt"), std::ios::binary);
  const std::string got((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_GT(got.size(), 1000u);
  EXPECT_TRUE(got == want.str()) << got.size() << " vs " << want.str().size() << " bytes";
  // An empty tree too.
  octomap::OcTree empty(0.05);
  write_octomap(empty, dir.file("empty.bt"));
  std::ostringstream want_empty(std::ios::binary);
  testing::internal::CaptureStderr();
  ASSERT_TRUE(empty.writeBinaryConst(want_empty));
  testing::internal::GetCapturedStderr();
  std::ifstream in_empty(dir.file("empty.bt"), std::ios::binary);
  EXPECT_EQ(
      std::string((std::istreambuf_iterator<char>(in_empty)), std::istreambuf_iterator<char>()),
      want_empty.str());
}

TEST(OctoMap, BadInput) {
  for (double r : {0.0, -0.02, 1e-9, 100.0, std::nan("")}) {
    OctoMapOptions o;
    o.resolution = r;
    expect_input_error([&] { build_octomap({floor_patch(true)}, o); }, {"resolution"});
  }
  PointCloud far = floor_patch(true);
  far.source = "far.pcd";
  far.points.emplace_back(1e4f, 0.0f, 0.0f);  // beyond +-655 m at 2 cm
  expect_input_error([&] { build_octomap({far}, {}); }, {"far.pcd", "outside"});
  PointCloud bad_origin = floor_patch(true);
  bad_origin.sensor_origin = Eigen::Vector3d(0, std::nan(""), 0);
  expect_input_error([&] { build_octomap({bad_origin}, {}); }, {"floor", "origin"});
}

}  // namespace
}  // namespace terrastride::perception
