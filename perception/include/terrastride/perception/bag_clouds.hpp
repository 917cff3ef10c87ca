// Point clouds from a recording: every sensor_msgs/PointCloud2 of the chosen topics placed in a
// fixed frame with the sensor origin at its own time stamp (from /tf and /tf_static, interpolated),
// so an OctoMap carves free space from where the sensor was. And the listing `map --list` prints.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

struct BagCloudOptions {
  std::vector<std::string> topics;  // PointCloud2 topics to read (at least one)
  std::string fixed_frame;          // the frame every cloud is placed in (e.g. odom, map)
  // Time window on the messages' log times, in seconds: from the bag's first message when below
  // 1e9, else seconds since the epoch. nullopt: open.
  std::optional<double> start, end;
  int every = 1;  // use every N-th cloud of each topic (1 = all)
  std::string tf_topic = "/tf";
  std::string tf_static_topic = "/tf_static";
};

struct BagCloudInfo {
  std::string topic;
  int64_t stamp_ns = 0;    // header.stamp: the time the cloud was placed at
  int64_t log_time_ns = 0;
  std::string frame_id;
  size_t points_in = 0;    // width x height
  size_t non_finite = 0;   // NaN/inf points dropped
};

struct BagTopicStats {
  size_t messages = 0;       // on the topic, in the file's readable part
  size_t used = 0;           // delivered
  size_t outside_window = 0;
  size_t skipped_every = 0;
  size_t after_last_transform = 0;  // damaged bags: clouds past the readable transforms, skipped
  size_t points_in = 0, non_finite = 0;  // of the used clouds
};

struct BagCloudStats {
  std::string format;
  std::map<std::string, BagTopicStats> topics;
  size_t transforms = 0, static_transforms = 0;
  int64_t first_log_ns = 0;  // of the messages read (tf and clouds)
  BagDamage damage;
};

// Reads the bag twice: the transforms first (small), then the clouds one message at a time;
// `on_cloud` receives each placed cloud (points in `fixed_frame`, sensor_origin set, source
// "PATH:TOPIC@STAMP") and may move it. Throws InputError naming the file and, for a message, its
// topic and time: a topic the bag lacks or that is not PointCloud2, a message that does not
// decode, a cloud whose frame has no transform to the fixed frame at its stamp (naming both frames
// and the time), no cloud selected. A truncated or corrupt tail is not an error: stats->damage
// says what was skipped, including the clouds stamped after the last transform the damaged file
// still holds (they cannot be placed).
void read_bag_clouds(const std::string& path, const BagCloudOptions& options,
                     const std::function<void(PointCloud&&, const BagCloudInfo&)>& on_cloud,
                     BagCloudStats* stats = nullptr);

struct BagListing {
  struct Topic {
    std::string name, type, encoding;
    size_t messages = 0;
    int64_t first_log_ns = 0, last_log_ns = 0;
    std::set<std::string> frames;  // header.frame_id of its clouds (PointCloud2 topics)
  };
  std::string format;
  std::vector<Topic> topics;
  std::vector<std::string> tf_links;  // TfBuffer::describe
  std::vector<std::string> frames;    // every tf frame
  BagDamage damage;
};

// One pass over the bag: topics, types, counts, time spans, the frames of the clouds and the tf
// tree. Throws InputError as read_bag_clouds.
BagListing list_bag(const std::string& path);

}  // namespace terrastride::perception
