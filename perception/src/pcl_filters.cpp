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

// The cells of a pcl::octree::OctreePointCloudPointVector<PointXYZ> of the given resolution after
// addPointsFromInputCloud(), in the order its leaf_depth_begin() visits them, each with its point
// indices in ascending order, computed without building the tree. The tree (one heap node and one
// index vector per cell, freed again at the end) cost about as much as the outlier removal on the
// cells; this is a sort of one 64-bit code per point. The octree's cell of a point depends on the
// order the points arrive in (its bounding box starts at the first point and doubles towards each
// point outside it), so this replays OctreePointCloud::adoptBoundingBoxToPoint, getKeyBitSize and
// genOctreeKeyforPoint (PCL 1.13, octree_pointcloud.hpp) with the same double arithmetic: a key
// computed before the box grew below a point keeps its value inside the moved subtree, i.e. grows
// by the cells added below. tests/perception/test_filters_pcl.cpp compares it with the tree.
// Returns false (the caller then builds the tree) when the tree would be deeper than 21 levels,
// whose 3 x 21 key bits fill the 64-bit code.
struct OctreeCells {
  std::vector<uint32_t> order;   // point indices, cell after cell
  std::vector<uint32_t> starts;  // cell c holds order[starts[c] .. starts[c + 1])
};

