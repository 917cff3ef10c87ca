// Robot recordings as input: ROS 2 bags (MCAP, sqlite3 .db3) and ROS 1 .bag files,
// read message by message. The readers stream: an MCAP file is read one record (one chunk) at a
// time, a .db3 one row at a time, a ROS 1 bag through librosbag_storage's chunked reader; memory
// holds one chunk, not the file.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

// How a message's bytes are serialised.
enum class MessageEncoding { kCdr, kRos1, kOther };

struct BagTopic {
  std::string name;
  std::string type;  // ROS type as the bag names it, normalised to "pkg/Msg" ("pkg/msg/Msg" too)
  MessageEncoding encoding = MessageEncoding::kCdr;
  std::string encoding_name;  // as the file says ("cdr", "ros1", "json", ...)
};

struct BagMessage {
  const BagTopic* topic = nullptr;
  int64_t log_time_ns = 0;  // when the recorder received it (ns since the epoch)
  std::string_view data;    // valid during the callback only
};

// What a read skipped: a truncated tail (the bytes after the last complete record) or corrupt
// chunks (skipped, the reading goes on after them).
struct BagDamage {
  bool damaged() const { return !problems.empty(); }
  std::vector<std::string> problems;  // one sentence each, with the byte offset
  uint64_t skipped_bytes = 0;         // bytes of the file whose messages were not delivered
  uint64_t file_bytes = 0;
};

class BagReader {
 public:
  virtual ~BagReader() = default;
  const std::string& path() const { return path_; }
  // Calls `on` for every message of the topics `want` accepts, in file order (which is log-time
  // order for the recorders' files). A truncated or corrupt tail is not an error: the messages
  // before it are delivered and damage() says what was skipped. A file that is not a bag of its
  // kind, or whose structure is broken before any message, throws InputError naming the path.
  virtual void read(const std::function<bool(const BagTopic&)>& want,
                    const std::function<void(const BagMessage&)>& on) = 0;
  // Every topic the file declares (known after read(), and for MCAP/.db3 after open).
  virtual std::vector<BagTopic> topics() const = 0;
  const BagDamage& damage() const { return damage_; }
  virtual std::string format() const = 0;  // "mcap", "sqlite3", "ros1"

 protected:
  explicit BagReader(std::string path) : path_(std::move(path)) {}
  std::string path_;
  BagDamage damage_;
};

// True for .mcap, .db3 and .bag (case-insensitive) and for a rosbag2 folder (a directory with
// metadata.yaml).
bool is_bag_file(const std::string& path);

// Opens a bag by its extension (.mcap, .db3, .bag), checking its magic, or a rosbag2 folder: its
// storage files in metadata.yaml's order (split recordings), read one after the other as one
// recording. Throws InputError.
std::unique_ptr<BagReader> open_bag(const std::string& path);

// The type name without "/msg/": "sensor_msgs/msg/PointCloud2" -> "sensor_msgs/PointCloud2".
std::string normalise_type(const std::string& type);

}  // namespace terrastride::perception
