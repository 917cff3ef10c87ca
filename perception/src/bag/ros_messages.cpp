// ROS message decoding from the wire: CDR (ROS 2) and ROS 1 serialisation of
// sensor_msgs/PointCloud2 and tf2_msgs/TFMessage (see ros_messages.hpp).
#include "terrastride/perception/ros_messages.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "bag/byte_cursor.hpp"

namespace terrastride::perception {
namespace {

using bag::Truncated;

// One reader for both wire formats: CDR aligns primitives to their size (relative to the end of
// the 4-byte encapsulation header), may be big endian and null-terminates strings; ROS 1 does none
// of this and puts a sequence number first in every std_msgs/Header.
class Wire {
 public:
  Wire(std::string_view data, MessageEncoding encoding) : data_(data), ros1_(encoding == MessageEncoding::kRos1) {
    if (encoding == MessageEncoding::kOther)
      throw InputError("the message encoding is neither CDR nor ROS 1");
    if (!ros1_) {
      if (data.size() < 4) throw InputError("a CDR message shorter than its 4-byte header");
      const auto kind = static_cast<uint8_t>(data[1]);
      if (data[0] != 0 || kind > 1)
        throw InputError("CDR encapsulation " + std::to_string(static_cast<uint8_t>(data[0])) + "," +
                         std::to_string(kind) +
                         " is not plain CDR (only CDR_LE and CDR_BE, ROS 2's, are read)");
      big_endian_ = kind == 0;
      pos_ = 4;
      origin_ = 4;
    }
  }

  template <typename T>
  T get(const char* what) {
    align(sizeof(T));
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    if (big_endian_) v = swap(v);
    return v;
  }
  std::string string(const char* what) {
    const uint32_t n = get<uint32_t>(what);
    need(n, what);
    std::string s(data_.data() + pos_, n);
    pos_ += n;
    if (!ros1_) {
      // CDR counts the terminating null.
      if (!s.empty() && s.back() == '\0') s.pop_back();
    }
    return s;
  }
  std::string_view bytes(uint32_t n, const char* what) {
    need(n, what);
    std::string_view v(data_.data() + pos_, n);
    pos_ += n;
    return v;
  }
  // A sequence's element count, checked against the bytes left (each element takes at least
  // `min_element_bytes`), so a corrupt count cannot ask for a huge allocation.
  uint32_t count(const char* what, size_t min_element_bytes) {
    const uint32_t n = get<uint32_t>(what);
    if (static_cast<uint64_t>(n) * min_element_bytes > data_.size() - pos_)
      throw Truncated(std::string(what) + ": " + std::to_string(n) + " elements do not fit in the " +
                      std::to_string(data_.size() - pos_) + " bytes left");
    return n;
  }
  // std_msgs/Header: (ROS 1: seq,) stamp, frame_id.
  void header(int64_t* stamp_ns, std::string* frame_id) {
    if (ros1_) get<uint32_t>("header.seq");
    const int64_t sec = ros1_ ? static_cast<int64_t>(get<uint32_t>("header.stamp.sec"))
                              : static_cast<int64_t>(get<int32_t>("header.stamp.sec"));
    const uint32_t nsec = get<uint32_t>("header.stamp.nanosec");
    if (nsec >= 1000000000u) throw InputError("header.stamp.nanosec " + std::to_string(nsec) + " >= 1e9");
    *stamp_ns = sec * 1000000000LL + nsec;
    *frame_id = string("header.frame_id");
  }

