// Cloud readers for XYZ text and NPY (hand-parsed: both are tiny, well-specified formats), the
// dispatch by extension, and the binary PCD writer. PCD/PLY reading is in pcl_io.cpp
// (in the PCL module, pcl_module.hpp).
#include "terrastride/perception/cloud_io.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string_view>

#include "cloud_io_internal.hpp"
#include "pcl_module.hpp"
#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/npy.hpp"

namespace fs = std::filesystem;

namespace terrastride::perception {
namespace {

using detail::lower_extension;

void check_readable_file(const std::string& path) {
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) throw InputError(path + ": file not found");
  if (fs::is_directory(status)) throw InputError(path + ": is a directory, not a point cloud file");
  std::ifstream probe(path, std::ios::binary);
  if (!probe) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  if (probe.peek() == std::char_traits<char>::eof()) throw InputError(path + ": file is empty");
}

std::string read_whole_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file: " + std::strerror(errno));
  std::string data;
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  // A pipe or device has no size; resizing to (size_t)-1 would throw bad_alloc, not an InputError.
  if (size < 0) throw InputError(path + ": cannot determine the file size (not a regular file?)");
  data.resize(static_cast<size_t>(size));
  in.seekg(0);
  in.read(data.data(), static_cast<std::streamsize>(data.size()));
  if (!in) throw InputError(path + ": read error");
  return data;
}

bool is_separator(char c) {
  return c == ' ' || c == '\t' || c == ',' || c == '\r';
}

// "x y z [more columns]" per line; '#' starts a comment. A line that has content but not three
// numbers is an error (with its line number): it usually means the file is not an XYZ cloud.
detail::RawCloud read_xyz_text(const std::string& path) {
  const std::string text = read_whole_file(path);
  if (text.find('\0') != std::string::npos) {
    throw InputError(path + ": contains binary data, not an 'x y z' text cloud");
  }
  detail::RawCloud raw;
  raw.points.reserve(text.size() / 24);
  const char* p = text.data();
  const char* const end = p + text.size();
  size_t line_no = 0;
  while (p < end) {
    ++line_no;
    const char* line_end = static_cast<const char*>(std::memchr(p, '\n', end - p));
    if (line_end == nullptr) line_end = end;
    const char* content_end = static_cast<const char*>(std::memchr(p, '#', line_end - p));
    if (content_end == nullptr) content_end = line_end;
    float v[3];
    int n = 0;
    const char* q = p;
    while (n < 3) {
      while (q < content_end && is_separator(*q)) ++q;
      if (q >= content_end) break;
      const char* token = q;
      // from_chars does not take a leading '+' (and "+-1" is not a number).
      if (*q == '+' && q + 1 < content_end && q[1] != '-') ++q;
      // Parsed as double and narrowed: from_chars<float> calls "1e-50" out of range, which would
      // turn a near-zero coordinate into a dropped point.
      double d = 0;
      const auto [next, err] = std::from_chars(q, content_end, d);
      const char* token_end = q;
      while (token_end < content_end && !is_separator(*token_end)) ++token_end;
      bool ok = err == std::errc() && next == token_end;
      constexpr float kMax = std::numeric_limits<float>::max();
      constexpr float kInf = std::numeric_limits<float>::infinity();
      v[n] = d > kMax ? kInf : d < -kMax ? -kInf : static_cast<float>(d);
      if (err == std::errc::result_out_of_range &&
          std::string_view(q, token_end - q).find_first_not_of("0123456789.eE+-") ==
              std::string_view::npos) {
        v[n] = kInf;  // beyond even a double: dropped later as non-finite
        ok = true;
      }
      if (!ok) {
        static const char* const kAxis[] = {"x", "y", "z"};
        const std::string_view bad(token, std::min<size_t>(40, token_end - token));
        throw InputError(path + ": line " + std::to_string(line_no) + ": column " +
                         std::to_string(n + 1) + " (" + kAxis[n] + "): '" + std::string(bad) +
                         "' is not a number");
      }
      q = token_end;
      ++n;
    }
    if (n == 3) {
      raw.points.emplace_back(v[0], v[1], v[2]);
    } else if (n > 0) {
      throw InputError(path + ": line " + std::to_string(line_no) +
                       ": expected 3 columns 'x y z', found " + std::to_string(n));
    }
    p = line_end + 1;
  }
  return raw;
}

