// ROS 1 bags (format 2.0) through Debian's librosbag_storage, built as the module
// terrastride_rosbag.so (ros1_module.hpp) (rosbag::Bag and rosbag::View): the
// library reads the index, the chunks (bz2/lz4) and the connection headers; this file hands the
// raw serialised messages on. rosbag needs a bag's index (at its end): a bag cut by a crash
// (unindexed) is refused with `rosbag reindex` as the remedy.
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <ros/serialization.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "bag/ros1_module.hpp"

namespace terrastride::perception::bag {
namespace {

class Ros1Reader : public BagReader {
 public:
  explicit Ros1Reader(const std::string& path) : BagReader(path) {
    std::error_code ec;
    damage_.file_bytes = std::filesystem::file_size(path, ec);
    {
      std::ifstream in(path, std::ios::binary);
      char magic[13] = {};
      in.read(magic, 13);
      if (std::string(magic, 13) != "#ROSBAG V2.0\n")
        throw InputError(path + ": not a ROS 1 bag (no '#ROSBAG V2.0' header; ROS 2 bags are "
                                ".mcap or .db3)");
    }
    try {
      bag_.open(path, rosbag::bagmode::Read);
    } catch (const std::exception& e) {
      // rosbag reads the index at the end of the file first: a bag cut by a crash or a copy fails
      // here (unindexed, or a read past the end).
      throw InputError(path + ": rosbag cannot open this ROS 1 bag (" + e.what() +
                       "): a bag cut short has lost its index; `rosbag reindex` on a copy rebuilds "
                       "it from the complete chunks");
    }
    rosbag::View all(bag_);
    for (const rosbag::ConnectionInfo* c : all.getConnections()) {
      if (topics_.count(c->topic)) continue;
      BagTopic t;
      t.name = c->topic;
      t.type = c->datatype;  // ROS 1 names types pkg/Msg already
      t.encoding = MessageEncoding::kRos1;
      t.encoding_name = "ros1";
      topics_[c->topic] = std::move(t);
    }
  }

  std::string format() const override { return "ros1"; }
  std::vector<BagTopic> topics() const override {
    std::vector<BagTopic> out;
    for (const auto& [n, t] : topics_) out.push_back(t);
    return out;
  }

  void read(const std::function<bool(const BagTopic&)>& want,
            const std::function<void(const BagMessage&)>& on) override {
    std::vector<std::string> names;
    for (const auto& [n, t] : topics_)
      if (!want || want(t)) names.push_back(n);
    if (names.empty()) return;
    std::vector<uint8_t> buffer;
    try {
      rosbag::View view(bag_, rosbag::TopicQuery(names));
      for (const rosbag::MessageInstance& m : view) {
        const BagTopic& t = topics_.at(m.getTopic());
        buffer.resize(m.size());
        ros::serialization::OStream out(buffer.data(), static_cast<uint32_t>(buffer.size()));
        m.write(out);
        BagMessage msg;
        msg.topic = &t;
        msg.log_time_ns = static_cast<int64_t>(m.getTime().toNSec());
        msg.data = std::string_view(reinterpret_cast<const char*>(buffer.data()), buffer.size());
        on(msg);
      }
    } catch (const rosbag::BagException& e) {
      damage_.problems.push_back(std::string("rosbag stopped: ") + e.what() +
                                 " (the rest of the file skipped)");
    } catch (const ros::Exception& e) {
      damage_.problems.push_back(std::string("rosbag stopped: ") + e.what() +
                                 " (the rest of the file skipped)");
    }
  }

 private:
  rosbag::Bag bag_;
  std::map<std::string, BagTopic> topics_;
};

}  // namespace

std::unique_ptr<BagReader> open_ros1_module(const std::string& path) {
  return std::make_unique<Ros1Reader>(path);
}

}  // namespace terrastride::perception::bag

extern "C" __attribute__((visibility("default"))) const
    terrastride::perception::bag::RosbagModule*
    terrastride_rosbag_module() {
  static const terrastride::perception::bag::RosbagModule module{
      terrastride::perception::bag::kRosbagModuleVersion,
      &terrastride::perception::bag::open_ros1_module};
  return &module;
}
