#include "terrastride/perception/bag_clouds.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "terrastride/perception/ros_messages.hpp"
#include "terrastride/perception/tf_buffer.hpp"

namespace terrastride::perception {
namespace {

constexpr const char* kPointCloud2 = "sensor_msgs/PointCloud2";
constexpr const char* kTfMessage = "tf2_msgs/TFMessage";

std::string strip_slash(const std::string& f) {
  return !f.empty() && f.front() == '/' ? f.substr(1) : f;
}

std::string where(const std::string& path, const BagMessage& m) {
  return path + ": " + m.topic->name + " message logged at " + format_stamp(m.log_time_ns) + " s";
}

// A window bound (finite seconds) in ns. Bounds beyond int64's nanoseconds (292 years from the
// epoch or from the first message) saturate: their conversion to int64_t would be undefined.
int64_t window_bound(double seconds, int64_t first_ns) {
  constexpr double kLimit = 9.2e18;  // < 2^63
  const double ns = std::clamp(seconds * 1e9, -kLimit, kLimit);
  if (seconds >= 1e9) return static_cast<int64_t>(ns);
  // first_ns + offset, saturated (both are within +-2^63).
  const int64_t offset = static_cast<int64_t>(ns);
  if (offset > 0 && first_ns > std::numeric_limits<int64_t>::max() - offset)
    return std::numeric_limits<int64_t>::max();
  if (offset < 0 && first_ns < std::numeric_limits<int64_t>::min() - offset)
    return std::numeric_limits<int64_t>::min();
  return first_ns + offset;
}

// A damaged file's problems (a chunk failing its CRC or its decompression), put before an error
// they may explain: the channels a corrupt chunk held are unknown, so "no topic" alone would
// blame the topic name for the file's damage.
std::string damage_first(const BagDamage& d) {
  if (!d.damaged()) return "";
  std::string out = "the file is damaged (";
  const size_t shown = std::min<size_t>(d.problems.size(), 3);
  for (size_t k = 0; k < shown; ++k) out += (k ? "; " : "") + d.problems[k];
  if (d.problems.size() > shown)
    out += "; and " + std::to_string(d.problems.size() - shown) + " more";
  return out + "), and so ";
}

void merge_damage(BagDamage* into, const BagDamage& d) {
  if (into->problems.empty()) *into = d;
}

// Pass 1 over the bag: its transforms into `tf` and the first log time (the time window's zero)
// into stats->first_log_ns. Returns the latest /tf stamp.
int64_t read_transforms(const std::string& path, const BagCloudOptions& options,
                        BagReader& reader, const std::set<std::string>& wanted, TfBuffer* tf_out,
                        BagCloudStats* stats_out) {
  TfBuffer& tf = *tf_out;
  BagCloudStats& stats = *stats_out;
  int64_t first = std::numeric_limits<int64_t>::max();
  int64_t tf_end = std::numeric_limits<int64_t>::min();  // the latest /tf stamp
  std::set<std::string> seen_topics;
  reader.read(
      [&](const BagTopic& t) {
        seen_topics.insert(t.name);
        if (t.name == options.tf_topic || t.name == options.tf_static_topic) {
          if (t.type != kTfMessage)
            throw InputError(path + ": topic " + t.name + " has type " + t.type + ", not " + kTfMessage);
          return true;
        }
        return wanted.count(t.name) > 0;
      },
      [&](const BagMessage& m) {
        first = std::min(first, m.log_time_ns);
        const bool is_static = m.topic->name == options.tf_static_topic;
        if (!is_static && m.topic->name != options.tf_topic) return;
        std::vector<TransformSample> samples;
        try {
          samples = decode_tf_message(m.data, m.topic->encoding);
        } catch (const InputError& e) {
          throw InputError(where(path, m) + ": " + e.what());
        }
        for (auto& s : samples) {
          try {
            tf.add(s, is_static);
          } catch (const InputError& e) {
            throw InputError(where(path, m) + ": " + e.what());
          }
          ++(is_static ? stats.static_transforms : stats.transforms);
          if (!is_static) tf_end = std::max(tf_end, s.stamp_ns);
        }
      });
  stats.first_log_ns = first == std::numeric_limits<int64_t>::max() ? 0 : first;
  return tf_end;
}

// The cloud topics asked for: present, PointCloud2, in an encoding that is read.
void check_cloud_topics(const std::string& path, const BagCloudOptions& options,
                        BagReader& reader, BagCloudStats* stats) {
  std::map<std::string, BagTopic> by_name;
  for (const auto& t : reader.topics()) by_name[t.name] = t;
  for (const auto& name : options.topics) {
    auto it = by_name.find(name);
    if (it == by_name.end()) {
      std::string list;
      for (const auto& [n, t] : by_name)
        if (t.type == kPointCloud2) list += (list.empty() ? "" : ", ") + n;
      throw InputError(path + ": " + damage_first(reader.damage()) + "no topic " + name +
                       " (PointCloud2 topics: " + (list.empty() ? "none" : list) + ")");
    }
    if (it->second.type != kPointCloud2)
      throw InputError(path + ": topic " + name + " has type " + it->second.type + ", not " +
                       kPointCloud2);
    if (it->second.encoding == MessageEncoding::kOther)
      throw InputError(path + ": topic " + name + " is encoded as '" + it->second.encoding_name +
                       "' (CDR and ROS 1 are read)");
    stats->topics[name];
  }
}

// The damage and skipped clouds joined into the figures; no cloud at all is an error saying why.
void finish_bag_stats(const std::string& path, const BagDamage& first_damage,
                      const BagDamage& second_damage, BagCloudStats* stats_out) {
  BagCloudStats& stats = *stats_out;
  stats.damage = second_damage;
  merge_damage(&stats.damage, first_damage);
  for (const auto& [name, t] : stats.topics)
    if (t.after_last_transform > 0)
      stats.damage.problems.push_back(name + ": " + std::to_string(t.after_last_transform) +
                                      " clouds stamped after the last readable transform skipped");
  size_t used = 0;
  for (const auto& [n, t] : stats.topics) used += t.used;
  if (used == 0) {
    std::string why;
    for (const auto& [n, t] : stats.topics)
      why += (why.empty() ? "" : "; ") + n + ": " + std::to_string(t.messages) + " messages, " +
             std::to_string(t.outside_window) + " outside the time window";
    throw InputError(path + ": " + damage_first(stats.damage) + "no cloud selected (" + why + ")");
  }
}

}  // namespace

void read_bag_clouds(const std::string& path, const BagCloudOptions& options,
                     const std::function<void(PointCloud&&, const BagCloudInfo&)>& on_cloud,
                     BagCloudStats* stats_out) {
  if (options.topics.empty()) throw InputError(path + ": no cloud topic given");
  if (options.fixed_frame.empty()) throw InputError(path + ": no fixed frame given");
  if (options.every < 1) throw InputError(path + ": every must be >= 1");
  if ((options.start && !std::isfinite(*options.start)) ||
      (options.end && !std::isfinite(*options.end)))
    throw InputError(path + ": the time window's start and end must be finite numbers of seconds");
  const std::string fixed = strip_slash(options.fixed_frame);
  BagCloudStats stats;
  std::unique_ptr<BagReader> reader = open_bag(path);
  stats.format = reader->format();
  const std::set<std::string> wanted(options.topics.begin(), options.topics.end());

  // Pass 1: the transforms, and the first log time (the window's zero).
  TfBuffer tf;
  const int64_t tf_end = read_transforms(path, options, *reader, wanted, &tf, &stats);
  check_cloud_topics(path, options, *reader, &stats);
  const int64_t lo = options.start ? window_bound(*options.start, stats.first_log_ns)
                                   : std::numeric_limits<int64_t>::min();
  const int64_t hi = options.end ? window_bound(*options.end, stats.first_log_ns)
                                 : std::numeric_limits<int64_t>::max();
  if (options.start && options.end && hi < lo)
    throw InputError(path + ": the time window ends before it starts");
  const BagDamage first_damage = reader->damage();

  // Pass 2: the clouds, one message at a time.
  std::map<std::string, size_t> in_window;
  reader = open_bag(path);
  reader->read([&](const BagTopic& t) { return wanted.count(t.name) > 0; },
               [&](const BagMessage& m) {
                 BagTopicStats& ts = stats.topics[m.topic->name];
                 ++ts.messages;
                 if (m.log_time_ns < lo || m.log_time_ns > hi) {
                   ++ts.outside_window;
                   return;
                 }
                 if (in_window[m.topic->name]++ % static_cast<size_t>(options.every) != 0) {
                   ++ts.skipped_every;
                   return;
                 }
                 DecodedCloud d;
                 try {
                   d = decode_pointcloud2(m.data, m.topic->encoding);
                 } catch (const InputError& e) {
                   throw InputError(where(path, m) + ": " + e.what());
                 }
                 const std::string frame = strip_slash(d.frame_id);
                 Eigen::Isometry3d fixed_from_cloud;
                 try {
                   fixed_from_cloud = tf.lookup(fixed, frame, d.stamp_ns);
                 } catch (const InputError& e) {
                   // A damaged bag's transforms stop where its readable part does: the clouds
                   // after its last transform cannot be placed, and are skipped (counted).
                   if (first_damage.damaged() && d.stamp_ns > tf_end) {
                     ++ts.after_last_transform;
                     return;
                   }
                   throw InputError(where(path, m) + " (cloud in frame '" + frame + "', stamped " +
                                    format_stamp(d.stamp_ns) + " s): " + e.what());
                 }
                 PointCloud cloud;
                 cloud.points.reserve(d.points.size());
                 const Eigen::Isometry3f T = fixed_from_cloud.cast<float>();
                 for (const auto& p : d.points) cloud.points.push_back(T * p);
                 cloud.sensor_origin = fixed_from_cloud.translation();
                 cloud.source = path + ":" + m.topic->name + "@" + format_stamp(d.stamp_ns);
                 ++ts.used;
                 ts.points_in += d.points_in;
                 ts.non_finite += d.non_finite;
                 BagCloudInfo info{m.topic->name, d.stamp_ns, m.log_time_ns, frame, d.points_in,
                                   d.non_finite};
                 on_cloud(std::move(cloud), info);
               });
  finish_bag_stats(path, first_damage, reader->damage(), &stats);
  if (stats_out) *stats_out = std::move(stats);
}

BagListing list_bag(const std::string& path) {
  BagListing out;
  std::unique_ptr<BagReader> reader = open_bag(path);
  out.format = reader->format();
  TfBuffer tf;
  std::map<std::string, BagListing::Topic> topics;
  reader->read([](const BagTopic&) { return true; },
               [&](const BagMessage& m) {
                 BagListing::Topic& t = topics[m.topic->name];
                 if (t.messages == 0) t.first_log_ns = m.log_time_ns;
                 ++t.messages;
                 t.first_log_ns = std::min(t.first_log_ns, m.log_time_ns);
                 t.last_log_ns = std::max(t.last_log_ns, m.log_time_ns);
                 try {
                   if (m.topic->type == kPointCloud2 && m.topic->encoding != MessageEncoding::kOther)
                     t.frames.insert(
                         strip_slash(decode_pointcloud2_header(m.data, m.topic->encoding).frame_id));
                   if (m.topic->type == kTfMessage && m.topic->encoding != MessageEncoding::kOther)
                     for (const auto& s : decode_tf_message(m.data, m.topic->encoding))
                       tf.add(s, m.topic->name == "/tf_static");
                 } catch (const InputError& e) {
                   throw InputError(where(path, m) + ": " + e.what());
                 }
               });
  for (const auto& bt : reader->topics()) {
    BagListing::Topic& t = topics[bt.name];
    t.name = bt.name;
    t.type = bt.type;
    t.encoding = bt.encoding_name;
  }
  for (auto& [n, t] : topics) out.topics.push_back(std::move(t));
  out.tf_links = tf.describe();
  out.frames = tf.frames();
  out.damage = reader->damage();
  return out;
}

}  // namespace terrastride::perception
