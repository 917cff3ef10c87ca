// sensor_msgs/PointCloud2 decoding (the decoder bags and the server's map.update share): clouds
// whose field list is empty or names a field twice, or whose data holds bytes beyond
// height x row_step, are refused naming the problem (they used to be accepted), in CDR and ROS 1.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "perception/test_util.hpp"
#include "terrastride/perception/ros_messages.hpp"

namespace terrastride::perception {
namespace {

using test::expect_input_error;

struct FieldSpec {
  std::string name;
  uint32_t offset;
};

// A PointCloud2 written from the message definition: FLOAT32 fields, `points` points of
// point_step 12 in each of `height` rows, `extra` bytes appended to data.
std::string cloud_message(MessageEncoding encoding, const std::vector<FieldSpec>& fields,
                          uint32_t points, uint32_t extra = 0, uint32_t height = 1) {
  const bool cdr = encoding == MessageEncoding::kCdr;
  std::string b;
  if (cdr) b = std::string("\0\1\0\0", 4);  // CDR_LE
  const auto align = [&](size_t n) {
    if (cdr)
      while ((b.size() - 4) % n) b.push_back(0);
  };
  const auto u32 = [&](uint32_t v) {
    align(4);
    b.append(reinterpret_cast<const char*>(&v), 4);
  };
  const auto str = [&](const std::string& s) {
    u32(static_cast<uint32_t>(s.size() + (cdr ? 1 : 0)));
    b += s;
    if (cdr) b.push_back(0);
  };
  if (!cdr) u32(7);  // header.seq
  u32(1700000000);
  u32(5);
  str("lidar");
  u32(height);
  u32(points);  // width
  u32(static_cast<uint32_t>(fields.size()));
  for (const auto& f : fields) {
    str(f.name);
    u32(f.offset);
    b.push_back(7);  // FLOAT32
    u32(1);
  }
  b.push_back(0);       // is_bigendian
  u32(12);              // point_step
  u32(12 * points);     // row_step
  u32(12 * points * height + extra);
  for (uint32_t i = 0; i < 3 * points * height; ++i) {
    const float v = 0.1f * static_cast<float>(i);
    b.append(reinterpret_cast<const char*>(&v), 4);
  }
  b.append(extra, '\x7f');
  b.push_back(1);  // is_dense
  return b;
}

const std::vector<FieldSpec> kXyz = {{"x", 0}, {"y", 4}, {"z", 8}};

class Pointcloud2Decoder : public ::testing::TestWithParam<MessageEncoding> {};

TEST_P(Pointcloud2Decoder, AcceptsAWellFormedCloud) {
  const DecodedCloud c = decode_pointcloud2(cloud_message(GetParam(), kXyz, 4), GetParam());
  EXPECT_EQ(c.points.size(), 4u);
  EXPECT_EQ(c.frame_id, "lidar");
}

TEST_P(Pointcloud2Decoder, RefusesNoFields) {
  expect_input_error([&] { decode_pointcloud2(cloud_message(GetParam(), {}, 4), GetParam()); },
                     {"no fields", "field count 0"});
  // No fields and no points: still not a cloud.
  expect_input_error([&] { decode_pointcloud2(cloud_message(GetParam(), {}, 0), GetParam()); },
                     {"field count 0"});
}

TEST_P(Pointcloud2Decoder, RefusesDuplicateFieldNames) {
  for (const auto& fields : std::vector<std::vector<FieldSpec>>{
           {{"x", 0}, {"y", 4}, {"z", 8}, {"x", 4}},
           {{"x", 0}, {"y", 4}, {"z", 8}, {"intensity", 8}, {"intensity", 8}}}) {
    const std::string twice = fields.back().name;
    expect_input_error(
        [&] { decode_pointcloud2(cloud_message(GetParam(), fields, 4), GetParam()); },
        {"field '" + twice + "' is declared twice"});
  }
}

TEST_P(Pointcloud2Decoder, RefusesBytesBeyondHeightTimesRowStep) {
  for (const uint32_t extra : {1u, 12u, 1000u})
    expect_input_error(
        [&] { decode_pointcloud2(cloud_message(GetParam(), kXyz, 4, extra), GetParam()); },
        {std::to_string(extra) + " trailing bytes beyond height 1 x row_step 48 = 48"});
  // An empty cloud with data.
  expect_input_error(
      [&] { decode_pointcloud2(cloud_message(GetParam(), kXyz, 0, 12), GetParam()); },
      {"12 trailing bytes"});
}

// No points in many rows (width 0) is an empty cloud: its rows are not walked (a message of 4e9
// empty rows, found by fuzz_bag, looped over them for seconds). Points in several rows all read.
TEST_P(Pointcloud2Decoder, EmptyRowsAreAnEmptyCloud) {
  const DecodedCloud empty =
      decode_pointcloud2(cloud_message(GetParam(), kXyz, 0, 0, 4'000'000'000u), GetParam());
  EXPECT_EQ(empty.height, 4'000'000'000u);
  EXPECT_EQ(empty.points_in, 0u);
  EXPECT_TRUE(empty.points.empty());
  const DecodedCloud rows = decode_pointcloud2(cloud_message(GetParam(), kXyz, 2, 0, 3), GetParam());
  EXPECT_EQ(rows.points_in, 6u);
  EXPECT_EQ(rows.points.size(), 6u);
}

INSTANTIATE_TEST_SUITE_P(Encodings, Pointcloud2Decoder,
                         ::testing::Values(MessageEncoding::kCdr, MessageEncoding::kRos1),
                         [](const auto& info) {
                           return info.param == MessageEncoding::kCdr ? std::string("Cdr")
                                                                      : std::string("Ros1");
                         });

}  // namespace
}  // namespace terrastride::perception
