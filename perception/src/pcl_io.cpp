// PCD and PLY reading through PCL's io module. The only translation unit with PCL io headers.
#include <cstring>
#include <fstream>

#include "cloud_io_internal.hpp"
#include "terrastride/perception/point_cloud.hpp"

#ifdef TERRASTRIDE_HAVE_PCL
#include <pcl/PCLPointCloud2.h>
#include <pcl/console/print.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#endif

namespace terrastride::perception::detail {
namespace {

std::string first_bytes(const std::string& path, size_t n) {
  std::ifstream in(path, std::ios::binary);
  std::string s(n, '\0');
  in.read(s.data(), static_cast<std::streamsize>(n));
  s.resize(static_cast<size_t>(in.gcount()));
  return s;
}

// PCL's readers print their own diagnostics and, for some garbage, get far before failing; a
// cheap look at the first bytes gives a clearer "this is not a PCD/PLY file" message up front.
void check_pcd_signature(const std::string& path) {
  std::string head = first_bytes(path, 4096);
  size_t pos = 0;
  while (pos < head.size()) {
    size_t eol = head.find('\n', pos);
    if (eol == std::string::npos) eol = head.size();
    std::string line = head.substr(pos, eol - pos);
    pos = eol + 1;
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    static const char* const kKeys[] = {"VERSION", "FIELDS", "SIZE",   "TYPE",      "COUNT",
                                        "WIDTH",   "HEIGHT", "POINTS", "VIEWPOINT", "DATA"};
    for (const char* key : kKeys) {
      if (line.compare(start, std::strlen(key), key) == 0) return;
    }
    break;
  }
  throw InputError(path + ": not a PCD file (no PCD header: expected VERSION/FIELDS lines)");
}

void check_ply_signature(const std::string& path) {
  const std::string head = first_bytes(path, 4);
  if (head.compare(0, 3, "ply") != 0 || (head.size() > 3 && head[3] != '\n' && head[3] != '\r')) {
    throw InputError(path + ": not a PLY file (does not start with 'ply')");
  }
}

#ifdef TERRASTRIDE_HAVE_PCL

// PCL reports parse problems on its console; we turn them into one InputError instead, so the
// console stays quiet while our readers run.
class QuietPcl {
 public:
  QuietPcl() : saved_(pcl::console::getVerbosityLevel()) {
    pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  }
  ~QuietPcl() { pcl::console::setVerbosityLevel(saved_); }

 private:
  pcl::console::VERBOSITY_LEVEL saved_;
};

// Pulls x, y, z (float32 or float64 fields) out of a PCLPointCloud2 blob, whatever other fields
// (normals, intensity, padding) it carries.
RawCloud extract_xyz(const std::string& path, const pcl::PCLPointCloud2& blob) {
  int offset[3] = {-1, -1, -1};
  uint8_t type[3] = {0, 0, 0};
  const char* names[3] = {"x", "y", "z"};
  for (const auto& f : blob.fields) {
    for (int k = 0; k < 3; ++k) {
      if (f.name == names[k]) {
        offset[k] = static_cast<int>(f.offset);
        type[k] = f.datatype;
      }
    }
  }
  for (int k = 0; k < 3; ++k) {
    if (offset[k] < 0) throw InputError(path + ": has no '" + names[k] + "' field");
    if (type[k] != pcl::PCLPointField::FLOAT32 && type[k] != pcl::PCLPointField::FLOAT64) {
      throw InputError(path + ": field '" + names[k] + "' is not float32/float64");
    }
    const size_t size = type[k] == pcl::PCLPointField::FLOAT32 ? 4 : 8;
    if (static_cast<size_t>(offset[k]) + size > blob.point_step) {
      throw InputError(path + ": field '" + names[k] + "' lies outside the point record");
    }
  }
  const size_t n = static_cast<size_t>(blob.width) * blob.height;
  if (blob.data.size() < n * blob.point_step) throw InputError(path + ": point data is truncated");
  RawCloud raw;
  raw.points.resize(n);
  const uint8_t* base = blob.data.data();
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* rec = base + i * blob.point_step;
    for (int k = 0; k < 3; ++k) {
      if (type[k] == pcl::PCLPointField::FLOAT32) {
        float v;
        std::memcpy(&v, rec + offset[k], 4);
        raw.points[i][k] = v;
      } else {
        double v;
        std::memcpy(&v, rec + offset[k], 8);
        raw.points[i][k] = static_cast<float>(v);
      }
    }
  }
  return raw;
}

// "Identity-zero" is PCL's default viewpoint, i.e. no sensor pose recorded in the file.
std::optional<Eigen::Vector3d> origin_if_recorded(const Eigen::Vector4f& origin,
                                                  const Eigen::Quaternionf& orientation) {
  const bool zero = origin.head<3>().isZero(0.0f);
  const bool identity = orientation.w() == 1.0f && orientation.vec().isZero(0.0f);
  if (zero && identity) return std::nullopt;
  if (!origin.head<3>().allFinite()) return std::nullopt;
  return origin.head<3>().cast<double>();
}

#endif

}  // namespace

RawCloud read_pcd_with_pcl(const std::string& path) {
  check_pcd_signature(path);
#ifdef TERRASTRIDE_HAVE_PCL
  QuietPcl quiet;
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int version = 0;
  pcl::PCDReader reader;
  int rc;
  try {
    rc = reader.read(path, blob, origin, orientation, version);
  } catch (const std::exception& e) {
    throw InputError(path + ": unreadable PCD file: " + e.what());
  }
  if (rc < 0) throw InputError(path + ": unreadable or corrupt PCD file (PCL reader failed)");
  RawCloud raw = extract_xyz(path, blob);
  raw.origin = origin_if_recorded(origin, orientation);
  return raw;
#else
  throw InputError(path + ": PCD reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

RawCloud read_ply_with_pcl(const std::string& path) {
  check_ply_signature(path);
#ifdef TERRASTRIDE_HAVE_PCL
  QuietPcl quiet;
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int version = 0;
  pcl::PLYReader reader;
  int rc;
  try {
    rc = reader.read(path, blob, origin, orientation, version);
  } catch (const std::exception& e) {
    throw InputError(path + ": unreadable PLY file: " + e.what());
  }
  if (rc < 0) throw InputError(path + ": unreadable or corrupt PLY file (PCL reader failed)");
  RawCloud raw = extract_xyz(path, blob);
  raw.origin = origin_if_recorded(origin, orientation);
  return raw;
#else
  throw InputError(path + ": PLY reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

}  // namespace terrastride::perception::detail