bool octree_cells(const pcl::PointCloud<pcl::PointXYZ>& cloud, double resolution,
                  OctreeCells* cells) {
  constexpr unsigned kMaxDepth = 21;
  const size_t n = cloud.size();
  if (n == 0 || n > std::numeric_limits<uint32_t>::max()) return false;
  const double min_value = std::numeric_limits<float>::epsilon();  // PCL's minValue
  double lo[3] = {0.0, 0.0, 0.0}, hi[3] = {resolution, resolution, resolution};
  unsigned depth = 0;
  bool defined = false;
  int64_t added_below[3] = {0, 0, 0};  // cells the box has grown by below, per axis
  // Per point and axis: its key when inserted minus the cells added below until then.
  std::vector<int64_t> key(3 * n);
  for (size_t i = 0; i < n; ++i) {
    const float p[3] = {cloud[i].x, cloud[i].y, cloud[i].z};
    for (;;) {  // adoptBoundingBoxToPoint
      bool below[3], above[3];
      for (int a = 0; a < 3; ++a) {
        below[a] = p[a] < lo[a];
        above[a] = p[a] >= hi[a];
      }
      const bool violated = below[0] || below[1] || below[2] || above[0] || above[1] || above[2];
      if (defined && !violated) break;
      if (defined) {
        const double side = static_cast<double>(1 << depth) * resolution;
        for (int a = 0; a < 3; ++a) {
          if (!above[a]) {
            lo[a] -= side;
            added_below[a] += int64_t{1} << depth;
          }
        }
        ++depth;
        if (depth > kMaxDepth) return false;
        const double grown = static_cast<double>(1 << depth) * resolution - min_value;
        for (int a = 0; a < 3; ++a) hi[a] = lo[a] + grown;
      } else {  // the first point, then getKeyBitSize on the empty tree
        for (int a = 0; a < 3; ++a) {
          lo[a] = p[a] - resolution / 2;
          hi[a] = p[a] + resolution / 2;
        }
        uint32_t max_voxels = 2;
        for (int a = 0; a < 3; ++a) {
          max_voxels =
              std::max(max_voxels,
                       static_cast<uint32_t>(std::ceil((hi[a] - lo[a] - min_value) / resolution)));
        }
        depth = std::min<uint32_t>(
            32, static_cast<uint32_t>(std::ceil(std::log2(max_voxels) - min_value)));
        if (depth > kMaxDepth) return false;
        const double side = static_cast<double>(1 << depth) * resolution;
        for (int a = 0; a < 3; ++a) {
          const double oversize = (side - (hi[a] - lo[a])) / 2.0;
          if (oversize > min_value) {
            lo[a] -= oversize;
            hi[a] += oversize;
          }
        }
        defined = true;
      }
    }
    for (int a = 0; a < 3; ++a) {  // genOctreeKeyforPoint
      key[3 * i + a] =
          static_cast<int64_t>(static_cast<uint32_t>((p[a] - lo[a]) / resolution)) - added_below[a];
    }
  }
  // Depth-first leaf order: child index (x bit, y bit, z bit) from the top level down, i.e. the
  // Morton code with x most significant (keys are below 2^depth <= 2^21).
  const auto spread = [](uint64_t v) {  // bit b of v to bit 3b
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  std::vector<uint64_t> code(n), code_scratch(n);
  for (size_t i = 0; i < n; ++i) {
    code[i] = spread(static_cast<uint64_t>(key[3 * i] + added_below[0])) << 2 |
              spread(static_cast<uint64_t>(key[3 * i + 1] + added_below[1])) << 1 |
              spread(static_cast<uint64_t>(key[3 * i + 2] + added_below[2]));
  }
  std::vector<int64_t>().swap(key);
  // Stable LSD radix sort of (code, index) by code, 11-bit digits, only those the depth uses: each
  // cell's indices stay ascending, as the tree's index vectors hold them.
  std::vector<uint32_t> order(n), scratch(n);
  for (size_t i = 0; i < n; ++i) order[i] = static_cast<uint32_t>(i);
  constexpr unsigned kDigit = 11;
  constexpr uint64_t kMask = (1u << kDigit) - 1;
  std::vector<size_t> count(kMask + 2);
  for (unsigned shift = 0; shift < 3 * depth; shift += kDigit) {
    std::fill(count.begin(), count.end(), 0);
    for (size_t i = 0; i < n; ++i) ++count[((code[i] >> shift) & kMask) + 1];
    if (count[((code[0] >> shift) & kMask) + 1] == n) continue;  // one digit value: no move
    for (size_t d = 1; d < count.size(); ++d) count[d] += count[d - 1];
    for (size_t i = 0; i < n; ++i) {
      const size_t to = count[(code[i] >> shift) & kMask]++;
      code_scratch[to] = code[i];
      scratch[to] = order[i];
    }
    code.swap(code_scratch);
    order.swap(scratch);
  }
  cells->starts.clear();
  for (size_t i = 0; i < n; ++i)
    if (i == 0 || code[i] != code[i - 1]) cells->starts.push_back(static_cast<uint32_t>(i));
  cells->starts.push_back(static_cast<uint32_t>(n));
  cells->order = std::move(order);
  return true;
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
    // VoxelGrid indexes voxels with 32-bit integers and, when they would overflow, only prints a
    // warning and returns the cloud unfiltered; refuse instead so the caller learns about it.
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
    Eigen::Vector3f hi = -lo;
    for (const auto& p : current->points) {
      lo = lo.cwiseMin(p.getVector3fMap());
      hi = hi.cwiseMax(p.getVector3fMap());
    }
    const Eigen::Array3d cells =
        ((hi - lo).cast<double>().array() / options.voxel_size).floor() + 1.0;
    if (cells.prod() > static_cast<double>(std::numeric_limits<int32_t>::max())) {
      throw InputError(name + ": voxel size " + std::to_string(options.voxel_size) +
                       " m is too small for a cloud spanning " + std::to_string(hi.x() - lo.x()) +
                       " x " + std::to_string(hi.y() - lo.y()) + " x " +
                       std::to_string(hi.z() - lo.z()) +
                       " m (too many voxels); use a larger voxel or crop first");
    }
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
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
    Eigen::Vector3f hi = -lo;
    for (const auto& p : current->points) {
      lo = lo.cwiseMin(p.getVector3fMap());
      hi = hi.cwiseMax(p.getVector3fMap());
    }
    // Octree keys hold 31 levels; refuse cells that small rather than let PCL fail.
    if (((hi - lo).cast<double>().array() / options.outlier_voxel).maxCoeff() > double(1 << 30)) {
      throw InputError(name + ": outlier voxel size " + std::to_string(options.outlier_voxel) +
                       " m is too small for the cloud's extent");
    }
    OctreeCells cells;
    if (!octree_cells(*current, options.outlier_voxel, &cells)) {
      // Deeper than octree_cells handles: the tree itself.
      pcl::octree::OctreePointCloudPointVector<pcl::PointXYZ> octree(options.outlier_voxel);
      octree.setInputCloud(current);
      octree.addPointsFromInputCloud();
      cells.order.clear();
      cells.starts.clear();
      for (auto it = octree.leaf_depth_begin(); it != octree.leaf_depth_end(); ++it) {
        const pcl::Indices& idx = it.getLeafContainer().getPointIndicesVector();
        if (idx.empty()) continue;
        cells.starts.push_back(static_cast<uint32_t>(cells.order.size()));
        for (const auto i : idx) cells.order.push_back(static_cast<uint32_t>(i));
      }
      cells.starts.push_back(static_cast<uint32_t>(cells.order.size()));
    }
    const size_t cell_count = cells.starts.size() - 1;
    Cloud::Ptr centroids(new Cloud);
    centroids->reserve(cell_count);
    for (size_t c = 0; c < cell_count; ++c) {
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      for (uint32_t j = cells.starts[c]; j < cells.starts[c + 1]; ++j)
        sum += (*current)[cells.order[j]].getVector3fMap().cast<double>();
      const double count = static_cast<double>(cells.starts[c + 1] - cells.starts[c]);
      const Eigen::Vector3f m = (sum / count).cast<float>();
      centroids->push_back(pcl::PointXYZ(m.x(), m.y(), m.z()));
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
        for (uint32_t j = cells.starts[c]; j < cells.starts[c + 1]; ++j) keep[cells.order[j]] = 1;
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
