// The PCL half of filter_cloud (filters.cpp): crop box, voxel grid and statistical outlier removal
// with PCL's filters. Built into the PCL module (pcl_module.hpp) with pcl_io.cpp, so that a process
// loads PCL (and the VTK libraries PCL's io pulls in) only when it filters or reads a PCD/PLY cloud.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>
#include <pcl/filters/crop_box.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/octree/octree_pointcloud_pointvector.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/search/flann_search.h>

#include "pcl_module.hpp"

namespace terrastride::perception::detail {
namespace {

// The k-NN search behind the statistical outlier removal, in batches. SOR asks its searcher for
// the neighbours of every point, one point at a time; through PCL's default searcher
// (KdTreeFLANN) each such query costs a few allocations and one OpenMP parallel region around
// FLANN's search (two futex system calls a query with libgomp), about half of SOR's time. This
// searcher is the same exact FLANN kd-tree (KDTreeSingleIndex, 15 points a leaf, L2_Simple, eps 0:
// what KdTreeFLANN builds) and, when asked for point i, runs FLANN's batched k-NN once for the
// 4096 points from i on and answers the following queries from that block. Same neighbours, same
// distances, hence the same points kept.
class BlockedKnnSearch : public pcl::search::FlannSearch<pcl::PointXYZ> {
  using Base = pcl::search::FlannSearch<pcl::PointXYZ>;

 public:
  static constexpr size_t kBlock = 4096;

  explicit BlockedKnnSearch(int k)
      : Base(/*sorted=*/false, Base::FlannIndexCreatorPtr(new Base::KdTreeIndexCreator(15))),
        k_(k) {
    // As FlannSearch's own queries: exact search (eps 0), unsorted results as SOR asks.
    params_.eps = getEpsilon();
    params_.sorted = getSortedResults();
    params_.checks = getChecks();
  }

  void setInputCloud(const PointCloudConstPtr& cloud,
                     const pcl::IndicesConstPtr& indices = pcl::IndicesConstPtr()) override {
    Base::setInputCloud(cloud, indices);
    first_ = rows_ = 0;
  }

  using Base::nearestKSearch;
  int nearestKSearch(pcl::index_t index, int k, pcl::Indices& k_indices,
                     std::vector<float>& k_sqr_distances) const override {
    const auto& input = getInputCloud();
    const size_t n = input ? input->size() : 0;
    const auto i = static_cast<size_t>(index);
    // Only the plain case is blocked: whole dense cloud, the k it was made for, k <= points.
    if (k != k_ || getIndices() || !input->is_dense || i >= n || n < static_cast<size_t>(k)) {
      return Base::nearestKSearch(index, k, k_indices, k_sqr_distances);
    }
    if (i < first_ || i >= first_ + rows_) {
      first_ = i;
      rows_ = std::min(kBlock, n - i);
      ids_.resize(rows_ * k);
      sqr_.resize(rows_ * k);
      // PointXYZ is x, y, z and padding: a 3-column matrix with a 16-byte stride.
      const flann::Matrix<float> queries(const_cast<float*>(&(*input)[i].x), rows_, 3,
                                         sizeof(pcl::PointXYZ));
      flann::Matrix<size_t> ids(ids_.data(), rows_, k);
      flann::Matrix<float> sqr(sqr_.data(), rows_, k);
      index_->knnSearch(queries, ids, sqr, k, params_);
    }
    const size_t row = (i - first_) * k;
    k_indices.resize(k);
    k_sqr_distances.resize(k);
    for (int j = 0; j < k; ++j) {
      k_indices[j] = static_cast<pcl::index_t>(ids_[row + j]);
      k_sqr_distances[j] = sqr_[row + j];
    }
    return k;
  }

