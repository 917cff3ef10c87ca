// Fusing clouds into an octomap::OcTree.
#include "terrastride/perception/octomap_fusion.hpp"

#include <cmath>
#include <sstream>

#include "terrastride/perception/atomic_output.hpp"

namespace terrastride::perception {
namespace {

// OcTree keys are 16 bit with the origin in the middle, so coordinates must stay within
// resolution * 2^15 of zero; beyond that OctoMap only prints an error and drops the point.
double addressable_half_extent(const octomap::OcTree& tree) {
  return tree.getResolution() * static_cast<double>(1u << (tree.getTreeDepth() - 1));
}

std::string describe(const PointCloud& cloud) {
  return cloud.source.empty() ? std::string("point cloud") : cloud.source;
}

}  // namespace

void insert_into_octomap(octomap::OcTree& tree, const PointCloud& cloud, double max_range,
                         bool discretize) {
  const double limit = addressable_half_extent(tree);
  const auto outside = [&](const Eigen::Vector3d& p) { return (p.array().abs() >= limit).any(); };
  if (cloud.sensor_origin) {
    if (!cloud.sensor_origin->allFinite()) {
      throw InputError(describe(cloud) + ": sensor origin is not finite");
    }
    if (outside(*cloud.sensor_origin)) {
      throw InputError(describe(cloud) + ": sensor origin lies outside the OctoMap's extent (+-" +
                       std::to_string(limit) + " m at this resolution)");
    }
  }
  octomap::Pointcloud scan;
  scan.reserve(cloud.points.size());
  for (const auto& p : cloud.points) {
    if (!p.allFinite()) continue;
    if (outside(p.cast<double>())) {
      std::ostringstream s;
      s << describe(cloud) << ": point (" << p.x() << ", " << p.y() << ", " << p.z()
        << ") lies outside the OctoMap's extent (+-" << limit
        << " m at this resolution); crop the cloud or use a coarser resolution";
      throw InputError(s.str());
    }
    scan.push_back(p.x(), p.y(), p.z());
  }
  if (cloud.sensor_origin) {
    const Eigen::Vector3d& o = *cloud.sensor_origin;
    // lazy_eval: inner nodes are updated once below instead of after every ray.
    tree.insertPointCloud(scan, octomap::point3d(o.x(), o.y(), o.z()), max_range,
                          /*lazy_eval=*/true, discretize);
  } else {
    // No origin means no known ray, hence no evidence about free space: only the hit voxels are
    // marked occupied (once per voxel per cloud, as insertPointCloud does for endpoints). Carving
    // from a guessed origin would erase real obstacles. max_range does not apply without rays.
    octomap::KeySet occupied;
    octomap::OcTreeKey key;
    for (size_t i = 0; i < scan.size(); ++i) {
      if (tree.coordToKeyChecked(scan[i], key)) occupied.insert(key);
    }
    for (const auto& k : occupied) tree.updateNode(k, true, /*lazy_eval=*/true);
  }
  tree.updateInnerOccupancy();
}

std::unique_ptr<octomap::OcTree> build_octomap(const std::vector<PointCloud>& clouds,
                                               const OctoMapOptions& options) {
  if (!std::isfinite(options.resolution) || options.resolution < 0.001 ||
      options.resolution > 10.0) {
    throw InputError("OctoMap resolution " + std::to_string(options.resolution) +
                     " m is out of range (expected 0.001 to 10 m)");
  }
  if (std::isnan(options.max_range)) throw InputError("OctoMap max range is NaN");
  auto tree = std::make_unique<octomap::OcTree>(options.resolution);
  for (const auto& cloud : clouds) {
    insert_into_octomap(*tree, cloud, options.max_range, options.discretize);
  }
  return tree;
}

void write_octomap(const octomap::OcTree& tree, const std::string& path) {
  // The byte stream of AbstractOccupancyOcTree::writeBinaryConst (header, then the node bits from
  // the root), written here because the Debian liboctomap is built with debug output on and its
  // writeBinaryConst / writeBinaryData print "Writing N nodes to output stream... done." to stderr.
  // writeBinaryNode is the silent public part they call.
  std::ostringstream out(std::ios::binary);
  out << "# Octomap OcTree binary file\n# (feel free to add / change comments, but leave the first "
         "line as it is!)\n#\n";
  out << "id " << tree.getTreeType() << std::endl;
  out << "size " << tree.size() << std::endl;
  out << "res " << tree.getResolution() << std::endl;
  out << "data" << std::endl;
  if (tree.getRoot()) tree.writeBinaryNode(out, tree.getRoot());
  if (!out.good()) throw InputError(path + ": cannot serialise the OctoMap");
  write_file_atomically(path, out.str());
}

}  // namespace terrastride::perception
