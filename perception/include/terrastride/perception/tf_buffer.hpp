// The transforms of a recording (/tf and /tf_static) and their lookup at a time, as tf2 does it:
// frames form a tree (each child has one parent); a dynamic transform is interpolated between the
// two samples around the time (translation linearly, rotation by slerp) and never extrapolated;
// a static one holds at every time.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "terrastride/perception/ros_messages.hpp"

namespace terrastride::perception {

class TfBuffer {
 public:
  // Throws InputError when the child already has another parent (tf2 allows one).
  void add(const TransformSample& sample, bool is_static);

  // target_from_source at `time_ns`. Throws InputError naming both frames and the time: a frame
  // the buffer never saw, frames in different trees, or a dynamic link without samples on both
  // sides of the time (with the span it does cover).
  Eigen::Isometry3d lookup(const std::string& target, const std::string& source,
                           int64_t time_ns) const;

  bool empty() const { return links_by_child_.empty(); }
  // Every frame named (parents and children), sorted.
  std::vector<std::string> frames() const;
  // "parent -> child (static|N samples)" per link, for listings and errors.
  std::vector<std::string> describe() const;

 private:
  struct Link {
    std::string parent;
    bool is_static = false;
    std::vector<std::pair<int64_t, Eigen::Isometry3d>> samples;  // by time (static: the latest)
  };
  Eigen::Isometry3d link_at(const std::string& child, const Link& link, int64_t time_ns,
                            const std::string& target, const std::string& source) const;
  // The frames from `frame` up to its root, `frame` first.
  std::vector<std::string> chain(const std::string& frame) const;
  std::map<std::string, Link> links_by_child_;
};

// Seconds with nanoseconds, for messages ("1700000000.123456789").
std::string format_stamp(int64_t time_ns);

}  // namespace terrastride::perception