 private:
  int k_;
  flann::SearchParams params_;
  mutable size_t first_ = 0, rows_ = 0;
  mutable std::vector<size_t> ids_;
  mutable std::vector<float> sqr_;
};

// PCL's statistical outlier removal on the searcher above, returning the indices of the points
// kept. The PCLPointCloud2 flavour of pcl::StatisticalOutlierRemoval is used because its searcher
// (tree_) is open to subclasses; its meanK counts the point itself (hence k + 1), and it computes
// the same mean neighbour distances, mean, stddev and threshold as the PointXYZ flavour.
pcl::Indices remove_statistical_outliers(const pcl::PointCloud<pcl::PointXYZ>& cloud, int k,
                                         double stddev) {
  if (cloud.size() <= static_cast<size_t>(k)) {  // fewer points than neighbours: PCL's own SOR
    pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
    sor.setMeanK(k);
    sor.setStddevMulThresh(stddev);
    sor.setInputCloud(cloud.makeShared());
    pcl::Indices kept;
    sor.filter(kept);
    return kept;
  }
  struct Sor : pcl::StatisticalOutlierRemoval<pcl::PCLPointCloud2> {
    Sor(int k, double stddev) {
      setMeanK(k + 1);
      setStddevMulThresh(stddev);
      tree_.reset(new BlockedKnnSearch(k + 1));
    }
  } sor(k, stddev);
  pcl::PCLPointCloud2::Ptr blob(new pcl::PCLPointCloud2);
  pcl::toPCLPointCloud2(cloud, *blob);
  sor.setInputCloud(blob);
  // PCL 1.13's StatisticalOutlierRemoval<PCLPointCloud2>::applyFilter(Indices&) writes the kept
  // indices into the vector without sizing it first (it only shrinks it at the end): size it to
  // the largest possible result.
  pcl::Indices kept(cloud.size());
  sor.filter(kept);
  return kept;
}

// The bounding box of a PCL cloud.
void bounds(const pcl::PointCloud<pcl::PointXYZ>& cloud, Eigen::Vector3f* lo, Eigen::Vector3f* hi) {
  *lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  *hi = -*lo;
  for (const auto& p : cloud.points) {
    *lo = lo->cwiseMin(p.getVector3fMap());
    *hi = hi->cwiseMax(p.getVector3fMap());
  }
}

// The input point that stretches the cloud furthest along `axis`: the one furthest from the
// median there (among the points the crop keeps). A grid too fine for the cloud's extent is
// nearly always one far stray return, and naming it (index in the input, coordinates) tells the
// user what to crop or clean, where the extent alone does not.
std::string farthest_point(const PointCloud& cloud, const CloudFilterOptions& options, int axis) {
  constexpr float kBig = std::numeric_limits<float>::max();
  const Eigen::Vector3f lo = options.crop_min.value_or(Eigen::Vector3f::Constant(-kBig));
  const Eigen::Vector3f hi = options.crop_max.value_or(Eigen::Vector3f::Constant(kBig));
  const auto kept = [&](const Eigen::Vector3f& p) {
    return p.allFinite() && (p.array() >= lo.array()).all() && (p.array() <= hi.array()).all();
  };
  std::vector<float> values;
  for (const auto& p : cloud.points)
    if (kept(p)) values.push_back(p[axis]);
  if (values.empty()) return "";
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  const double median = values[values.size() / 2];
  size_t worst = 0;
  double worst_distance = -1;
  for (size_t i = 0; i < cloud.points.size(); ++i)
    if (kept(cloud.points[i]) && std::abs(cloud.points[i][axis] - median) > worst_distance) {
      worst = i;
      worst_distance = std::abs(cloud.points[i][axis] - median);
    }
  const Eigen::Vector3f& p = cloud.points[worst];
  const char axis_name = static_cast<char>('x' + axis);
  return "point " + std::to_string(worst) + " (" + std::to_string(p.x()) + ", " +
         std::to_string(p.y()) + ", " + std::to_string(p.z()) + ") lies " +
         std::to_string(worst_distance) + " m from the cloud's median " + axis_name + " (" +
         std::to_string(median) + ")";
}

// VoxelGrid indexes voxels with 32-bit integers and, when they would overflow, only prints a
// warning and returns the cloud unfiltered; refuse instead so the caller learns about it.
void check_voxel_grid_extent(const PointCloud& input, const pcl::PointCloud<pcl::PointXYZ>& current,
                             const CloudFilterOptions& options, const std::string& name) {
  Eigen::Vector3f lo, hi;
  bounds(current, &lo, &hi);
  const Eigen::Array3d cells =
      ((hi - lo).cast<double>().array() / options.voxel_size).floor() + 1.0;
  if (cells.prod() <= static_cast<double>(std::numeric_limits<int32_t>::max())) return;
  int axis = 0;
  cells.maxCoeff(&axis);
  throw InputError(name + ": " + farthest_point(input, options, axis) + ": the cloud spans " +
                   std::to_string(hi.x() - lo.x()) + " x " + std::to_string(hi.y() - lo.y()) +
                   " x " + std::to_string(hi.z() - lo.z()) + " m, more than the " +
                   std::to_string(std::numeric_limits<int32_t>::max()) + " voxels of size " +
                   std::to_string(options.voxel_size) +
                   " m a voxel grid can index; remove the point, crop, or use a larger voxel");
}

// PCL octree keys hold 31 levels: each axis spans at most 2^30 cells of the outlier voxel size.
// Refuse a cloud that wide rather than let PCL fail.
void check_outlier_octree_extent(const PointCloud& input,
                                 const pcl::PointCloud<pcl::PointXYZ>& current,
                                 const CloudFilterOptions& options, const std::string& name) {
  Eigen::Vector3f lo, hi;
  bounds(current, &lo, &hi);
  const Eigen::Array3d cells = (hi - lo).cast<double>().array() / options.outlier_voxel;
  int axis = 0;
  if (cells.maxCoeff(&axis) <= double(1 << 30)) return;
  const char axis_name = static_cast<char>('x' + axis);
  throw InputError(name + ": " + farthest_point(input, options, axis) + ": the cloud spans " +
                   std::to_string(hi[axis] - lo[axis]) + " m in " + axis_name +
                   ", more than the 2^30 cells of the outlier voxel size " +
                   std::to_string(options.outlier_voxel) + " m (" +
                   std::to_string(double(1 << 30) * options.outlier_voxel) +
                   " m) the outlier octree can index; remove the point, crop, or use a larger "
                   "outlier voxel");
}

}  // namespace

void filter_with_pcl(const PointCloud& cloud, const CloudFilterOptions& options,
                     const std::string& name, FilterStats* stats, PointCloud* filtered) {
  FilterStats& s = *stats;
  PointCloud& out = *filtered;
  using Cloud = pcl::PointCloud<pcl::PointXYZ>;
  Cloud::Ptr current(new Cloud);
  current->reserve(cloud.points.size());
  for (const auto& p : cloud.points) {
    if (p.allFinite()) current->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  }
  current->is_dense = true;  // every NaN was dropped just above
  s.non_finite = s.points_in - current->size();

  if (options.crop_min || options.crop_max) {
    constexpr float kBig = std::numeric_limits<float>::max();
    const Eigen::Vector3f lo = options.crop_min.value_or(Eigen::Vector3f::Constant(-kBig));
    const Eigen::Vector3f hi = options.crop_max.value_or(Eigen::Vector3f::Constant(kBig));
    pcl::CropBox<pcl::PointXYZ> crop;
    crop.setMin(Eigen::Vector4f(lo.x(), lo.y(), lo.z(), 1.0f));
    crop.setMax(Eigen::Vector4f(hi.x(), hi.y(), hi.z(), 1.0f));
    crop.setInputCloud(current);
    Cloud::Ptr next(new Cloud);
    crop.filter(*next);
    current = next;
  }
  s.after_crop = current->size();

  if (options.voxel_size > 0.0f && !current->empty()) {
    check_voxel_grid_extent(cloud, *current, options, name);
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    grid.setLeafSize(options.voxel_size, options.voxel_size, options.voxel_size);
    grid.setInputCloud(current);
    Cloud::Ptr next(new Cloud);
    grid.filter(*next);
    current = next;
  }
  s.after_voxel = current->size();

  bool sparse = false;
  if (options.outlier_neighbours > 0 && current->size() > 1 && options.outlier_voxel > 0.0f) {
    // Statistical outlier removal by voxel: the points are grouped into the leaves of a PCL octree
    // of outlier_voxel cells (memory grows with the occupied cells only), the removal runs on one
    // centroid per occupied cell, and each cell's points are kept or dropped together. SOR then
    // costs per occupied cell instead of per point, and a dense patch near the sensor no longer
    // sets the neighbour-distance statistics for the sparse returns far away.
    check_outlier_octree_extent(cloud, *current, options, name);
    pcl::octree::OctreePointCloudPointVector<pcl::PointXYZ> octree(options.outlier_voxel);
    octree.setInputCloud(current);
    octree.addPointsFromInputCloud();
    Cloud::Ptr centroids(new Cloud);
    std::vector<const pcl::Indices*> members;
    centroids->reserve(octree.getLeafCount());
    members.reserve(octree.getLeafCount());
    for (auto it = octree.leaf_depth_begin(); it != octree.leaf_depth_end(); ++it) {
      const pcl::Indices& idx = it.getLeafContainer().getPointIndicesVector();
      if (idx.empty()) continue;
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      for (const auto i : idx) sum += (*current)[i].getVector3fMap().cast<double>();
      const Eigen::Vector3f c = (sum / static_cast<double>(idx.size())).cast<float>();
      centroids->push_back(pcl::PointXYZ(c.x(), c.y(), c.z()));
      members.push_back(&idx);
    }
    // Cells holding under two points on average (a sparse cloud): judging cells would save little
    // and blur the neighbour distances, so the points are judged themselves below.
    sparse = centroids->size() * 2 > current->size();
    if (!sparse) s.outlier_cells = centroids->size();
    if (!sparse && centroids->size() > 1) {
      const pcl::Indices kept_cells = remove_statistical_outliers(
          *centroids, options.outlier_neighbours, options.outlier_stddev);
      std::vector<uint8_t> keep(current->size(), 0);
      for (const auto c : kept_cells)
        for (const auto i : *members[c]) keep[i] = 1;
      Cloud::Ptr next(new Cloud);
      next->reserve(current->size());
      for (size_t i = 0; i < current->size(); ++i)
        if (keep[i]) next->push_back((*current)[i]);
      next->is_dense = true;
      current = next;
    }
  }
  if (options.outlier_neighbours > 0 && current->size() > 1 &&
      (options.outlier_voxel <= 0.0f || sparse)) {
    const pcl::Indices kept =
        remove_statistical_outliers(*current, options.outlier_neighbours, options.outlier_stddev);
    Cloud::Ptr next(new Cloud);
    next->reserve(kept.size());
    for (const auto i : kept) next->push_back((*current)[i]);
    next->is_dense = true;
    current = next;
  }
  s.after_outliers = current->size();

  out.points.reserve(current->size());
  for (const auto& p : current->points) out.points.emplace_back(p.x, p.y, p.z);
}

}  // namespace terrastride::perception::detail