detail::RawCloud read_npy_cloud(const std::string& path) {
  const NpyArray a = read_npy(path);
  if (a.dtype != "<f4" && a.dtype != "<f8") {
    throw InputError(path + ": NPY dtype '" + a.dtype +
                     "' is not a point cloud; expected float32 (<f4) or float64 (<f8)");
  }
  std::ostringstream shape;
  shape << "(";
  for (size_t i = 0; i < a.shape.size(); ++i) shape << (i ? ", " : "") << a.shape[i];
  shape << (a.shape.size() == 1 ? ",)" : ")");
  if (a.shape.size() != 2 || a.shape[1] < 3) {
    throw InputError(path + ": NPY shape " + shape.str() +
                     " is not a point cloud; expected (N, 3)");
  }
  // (3, N) is x, y, z stored as rows, one column per point: read as (N, >=3) it would make three
  // points out of the first three columns. A cloud with more values per point than points is
  // implausible, while (2, 4) (two points with an extra column) cannot be a transposed x y z.
  if (a.shape[0] >= 3 && a.shape[1] > a.shape[0]) {
    throw InputError(path + ": NPY shape " + shape.str() +
                     " has more columns than rows: it looks like one row per coordinate and one "
                     "column per point; a cloud is one row per point, shape (N, 3) or (N, >=3): "
                     "save the transpose (numpy: np.save(path, a.T))");
  }
  detail::RawCloud raw;
  const size_t rows = a.shape[0], cols = a.shape[1];
  raw.points.resize(rows);
  if (a.dtype == "<f4") {
    const char* base = a.bytes.data();
    for (size_t r = 0; r < rows; ++r) {
      std::memcpy(raw.points[r].data(), base + r * cols * 4, 12);
    }
  } else {
    const char* base = a.bytes.data();
    for (size_t r = 0; r < rows; ++r) {
      double d[3];
      std::memcpy(d, base + r * cols * 8, 24);
      raw.points[r] = Eigen::Vector3d(d[0], d[1], d[2]).cast<float>();
    }
  }
  return raw;
}

}  // namespace

