// libFuzzer target for the recording readers: everything `terrastride map RUN.mcap`
// and the server's map.update "pointcloud2" run on untrusted bytes.
// - Input starting with the MCAP magic: written to a scratch .mcap file and read by open_bag
//   (records, chunks and their zstd/lz4 decompression and CRCs), list_bag and read_bag_clouds
//   (tf buffer, interpolation, placing clouds).
// - Input starting with SQLite's header: the same as a .db3 (rosbag2's schema through SQLite).
// - Input starting with "#ROSBAG V2.0": the same as a ROS 1 .bag: the check of its records
//   (ros1_check.cpp), then, in the regular suite's replay, librosbag through the module.
// - Anything else: one message, decoded as sensor_msgs/PointCloud2 and tf2_msgs/TFMessage, in
//   CDR and in ROS 1 serialisation, and its transforms looked up in a tf buffer.
// Every failure must be an InputError; a decoded cloud must account for all its points. Build and
// run: tests/fuzz/run.sh (Debian clang with libclang-rt-14-dev); the regular suite replays the
// seed corpus tests/fuzz/corpus_bag (BagFuzzCorpus.Replay).
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>

#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/bag_clouds.hpp"
#include "terrastride/perception/ros_messages.hpp"
#include "terrastride/perception/tf_buffer.hpp"

namespace {

namespace pe = terrastride::perception;

void exercise_message(std::string_view data) {
  for (const pe::MessageEncoding enc : {pe::MessageEncoding::kCdr, pe::MessageEncoding::kRos1}) {
    try {
      const pe::DecodedCloud c = pe::decode_pointcloud2(data, enc);
      // Every point of width x height is either kept or counted as dropped.
      if (c.points.size() + c.non_finite != c.points_in) __builtin_trap();
      if (c.points_in != static_cast<std::size_t>(c.width) * c.height) __builtin_trap();
    } catch (const pe::InputError&) {
    }
    try {
      (void)pe::decode_pointcloud2_header(data, enc);
    } catch (const pe::InputError&) {
    }
    try {
      const auto samples = pe::decode_tf_message(data, enc);
      pe::TfBuffer tf;
      for (const auto& s : samples) tf.add(s, /*is_static=*/false);
      for (const auto& s : samples) {
        (void)tf.lookup(samples.front().parent, s.child, s.stamp_ns);
        (void)tf.lookup(s.child, samples.back().child, s.stamp_ns + 1);
      }
    } catch (const pe::InputError&) {
    }
  }
}

// A scratch folder per process, rewritten for every input. The folder is removed by its owner's
// destructor: an atexit handler registered while the static is being built runs after the static's
// destructor (reverse order of registration) and read a freed string under ASan.
struct ScratchDir {
  std::string path;
  ScratchDir() {
    const char* base = std::getenv("TMPDIR");
    path = std::string(base && *base ? base : "/tmp") + "/fuzz-bag-XXXXXX";
    if (!::mkdtemp(path.data())) std::abort();
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
};

const std::string& scratch(const char* extension) {
  static const ScratchDir dir;
  static const std::string mcap = dir.path + "/in.mcap", db3 = dir.path + "/in.db3",
                           bag = dir.path + "/in.bag";
  if (std::strcmp(extension, ".mcap") == 0) return mcap;
  return std::strcmp(extension, ".bag") == 0 ? bag : db3;
}

void exercise_file(std::string_view data, const char* extension) {
  const std::string& path = scratch(extension);
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data.data(), 1, data.size(), f);
    std::fclose(f);
  } else {
    std::abort();
  }
  std::vector<std::string> cloud_topics;
  try {
    auto reader = pe::open_bag(path);
    reader->read([](const pe::BagTopic&) { return true; },
                 [&](const pe::BagMessage& m) {
                   if (m.topic->type == "sensor_msgs/PointCloud2" ||
                       m.topic->type == "tf2_msgs/TFMessage")
                     exercise_message(m.data);
                 });
    for (const auto& t : reader->topics())
      if (t.type == "sensor_msgs/PointCloud2") cloud_topics.push_back(t.name);
  } catch (const pe::InputError&) {
  }
  try {
    (void)pe::list_bag(path);
  } catch (const pe::InputError&) {
  }
  if (cloud_topics.empty()) return;
  pe::BagCloudOptions options;
  options.topics = cloud_topics;
  options.fixed_frame = "odom";
  try {
    pe::read_bag_clouds(path, options, [](pe::PointCloud&& cloud, const pe::BagCloudInfo&) {
      if (!cloud.sensor_origin) __builtin_trap();  // every placed cloud has its origin
    });
  } catch (const pe::InputError&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  static constexpr std::string_view kMcapMagic("\x89MCAP0\r\n", 8);
  static constexpr std::string_view kSqliteMagic("SQLite format 3\0", 16);
  if (bytes.substr(0, kMcapMagic.size()) == kMcapMagic)
    exercise_file(bytes, ".mcap");
  else if (bytes.substr(0, kSqliteMagic.size()) == kSqliteMagic)
    exercise_file(bytes, ".db3");
  else if (bytes.substr(0, 13) == "#ROSBAG V2.0\n")
    exercise_file(bytes, ".bag");
  else
    exercise_message(bytes);
  return 0;
}
