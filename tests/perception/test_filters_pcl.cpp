// The outlier removal of filter_cloud (batched FLANN k-NN under the PCLPointCloud2 flavour of
// PCL's StatisticalOutlierRemoval) keeps exactly the points PCL's
// StatisticalOutlierRemoval<PointXYZ> keeps with its own searcher.
#include <gtest/gtest.h>

#include <pcl/filters/statistical_outlier_removal.h>
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

}  // namespace
}  // namespace terrastride::perception
