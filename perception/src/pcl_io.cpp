// PCD and PLY reading through PCL's io module. The only translation unit with PCL io headers.
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <vector>

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

// PCL allocates what the header promises (even in readHeader) before reading the body, so a
// lying header in a corrupt or hostile file would make it allocate gigabytes. These checks parse
// just the counts and compare the promise with the bytes present, before PCL sees the file.
[[noreturn]] void too_short(const std::string& path, double points, uintmax_t file_size) {
  throw InputError(path + ": header promises " + std::to_string(static_cast<uint64_t>(points)) +
                   " points but the file has only " + std::to_string(file_size) +
                   " bytes (truncated or corrupt)");
}

std::vector<std::string> split_words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> words;
  for (std::string w; in >> w;) words.push_back(w);
  return words;
}

double to_number(const std::string& path, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0' || !(v >= 0)) {
    throw InputError(path + ": bad number '" + text + "' in header");
  }
  return v;
}

void check_pcd_size(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<double> sizes, counts;
  double points = -1, width = -1, height = 1;
  std::string data, line;
  size_t lines = 0;
  while (data.empty() && std::getline(in, line) && ++lines < 1000) {
    const auto w = split_words(line);
    if (w.empty() || w[0][0] == '#') continue;
    if (w[0] == "SIZE" || w[0] == "COUNT") {
      auto& v = w[0] == "SIZE" ? sizes : counts;
      for (size_t i = 1; i < w.size(); ++i) v.push_back(to_number(path, w[i]));
    } else if (w[0] == "POINTS" && w.size() > 1) {
      points = to_number(path, w[1]);
    } else if (w[0] == "WIDTH" && w.size() > 1) {
      width = to_number(path, w[1]);
    } else if (w[0] == "HEIGHT" && w.size() > 1) {
      height = to_number(path, w[1]);
    } else if (w[0] == "DATA" && w.size() > 1) {
      data = w[1];
    }
  }
  if (data.empty()) return;  // no complete header: PCL reports it
  const std::streamoff header_end = in.tellg();
  std::error_code ec;
  const uintmax_t file_size = std::filesystem::file_size(path, ec);
  if (ec || header_end < 0) return;
  const double body = static_cast<double>(file_size) - static_cast<double>(header_end);
  const double n = std::max(points, width * height);
  double step = 0;
  for (size_t i = 0; i < sizes.size(); ++i) step += sizes[i] * (i < counts.size() ? counts[i] : 1);
  double need;
  if (data == "ascii") {
    need = n * 2.0 * std::max<double>(1, static_cast<double>(sizes.size()));  // >= "0 " a value
  } else if (data == "binary_compressed") {
    need = n * step / 100.0 - 1e6;  // LZF does not compress better than about 1:90
  } else {
    need = n * step;
  }
  if (need > body) too_short(path, n, file_size);
}

size_t ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
      t == "float32") {
    return 4;
  }
  if (t == "double" || t == "float64") return 8;
  return 1;
}

void check_ply_size(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line, format;
  double need = 0, count = 0, record = 0, points = 0;
  bool ended = false;
  size_t lines = 0;
  const auto close_element = [&] { need += count * record; };
  while (std::getline(in, line) && ++lines < 10000) {
    const auto w = split_words(line);
    if (w.empty()) continue;
    if (w[0] == "format" && w.size() > 1) {
      format = w[1];
    } else if (w[0] == "element" && w.size() > 2) {
      close_element();
      count = to_number(path, w[2]);
      record = 0;
      if (w[1] == "vertex") points = count;
    } else if (w[0] == "property" && w.size() > 2) {
      // A list needs at least its count; an ascii value at least "0 ".
      const size_t bytes = w[1] == "list" ? ply_type_size(w[2]) : ply_type_size(w[1]);
      record += format == "ascii" ? 2.0 : static_cast<double>(bytes);
    } else if (w[0] == "end_header") {
      ended = true;
      break;
    }
  }
  if (!ended) return;  // PCL reports the broken header
  close_element();
  const std::streamoff header_end = in.tellg();
  std::error_code ec;
  const uintmax_t file_size = std::filesystem::file_size(path, ec);
  if (ec || header_end < 0) return;
  if (need > static_cast<double>(file_size) - static_cast<double>(header_end)) {
    too_short(path, points, file_size);
  }
}

void check_ply_signature(const std::string& path) {
  const std::string head = first_bytes(path, 4);
  if (head.compare(0, 3, "ply") != 0 || (head.size() > 3 && head[3] != '\n' && head[3] != '\r')) {
    throw InputError(path + ": not a PLY file (does not start with 'ply')");
  }
}

#ifdef TERRASTRIDE_HAVE_PCL

// PCL reports parse problems on its console; we turn them into one InputError instead. The
// level is set once per process and never restored: toggling a global around each read would race
// when several threads (the socket service) read clouds at once, and PCL is used only here.
void silence_pcl() {
  static std::once_flag once;
  std::call_once(once, [] { pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS); });
}

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

namespace {

#ifdef TERRASTRIDE_HAVE_PCL
// PCD and PLY differ only in PCL's reader class; both share pcl::FileReader::read.
RawCloud read_with_pcl_reader(pcl::FileReader& reader, const std::string& path,
                              const std::string& format) {
  silence_pcl();
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int version = 0;
  int rc;
  try {
    rc = reader.read(path, blob, origin, orientation, version);
  } catch (const std::exception& e) {
    throw InputError(path + ": unreadable " + format + " file: " + e.what());
  }
  if (rc < 0)
    throw InputError(path + ": unreadable or corrupt " + format + " file (PCL reader failed)");
  RawCloud raw = extract_xyz(path, blob);
  raw.origin = origin_if_recorded(origin, orientation);
  return raw;
}
#endif

}  // namespace

RawCloud read_pcd_with_pcl(const std::string& path) {
  check_pcd_signature(path);
  check_pcd_size(path);
#ifdef TERRASTRIDE_HAVE_PCL
  pcl::PCDReader reader;
  return read_with_pcl_reader(reader, path, "PCD");
#else
  throw InputError(path + ": PCD reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

RawCloud read_ply_with_pcl(const std::string& path) {
  check_ply_signature(path);
  check_ply_size(path);
#ifdef TERRASTRIDE_HAVE_PCL
  pcl::PLYReader reader;
  return read_with_pcl_reader(reader, path, "PLY");
#else
  throw InputError(path + ": PLY reading needs PCL (built with TERRASTRIDE_WITH_PCL=OFF)");
#endif
}

}  // namespace terrastride::perception::detail