CloudFileRead read_cloud_file(const std::string& path) {
  const std::string ext = lower_extension(path);
  const bool known =
      ext == ".pcd" || ext == ".ply" || ext == ".xyz" || ext == ".txt" || ext == ".npy";
  if (!known) {
    throw InputError(path + ": unknown point cloud extension '" + ext +
                     "' (expected .pcd, .ply, .xyz, .txt or .npy)");
  }
  check_readable_file(path);
  detail::RawCloud raw;
#ifdef TERRASTRIDE_HAVE_PCL
  // PCL's readers live in the PCL module, loaded here on first use (pcl_module.hpp).
  if (ext == ".pcd") {
    raw = detail::pcl_module().read_pcd(path);
  } else if (ext == ".ply") {
    raw = detail::pcl_module().read_ply(path);
#else
  if (ext == ".pcd") {
    raw = detail::read_pcd_with_pcl(path);
  } else if (ext == ".ply") {
    raw = detail::read_ply_with_pcl(path);
#endif
  } else if (ext == ".npy") {
    raw = read_npy_cloud(path);
  } else {
    raw = read_xyz_text(path);
  }
  CloudFileRead file;
  if (raw.has_viewpoint) {
    if (!raw.viewpoint_position.allFinite())
      throw InputError(path + ": VIEWPOINT position is not finite");
    const Eigen::Vector4d& q = raw.viewpoint_wxyz;
    SensorPose pose;
    pose.position = raw.viewpoint_position;
    // VIEWPOINT lists the quaternion w first (PCL's order: tx ty tz qw qx qy qz).
    pose.orientation = checked_quaternion(q[1], q[2], q[3], q[0], path + ": VIEWPOINT");
    file.viewpoint = pose;
    file.viewpoint_marked = raw.sensor_frame_marked;
  }
  const size_t in_file = raw.points.size();
  if (in_file == 0) throw InputError(path + ": contains no points");
  // Compact in place: NaN/inf points carry no geometry (sensors use them for "no return").
  auto kept = std::remove_if(raw.points.begin(), raw.points.end(),
                             [](const Eigen::Vector3f& p) { return !p.allFinite(); });
  raw.points.erase(kept, raw.points.end());
  if (raw.points.empty()) {
    throw InputError(path + ": all " + std::to_string(in_file) +
                     " points are non-finite (NaN or infinite)");
  }
  file.stats.points_in_file = in_file;
  file.stats.non_finite = in_file - raw.points.size();
  file.points = std::move(raw.points);
  return file;
}

std::optional<FileSensor> file_sensor(const CloudFileRead& file, const std::string& path,
                                      ViewpointUse use) {
  if (!file.viewpoint) return std::nullopt;
  const SensorPose& vp = *file.viewpoint;
  const bool rotated = !vp.orientation.isApprox(Eigen::Quaterniond::Identity(), 1e-12);
  std::ostringstream text;
  text.precision(7);  // as stored: float32
  text << "VIEWPOINT " << vp.position.x() << " " << vp.position.y() << " " << vp.position.z() << " "
       << vp.orientation.w() << " " << vp.orientation.x() << " " << vp.orientation.y() << " "
       << vp.orientation.z();
  // World-frame points: the VIEWPOINT's rotation, if any, is the sensor's and is not applied.
  if (use == ViewpointUse::kPosition)
    return FileSensor{SensorPose{vp.position, Eigen::Quaterniond::Identity()}, false};
  if (use == ViewpointUse::kDefault && !rotated && !file.viewpoint_marked)
    throw InputError(
        path + ": " + text.str() +
        " gives a sensor position without a rotation, and the file does not say which frame "
        "its points are in: terrastride's writer of earlier versions put world-frame points "
        "and the sensor position there (--viewpoint origin reads it so), while PCL means points "
        "relative to that position in a sensor frame parallel to the world (--viewpoint pose)");
  return FileSensor{vp, true};
}

PointCloud read_cloud(const std::string& path, std::optional<Eigen::Vector3d> origin,
                      ReadStats* stats) {
  if (origin && !origin->allFinite()) throw InputError(path + ": sensor origin is not finite");
  CloudFileRead file = read_cloud_file(path);
  PointCloud cloud;
  cloud.source = path;
  if (stats) *stats = file.stats;
  if (origin) {
    cloud.sensor_origin = origin;
  } else if (file.viewpoint && file.viewpoint_marked) {
    const size_t dropped = transform_points(file.points, *file.viewpoint);
    if (stats) stats->non_finite += dropped;
    if (file.points.empty())
      throw InputError(path + ": no point is finite once placed by its VIEWPOINT");
    cloud.sensor_origin = file.viewpoint->position;
  } else if (file.viewpoint) {
    cloud.sensor_origin = file.viewpoint->position;
  }
  cloud.points = std::move(file.points);
  return cloud;
}

PointCloud read_cloud(const std::string& path, std::optional<Eigen::Vector3d> origin) {
  return read_cloud(path, origin, nullptr);
}

void write_pcd(const PointCloud& cloud, const std::string& path, const SensorPose* frame) {
  // Written by hand (the binary PCD v0.7 layout is a text header plus packed float32 x y z) so the
  // bytes can go through write_file_atomically; PCL reads it back in tests.
  std::optional<SensorPose> pose;
  if (frame) {
    pose = *frame;
  } else if (cloud.sensor_origin) {
    pose = SensorPose{*cloud.sensor_origin, Eigen::Quaterniond::Identity()};
  }
  if (pose && (!pose->position.allFinite() || !pose->orientation.coeffs().allFinite()))
    throw InputError(path + ": sensor pose is not finite");
  if (pose) pose->orientation.normalize();
  std::ostringstream h;
  h.precision(9);
  const size_t n = cloud.points.size();
  h << "# .PCD v0.7 - Point Cloud Data file format\n";
  if (pose) h << detail::kSensorFrameMarker << "\n";
  h << "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
    << "WIDTH " << n << "\nHEIGHT 1\n";
  const SensorPose vp = pose.value_or(SensorPose{});
  // PCL's order: tx ty tz qw qx qy qz.
  h << "VIEWPOINT " << vp.position.x() << " " << vp.position.y() << " " << vp.position.z() << " "
    << vp.orientation.w() << " " << vp.orientation.x() << " " << vp.orientation.y() << " "
    << vp.orientation.z() << "\n"
    << "POINTS " << n << "\nDATA binary\n";
  std::string bytes = h.str();
  const size_t header = bytes.size();
  bytes.resize(header + n * 12);
  // The inverse pose: sensor = R^T (world - t), in double so the round trip loses only the
  // float rounding of the stored values.
  const Eigen::Matrix3d rt = vp.orientation.toRotationMatrix().transpose();
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector3f p = cloud.points[i];
    if (pose) p = (rt * (p.cast<double>() - vp.position)).cast<float>();
    std::memcpy(&bytes[header + i * 12], p.data(), 12);
  }
  write_file_atomically(path, bytes);
}

}  // namespace terrastride::perception
