// The outlier removal of filter_cloud (batched FLANN k-NN under the PCLPointCloud2 flavour of
// PCL's StatisticalOutlierRemoval) keeps exactly the points PCL's
// StatisticalOutlierRemoval<PointXYZ> keeps with its own searcher, and its removal by cell keeps
// exactly what PCL's octree cells (OctreePointCloudPointVector) judged by that filter keep.
#include <gtest/gtest.h>

#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/octree/octree_pointcloud_pointvector.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <random>

#include "terrastride/perception/filters.hpp"

namespace terrastride::perception {
namespace {

PointCloud noisy_steps(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::normal_distribution<float> noise(0.0f, 0.004f);
  PointCloud c;
  for (size_t i = 0; i < n; ++i) {
    const float x = u(rng), y = u(rng);
    c.points.emplace_back(x, y, (x > 0.2f ? 0.15f : 0.0f) + noise(rng));
    if (i % 97 == 0) c.points.emplace_back(x, y, 0.3f + u(rng));  // stray returns above
  }
  return c;
}

std::vector<Eigen::Vector3f> pcl_sor(const PointCloud& c, int k, double stddev) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr in(new pcl::PointCloud<pcl::PointXYZ>);
  for (const auto& p : c.points) in->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
  sor.setMeanK(k);
  sor.setStddevMulThresh(stddev);
  sor.setInputCloud(in);
  pcl::PointCloud<pcl::PointXYZ> out;
  sor.filter(out);
  std::vector<Eigen::Vector3f> pts;
  for (const auto& p : out.points) pts.emplace_back(p.x, p.y, p.z);
  return pts;
}

TEST(FilterCloud, OutlierRemovalKeepsWhatPclKeeps) {
  // Sizes around and across the 4096-query blocks.
  for (const size_t n : {30u, 300u, 4096u, 4097u, 12345u}) {
    for (const int k : {1, 8, 20}) {
      SCOPED_TRACE(testing::Message() << n << " points, k " << k);
      const PointCloud c = noisy_steps(n, static_cast<unsigned>(n + k));
      CloudFilterOptions o;
      o.outlier_neighbours = k;
      o.outlier_stddev = 1.0;
      o.outlier_voxel = 0.0f;  // judge every point, as PCL's filter does
      const PointCloud out = filter_cloud(c, o);
      const auto expected = pcl_sor(c, k, 1.0);
      if (n > 300) {
        EXPECT_LT(expected.size(), c.points.size());  // it does remove something
      }
      ASSERT_EQ(out.points.size(), expected.size());
      for (size_t i = 0; i < expected.size(); ++i) ASSERT_EQ(out.points[i], expected[i]) << i;
    }
  }
}

// The removal by cell as it was written with PCL alone: the points grouped by
// OctreePointCloudPointVector, one centroid per leaf in leaf_depth_begin() order (summed in
// double in the leaf's index order), PCL's StatisticalOutlierRemoval<PointXYZ> on the centroids,
// each kept leaf's points kept in input order.
std::vector<Eigen::Vector3f> pcl_sor_by_cell(const PointCloud& c, float voxel, int k,
                                             double stddev) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr in(new pcl::PointCloud<pcl::PointXYZ>);
  for (const auto& p : c.points) in->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  pcl::octree::OctreePointCloudPointVector<pcl::PointXYZ> octree(voxel);
  octree.setInputCloud(in);
  octree.addPointsFromInputCloud();
  pcl::PointCloud<pcl::PointXYZ>::Ptr centroids(new pcl::PointCloud<pcl::PointXYZ>);
  std::vector<pcl::Indices> members;
  for (auto it = octree.leaf_depth_begin(); it != octree.leaf_depth_end(); ++it) {
    const pcl::Indices& idx = it.getLeafContainer().getPointIndicesVector();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const auto i : idx) sum += (*in)[i].getVector3fMap().cast<double>();
    const Eigen::Vector3f m = (sum / static_cast<double>(idx.size())).cast<float>();
    centroids->push_back(pcl::PointXYZ(m.x(), m.y(), m.z()));
    members.push_back(idx);
  }
  EXPECT_LE(centroids->size() * 2, in->size()) << "a sparse cloud is judged per point";
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
  sor.setMeanK(k);
  sor.setStddevMulThresh(stddev);
  sor.setInputCloud(centroids);
  pcl::Indices kept_cells;
  sor.filter(kept_cells);
  std::vector<char> keep(in->size(), 0);
  for (const auto cell : kept_cells)
    for (const auto i : members[cell]) keep[i] = 1;
  std::vector<Eigen::Vector3f> pts;
  for (size_t i = 0; i < c.points.size(); ++i)
    if (keep[i]) pts.push_back(c.points[i]);
  return pts;
}

// Dense noisy steps, points in an order that grows the octree's box in every direction (first
// point inside, then outwards), and many points on cell borders (coordinates on a 5 mm lattice).
PointCloud dense_cloud(size_t n, unsigned seed, bool lattice) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::normal_distribution<float> noise(0.0f, 0.003f);
  PointCloud c;
  c.points.emplace_back(0.013f, -0.021f, 0.004f);
  for (size_t i = 0; i < n; ++i) {
    const float r = 0.05f + 1.5f * static_cast<float>(i) / static_cast<float>(n);  // outwards
    float x = r * u(rng) + 0.4f, y = 0.5f * r * u(rng);
    if (lattice) {
      x = std::round(x * 200.0f) / 200.0f;
      y = std::round(y * 200.0f) / 200.0f;
    }
    c.points.emplace_back(x, y, (x > 0.2f ? 0.15f : 0.0f) + noise(rng));
    if (i % 211 == 0) c.points.emplace_back(x, y, 0.4f + u(rng));  // stray returns above
  }
  return c;
}

TEST(FilterCloud, OutlierRemovalByCellKeepsWhatPclOctreeCellsKeep) {
  for (const bool lattice : {false, true}) {
    for (const float voxel : {0.01f, 0.02f, 0.037f}) {
      SCOPED_TRACE(testing::Message() << "voxel " << voxel << (lattice ? ", lattice" : ""));
      const PointCloud c = dense_cloud(60000, lattice ? 7u : 8u, lattice);
      CloudFilterOptions o;
      o.outlier_neighbours = 8;
      o.outlier_stddev = 1.0;
      o.outlier_voxel = voxel;
      FilterStats stats;
      const PointCloud out = filter_cloud(c, o, &stats);
      ASSERT_GT(stats.outlier_cells, 0u) << "judged by cell";
      const auto expected = pcl_sor_by_cell(c, voxel, 8, 1.0);
      EXPECT_LT(expected.size(), c.points.size());  // it does remove something
      ASSERT_EQ(out.points.size(), expected.size());
      for (size_t i = 0; i < expected.size(); ++i) ASSERT_EQ(out.points[i], expected[i]) << i;
    }
  }
}

}  // namespace
}  // namespace terrastride::perception