 private:
  void align(size_t n) {
    if (ros1_) return;
    const size_t rel = pos_ - origin_;
    const size_t pad = (n - rel % n) % n;
    need(pad, "alignment");
    pos_ += pad;
  }
  void need(size_t n, const char* what) {
    if (n > data_.size() - pos_)
      throw Truncated(std::string(what) + ": needs " + std::to_string(n) + " bytes, " +
                      std::to_string(data_.size() - pos_) + " left");
  }
  template <typename T>
  static T swap(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    for (size_t i = 0; i < sizeof(T) / 2; ++i) std::swap(b[i], b[sizeof(T) - 1 - i]);
    std::memcpy(&v, b, sizeof(T));
    return v;
  }
  std::string_view data_;
  bool ros1_;
  bool big_endian_ = false;
  size_t pos_ = 0;
  size_t origin_ = 0;
};

constexpr uint8_t kFloat32 = 7, kFloat64 = 8;

struct Field {
  std::string name;
  uint32_t offset = 0;
  uint8_t datatype = 0;
  uint32_t count = 0;
};

template <typename T>
double load(const char* p, bool swap_bytes) {
  T v;
  if (swap_bytes) {
    char b[sizeof(T)];
    for (size_t i = 0; i < sizeof(T); ++i) b[i] = p[sizeof(T) - 1 - i];
    std::memcpy(&v, b, sizeof(T));
  } else {
    std::memcpy(&v, p, sizeof(T));
  }
  return static_cast<double>(v);
}

// A cloud whose field list is empty or names a field twice is not what its writer meant to
// send (a reader would pick one of the two 'x' arbitrarily): refused rather than guessed at.
void check_fields(const std::vector<Field>& fields) {
  if (fields.empty()) throw InputError("the PointCloud2 declares no fields (field count 0)");
  std::set<std::string> names;
  for (const auto& f : fields)
    if (!names.insert(f.name).second)
      throw InputError("field '" + f.name + "' is declared twice");
}

// data holds exactly height rows of row_step bytes (sensor_msgs/PointCloud2's contract): more is
// bytes of unknown meaning (a writer's bug or a corrupted length), less is a cut cloud.
void check_data_size(uint32_t height, uint32_t row_step, size_t data_bytes) {
  const uint64_t expected = static_cast<uint64_t>(height) * row_step;
  if (data_bytes > expected)
    throw InputError(std::to_string(data_bytes) + " bytes of data, " +
                     std::to_string(data_bytes - expected) + " trailing bytes beyond height " +
                     std::to_string(height) + " x row_step " + std::to_string(row_step) + " = " +
                     std::to_string(expected));
}

DecodedCloud decode_cloud(std::string_view data, MessageEncoding encoding, bool header_only) {
  DecodedCloud out;
  try {
    Wire w(data, encoding);
    w.header(&out.stamp_ns, &out.frame_id);
    if (header_only) return out;
    out.height = w.get<uint32_t>("height");
    out.width = w.get<uint32_t>("width");
    const uint32_t n_fields = w.count("fields", 13);
    std::vector<Field> fields(n_fields);
    for (auto& f : fields) {
      f.name = w.string("fields[].name");
      f.offset = w.get<uint32_t>("fields[].offset");
      f.datatype = w.get<uint8_t>("fields[].datatype");
      f.count = w.get<uint32_t>("fields[].count");
    }
    const bool big = w.get<uint8_t>("is_bigendian") != 0;
    const uint32_t point_step = w.get<uint32_t>("point_step");
    const uint32_t row_step = w.get<uint32_t>("row_step");
    const uint32_t n_data = w.count("data", 1);
    const std::string_view bytes = w.bytes(n_data, "data");

    check_fields(fields);
    check_data_size(out.height, row_step, bytes.size());

    const Field* xyz[3] = {nullptr, nullptr, nullptr};
    for (const auto& f : fields)
      for (int k = 0; k < 3; ++k)
        if (f.name == std::string(1, static_cast<char>('x' + k))) xyz[k] = &f;
    for (int k = 0; k < 3; ++k) {
      const std::string name(1, static_cast<char>('x' + k));
      if (!xyz[k]) throw InputError("no field '" + name + "' (a PointCloud2 needs x, y, z)");
      if (xyz[k]->datatype != kFloat32 && xyz[k]->datatype != kFloat64)
        throw InputError("field '" + name + "' has datatype " + std::to_string(xyz[k]->datatype) +
                         " (x, y, z must be FLOAT32 (7) or FLOAT64 (8))");
      const uint32_t size = xyz[k]->datatype == kFloat32 ? 4 : 8;
      if (static_cast<uint64_t>(xyz[k]->offset) + size > point_step)
        throw InputError("field '" + name + "' at offset " + std::to_string(xyz[k]->offset) +
                         " does not fit in point_step " + std::to_string(point_step));
    }
    out.points_in = static_cast<size_t>(out.width) * out.height;
    if (out.points_in > 0) {
      if (static_cast<uint64_t>(out.width) * point_step > row_step)
        throw InputError("row_step " + std::to_string(row_step) + " is less than width " +
                         std::to_string(out.width) + " x point_step " + std::to_string(point_step));
      const uint64_t needed =
          static_cast<uint64_t>(row_step) * (out.height - 1) + static_cast<uint64_t>(out.width) * point_step;
      if (needed > bytes.size())
        throw InputError(std::to_string(bytes.size()) + " bytes of data for " +
                         std::to_string(out.height) + " rows of " + std::to_string(out.width) +
                         " points (" + std::to_string(needed) + " needed)");
    }
    out.points.reserve(out.points_in);
    // Rows only when they hold points: a cloud of width 0 may claim 4e9 empty rows (fuzz_bag: a
    // 185-byte message looped over them for seconds).
    const uint32_t rows = out.points_in > 0 ? out.height : 0;
    for (uint32_t r = 0; r < rows; ++r)
      for (uint32_t c = 0; c < out.width; ++c) {
        const char* p = bytes.data() + static_cast<size_t>(r) * row_step + static_cast<size_t>(c) * point_step;
        double v[3];
        for (int k = 0; k < 3; ++k)
          v[k] = xyz[k]->datatype == kFloat32 ? load<float>(p + xyz[k]->offset, big)
                                              : load<double>(p + xyz[k]->offset, big);
        if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2]) ||
            std::abs(v[0]) > 1e30 || std::abs(v[1]) > 1e30 || std::abs(v[2]) > 1e30) {
          ++out.non_finite;
          continue;
        }
        out.points.emplace_back(static_cast<float>(v[0]), static_cast<float>(v[1]),
                                static_cast<float>(v[2]));
      }
  } catch (const Truncated& e) {
    throw InputError(std::string("PointCloud2 cut short: ") + e.what());
  }
  return out;
}

}  // namespace

DecodedCloud decode_pointcloud2(std::string_view data, MessageEncoding encoding) {
  return decode_cloud(data, encoding, false);
}

DecodedCloud decode_pointcloud2_header(std::string_view data, MessageEncoding encoding) {
  return decode_cloud(data, encoding, true);
}

std::vector<TransformSample> decode_tf_message(std::string_view data, MessageEncoding encoding) {
  std::vector<TransformSample> out;
  try {
    Wire w(data, encoding);
    const uint32_t n = w.count("transforms", 64);
    out.resize(n);
    for (auto& t : out) {
      w.header(&t.stamp_ns, &t.parent);
      t.child = w.string("child_frame_id");
      double v[7];
      for (double& x : v) x = w.get<double>("transform");
      Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // x y z w on the wire
      const double norm = q.norm();
      for (double x : v)
        if (!std::isfinite(x))
          throw InputError("transform " + t.parent + " -> " + t.child + " is not finite");
      if (std::abs(norm - 1.0) > 1e-3)
        throw InputError("transform " + t.parent + " -> " + t.child + ": rotation quaternion of norm " +
                         std::to_string(norm) + " (not a rotation)");
      t.parent_from_child = Eigen::Isometry3d::Identity();
      t.parent_from_child.linear() = q.normalized().toRotationMatrix();
      t.parent_from_child.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
      // tf2 frame names carry no leading slash (ROS 1 bags often do).
      for (std::string* f : {&t.parent, &t.child})
        if (!f->empty() && f->front() == '/') f->erase(0, 1);
    }
  } catch (const Truncated& e) {
    throw InputError(std::string("TFMessage cut short: ") + e.what());
  }
  return out;
}

}  // namespace terrastride::perception
