// map.update with sensor_msgs/PointCloud2 payloads: a robot pushes the bytes its
// driver publishes (a uint8 attachment "pointcloud2") with the sensor's pose. Through the socket:
// the clouds of the bag fixtures (written by @foxglove/rosmsg2-serialization and Debian's
// python3-rosbag, tests/fixtures/bags/README.md), each pushed with its pose from the bag's /tf,
// give the same map as the same clouds as loose PCD files (placed by the fixtures' generator);
// bad payloads get a bad_request naming the problem and the connection stays usable.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "terrastride/perception/bag.hpp"
#include "terrastride/perception/ros_messages.hpp"
#include "terrastride/perception/tf_buffer.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "terrastride/terrain/map_build.hpp"
#include "test_server_process.hpp"

namespace {

using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
namespace p = terrastride::service::protocol;
namespace perception = terrastride::perception;

std::string fixture(const std::string& name) {
  return std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/bags/" + name;
}

std::string error_code(const p::Message& m) {
  if (m.header.value("ok", true)) return "";
  return m.header["error"].value("code", "");
}
std::string error_message(const p::Message& m) {
  if (m.header.value("ok", true)) return "";
  return m.header["error"].value("message", "");
}

struct RecordedCloud {
  std::string bytes;  // the message as recorded
  json pose;          // [x, y, z, qx, qy, qz, qw] of its frame in odom at its stamp
  std::string frame;
};

// The /points and /points_rear messages of a bag in file order, with their sensors' poses from
// the bag's /tf and /tf_static (what a robot's localisation would give it).
std::vector<RecordedCloud> recorded_clouds(const std::string& path,
                                           perception::MessageEncoding* encoding) {
  perception::TfBuffer tf;
  auto reader = perception::open_bag(path);
  reader->read([](const perception::BagTopic& t) { return t.name == "/tf" || t.name == "/tf_static"; },
               [&](const perception::BagMessage& m) {
                 for (const auto& s : perception::decode_tf_message(m.data, m.topic->encoding))
                   tf.add(s, m.topic->name == "/tf_static");
               });
  std::vector<RecordedCloud> clouds;
  reader = perception::open_bag(path);
  reader->read(
      [](const perception::BagTopic& t) { return t.name == "/points" || t.name == "/points_rear"; },
      [&](const perception::BagMessage& m) {
        *encoding = m.topic->encoding;
        const auto head = perception::decode_pointcloud2_header(m.data, m.topic->encoding);
        std::string frame = head.frame_id;
        if (!frame.empty() && frame.front() == '/') frame.erase(0, 1);
        const Eigen::Isometry3d pose = tf.lookup("odom", frame, head.stamp_ns);
        const Eigen::Quaterniond q(pose.linear());
        const Eigen::Vector3d t = pose.translation();
        clouds.push_back({std::string(m.data), {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()},
                          head.frame_id});
      });
  return clouds;
}

class Pointcloud2Update : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    server_ = std::make_unique<ServerProcess>(
        std::vector<std::string>{"--listen", "tcp://127.0.0.1:0", "--workers", "1"});
    ASSERT_FALSE(server_->tcp().empty()) << server_->output;
  }
  void TearDown() override { EXPECT_EQ(server_->stop(SIGTERM), 0) << server_->output; }
  std::unique_ptr<ServerProcess> server_;
};

// The heights and observed flags on a 2 cm lattice over the map's extent (status), in batches.
std::vector<json> sample_map(Client& c) {
  const json map = c.call_ok({{"op", "status"}})["map"];
  const double x0 = map["min_corner"][0], y0 = map["min_corner"][1];
  const double x1 = map["max_corner"][0], y1 = map["max_corner"][1];
  std::vector<float> xy;
  for (double x = x0 + 0.01; x < x1; x += 0.02)
    for (double y = y0 + 0.01; y < y1; y += 0.02)
      xy.insert(xy.end(), {static_cast<float>(x), static_cast<float>(y)});
  std::vector<json> out;
  for (std::size_t i = 0; i < xy.size(); i += 2 * 5000) {
    const std::vector<float> batch(xy.begin() + i, xy.begin() + std::min(xy.size(), i + 2 * 5000));
    const json r = c.call_ok({{"op", "map.query"}},
                             {p::make_float_attachment("points", {batch.size() / 2, 2}, batch)});
    for (const json& q : r["results"]) out.push_back(q);
  }
  return out;
}

TEST_P(Pointcloud2Update, SameMapAsTheEquivalentPcdFiles) {
  perception::MessageEncoding encoding = perception::MessageEncoding::kOther;
  const std::vector<RecordedCloud> clouds = recorded_clouds(fixture(GetParam()), &encoding);
  ASSERT_EQ(clouds.size(), 18u);
  const std::string encoding_name = encoding == perception::MessageEncoding::kRos1 ? "ros1" : "cdr";
  Client c = Client::connect(server_->tcp());
  json up;
  for (std::size_t k = 0; k < clouds.size(); ++k) {
    up = c.call_ok({{"op", "map.update"},
                    {"mode", k == 0 ? "replace" : "add"},
                    {"pose", clouds[k].pose},
                    {"frame", clouds[k].frame},
                    {"encoding", encoding_name}},
                   {p::make_bytes_attachment("pointcloud2", clouds[k].bytes)});
    EXPECT_EQ(up["source"], "pointcloud2");
    EXPECT_GT(up["stats"]["pointcloud2"]["points"].get<int>(), 100) << up.dump();
  }
  EXPECT_EQ(up["stats"]["clouds"], 18);
  const json stats_pointcloud2 = up["stats"];
  const std::vector<json> from_pointcloud2 = sample_map(c);

  // The same clouds as loose PCDs in odom with their sensor origins, as float32 points.
  std::vector<std::string> pcds;
  {
    std::ifstream list(fixture("pcd/list.txt"));
    for (std::string line; std::getline(list, line);)
      if (!line.empty()) pcds.push_back(fixture("pcd/" + line));
  }
  // World-frame points with the whole sensor pose as VIEWPOINT: its position only.
  terrastride::terrain::CloudPoseOptions world_frame;
  world_frame.viewpoint = terrastride::perception::ViewpointUse::kPosition;
  const terrastride::terrain::MapInput loose =
      terrastride::terrain::read_map_clouds(pcds, world_frame);
  ASSERT_EQ(loose.clouds.size(), 18u);
  for (std::size_t k = 0; k < loose.clouds.size(); ++k) {
    const auto& cl = loose.clouds[k];
    ASSERT_TRUE(cl.sensor_origin.has_value());
    const Eigen::Vector3d o = *cl.sensor_origin;
    up = c.call_ok({{"op", "map.update"},
                    {"mode", k == 0 ? "replace" : "add"},
                    {"origin", {o.x(), o.y(), o.z()}}},
                   {p::make_points_attachment("points", cl.points)});
  }
  for (const char* k : {"nx", "ny", "observed_cells", "filled_cells", "points_in_grid"})
    EXPECT_EQ(up["stats"][k], stats_pointcloud2[k]) << k;
  const std::vector<json> from_points = sample_map(c);
  ASSERT_EQ(from_points.size(), from_pointcloud2.size());

  // The same points in each cloud's sensor frame, with that frame's pose ("pose", as `map
  // --sensor-pose`): the same map.
  for (std::size_t k = 0; k < loose.clouds.size(); ++k) {
    const auto file = terrastride::perception::read_cloud_file(pcds[k]);
    ASSERT_TRUE(file.viewpoint.has_value());
    const terrastride::perception::SensorPose& vp = *file.viewpoint;
    std::vector<Eigen::Vector3f> local;
    for (const Eigen::Vector3f& w : loose.clouds[k].points)
      local.push_back((vp.orientation.inverse() * (w.cast<double>() - vp.position)).cast<float>());
    const Eigen::Quaterniond& q = vp.orientation;
    up = c.call_ok({{"op", "map.update"},
                    {"mode", k == 0 ? "replace" : "add"},
                    {"pose",
                     {vp.position.x(), vp.position.y(), vp.position.z(), q.x(), q.y(), q.z(), q.w()}}},
                   {p::make_points_attachment("points", local)});
  }
  EXPECT_EQ(up["stats"]["placement"]["pose"]["source"], "sensor-pose") << up.dump();
  const std::vector<json> from_posed = sample_map(c);
  ASSERT_EQ(from_posed.size(), from_points.size());
  for (std::size_t i = 0; i < from_posed.size(); ++i) {
    ASSERT_EQ(from_posed[i]["observed"], from_points[i]["observed"]) << i;
    if (from_posed[i]["observed"].get<bool>()) {
      EXPECT_NEAR(from_posed[i]["height"].get<double>(), from_points[i]["height"].get<double>(),
                  1e-3)
          << i;
    }
  }
  int observed = 0;
  for (std::size_t i = 0; i < from_points.size(); ++i) {
    ASSERT_EQ(from_points[i]["observed"], from_pointcloud2[i]["observed"]) << i;
    if (!from_points[i]["observed"].get<bool>()) continue;
    ++observed;
    EXPECT_NEAR(from_points[i]["height"].get<double>(), from_pointcloud2[i]["height"].get<double>(),
                1e-3)
        << i;
  }
  EXPECT_GT(observed, 3000);
}

INSTANTIATE_TEST_SUITE_P(Bags, Pointcloud2Update,
                         ::testing::Values("scan_zstd.mcap", "scan.bag"),
                         [](const auto& info) {
                           return info.param == "scan.bag" ? std::string("Ros1")
                                                           : std::string("Cdr");
                         });

// A PointCloud2 in CDR little endian, written here from the message definition (fields x y z of
// `datatype`, point_step 12 or 24 for float64, one row).
std::string cdr_cloud(const std::vector<Eigen::Vector3f>& pts, const std::string& frame,
                      std::uint8_t datatype = 7, std::uint32_t width_override = 0) {
  std::string b = {0, 1, 0, 0};  // CDR_LE
  auto align = [&](std::size_t n) {
    while ((b.size() - 4) % n) b.push_back(0);
  };
  auto u32 = [&](std::uint32_t v) {
    align(4);
    b.append(reinterpret_cast<const char*>(&v), 4);
  };
  auto str = [&](const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size() + 1));
    b += s;
    b.push_back(0);
  };
  u32(1700000000);  // stamp.sec
  u32(5);           // stamp.nanosec
  str(frame);
  const std::uint32_t size = datatype == 8 ? 8 : 4;
  u32(1);                                                                   // height
  u32(width_override ? width_override : static_cast<std::uint32_t>(pts.size()));  // width
  u32(3);
  for (std::uint32_t k = 0; k < 3; ++k) {
    str(std::string(1, static_cast<char>('x' + k)));
    u32(k * size);
    b.push_back(static_cast<char>(datatype));
    u32(1);
  }
  b.push_back(0);  // is_bigendian
  u32(3 * size);   // point_step
  const std::uint64_t width = width_override ? width_override : pts.size();
  u32(static_cast<std::uint32_t>(std::min<std::uint64_t>(3 * size * width, 0xffffffffu)));  // row_step
  u32(static_cast<std::uint32_t>(3 * size * pts.size()));  // data length
  for (const auto& p : pts)
    for (int k = 0; k < 3; ++k) {
      if (size == 8) {
        const double v = p[k];
        b.append(reinterpret_cast<const char*>(&v), 8);
      } else {
        b.append(reinterpret_cast<const char*>(&p[k]), 4);
      }
    }
  b.push_back(1);  // is_dense
  return b;
}

// A 1 m x 1 m floor 0.5 m below the sensor (the sensor's frame: z up).
std::vector<Eigen::Vector3f> floor_below(float drop) {
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) pts.emplace_back(0.01f * i - 0.5f, 0.01f * j - 0.5f, -drop);
  return pts;
}

// A depth camera's cloud as its driver publishes it: in the optical frame (z forward, x right,
// y down), the pose its body's (x forward, z up), pitched down and turned. With "sensor_frame":
// "optical" it maps as the same points in the world frame with the camera's position as origin.
TEST(Pointcloud2Placement, OpticalFrameCloudGivesTheWorldFrameGrid) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--workers", "1"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  // A floor with a 12 cm box, in the world frame.
  std::vector<Eigen::Vector3f> world;
  for (int i = 0; i < 150; ++i)
    for (int j = 0; j < 100; ++j) {
      const float x = 0.205f + 0.01f * i, y = -0.495f + 0.01f * j;
      const bool box = x > 0.8f && x < 1.2f && y > -0.2f && y < 0.2f;
      world.emplace_back(x, y, box ? 0.12f : 0.0f);
    }
  const Eigen::Vector3d t(-0.4, 0.1, 0.8);
  const Eigen::Quaterniond body = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ()) *
                                  Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitY());  // 40 deg down
  const Eigen::Quaterniond optical(0.5, -0.5, 0.5, -0.5);  // (w, x, y, z): REP 103's optical frame
  const Eigen::Quaterniond world_from_optical = body * optical;
  std::vector<Eigen::Vector3f> local;
  for (const Eigen::Vector3f& w : world)
    local.push_back((world_from_optical.inverse() * (w.cast<double>() - t)).cast<float>());
  // Forward really is the optical z axis: the floor lies ahead of the camera (z > 0).
  EXPECT_GT(local.front().z(), 0.0f);

  Client c = Client::connect(server.tcp());
  const json posed = c.call_ok({{"op", "map.update"},
                                {"mode", "replace"},
                                {"pose", {t.x(), t.y(), t.z(), body.x(), body.y(), body.z(), body.w()}},
                                {"sensor_frame", "optical"},
                                {"up", "check"}},
                               {p::make_bytes_attachment("pointcloud2", cdr_cloud(local, "camera"))});
  const json& placed = posed["stats"]["pointcloud2"];
  EXPECT_EQ(placed["pose"]["sensor_frame"], "optical") << placed.dump();
  EXPECT_EQ(placed["pose"]["source"], "sensor-pose") << placed.dump();
  ASSERT_TRUE(placed["pose"].contains("position")) << placed.dump();
  EXPECT_NEAR(placed["pose"]["position"][2].get<double>(), 0.8, 1e-9);
  ASSERT_TRUE(placed.contains("up")) << placed.dump();
  const std::vector<json> from_optical = sample_map(c);

  c.call_ok({{"op", "map.update"}, {"mode", "replace"}, {"origin", {t.x(), t.y(), t.z()}}},
            {p::make_points_attachment("points", world)});
  const std::vector<json> from_world = sample_map(c);
  const json world_extent = c.call_ok({{"op", "status"}})["map"]["min_corner"];
  ASSERT_EQ(from_optical.size(), from_world.size());
  int observed = 0;
  for (std::size_t i = 0; i < from_world.size(); ++i) {
    ASSERT_EQ(from_optical[i]["observed"], from_world[i]["observed"]) << i;
    if (!from_world[i]["observed"].get<bool>()) continue;
    ++observed;
    EXPECT_NEAR(from_optical[i]["height"].get<double>(), from_world[i]["height"].get<double>(),
                1e-3)
        << i;
  }
  EXPECT_GT(observed, 3000);
  // Taken as a body-frame cloud (the flag left out) the same bytes map elsewhere: the flag counts.
  c.call_ok({{"op", "map.update"},
             {"mode", "replace"},
             {"pose", {t.x(), t.y(), t.z(), body.x(), body.y(), body.z(), body.w()}}},
            {p::make_bytes_attachment("pointcloud2", cdr_cloud(local, "camera"))});
  const json body_extent = c.call_ok({{"op", "status"}})["map"]["min_corner"];
  EXPECT_GT(std::hypot(body_extent[0].get<double>() - world_extent[0].get<double>(),
                       body_extent[1].get<double>() - world_extent[1].get<double>()),
            0.1)
      << body_extent << " " << world_extent;
  EXPECT_EQ(server.stop(SIGTERM), 0) << server.output;
}

TEST(Pointcloud2UpdateErrors, BadPayloadsAreRefusedAndTheConnectionStaysUsable) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--workers", "1"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  const json pose = {2.0, 1.0, 0.6, 0.0, 0.0, 0.0, 1.0};
  const std::string good = cdr_cloud(floor_below(0.5f), "lidar");
  const auto query_at = [&c](double x, double y) {
    return c.call_ok({{"op", "map.query"}, {"points", {{x, y}}}})["results"][0];
  };
  // The pose's rotation is applied: a sensor turned 90 degrees about z sees a strip ahead of it
  // (sensor x in [0.2, 1), |y| <= 0.3; float64 fields), which lands at world y in [1.2, 2).
  std::vector<Eigen::Vector3f> strip;
  for (int i = 0; i < 80; ++i)
    for (int j = 0; j <= 60; ++j) strip.emplace_back(0.2f + 0.01f * i, 0.01f * j - 0.3f, -0.5f);
  const double s = std::sqrt(0.5);
  json up = c.call_ok({{"op", "map.update"},
                       {"mode", "replace"},
                       {"pose", {2.0, 1.0, 0.6, 0.0, 0.0, s, s}},
                       {"encoding", "cdr"}},
                      {p::make_bytes_attachment("pointcloud2", cdr_cloud(strip, "lidar", 8))});
  EXPECT_NEAR(query_at(2.0, 1.6)["height"].get<double>(), 0.1, 1e-3);
  EXPECT_TRUE(query_at(2.0, 1.6)["observed"].get<bool>());
  // Where an unturned sensor would look is off the map.
  const p::Message off = c.call({{"op", "map.query"}, {"points", {{2.6, 1.0}}}});
  EXPECT_NE(error_message(off).find("outside the map"), std::string::npos) << off.header.dump();
  // A good cloud: the floor lands at z = 0.1 around (2, 1).
  up = c.call_ok({{"op", "map.update"}, {"mode", "replace"}, {"pose", pose}, {"frame", "lidar"}},
                 {p::make_bytes_attachment("pointcloud2", good)});
  EXPECT_EQ(up["stats"]["pointcloud2"]["frame"], "lidar");
  EXPECT_EQ(up["stats"]["pointcloud2"]["points"], 10000);
  const auto query = [&query_at] { return query_at(2.0, 1.0); };
  EXPECT_NEAR(query()["height"].get<double>(), 0.1, 1e-3);

  struct Case {
    const char* what;
    json header;
    std::vector<p::Attachment> attachments;
    const char* message_part;
  };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Eigen::Vector3f> all_nan(50, Eigen::Vector3f(nan, nan, nan));
  std::string wrong_type = cdr_cloud(floor_below(0.5f), "lidar", 5);  // INT32
  std::string huge = cdr_cloud(floor_below(0.5f), "lidar", 7, 300'000'000u);
  std::string big_endian_encap = good;
  big_endian_encap[1] = 0;  // says CDR_BE: the lengths read big endian no longer fit
  const json base = {{"op", "map.update"}, {"pose", pose}};
  auto with = [&base](json extra) {
    json h = base;
    for (auto& [k, v] : extra.items()) h[k] = v;
    return h;
  };
  const std::vector<Case> cases = {
      {"truncated", base, {p::make_bytes_attachment("pointcloud2", good.substr(0, good.size() / 2))},
       "cut short"},
      {"cut in the header", base, {p::make_bytes_attachment("pointcloud2", good.substr(0, 30))},
       "cut short"},
      {"empty", base, {p::make_bytes_attachment("pointcloud2", "")}, "shorter than its 4-byte"},
      {"wrong field type", base, {p::make_bytes_attachment("pointcloud2", wrong_type)},
       "datatype 5"},
      {"huge width", base, {p::make_bytes_attachment("pointcloud2", huge)}, "bytes of data"},
      {"byte order", base, {p::make_bytes_attachment("pointcloud2", big_endian_encap)},
       "pointcloud2"},
      {"only NaN points", base,
       {p::make_bytes_attachment("pointcloud2", cdr_cloud(all_nan, "lidar"))},
       "no finite points"},
      {"NaN in the pose", with({{"pose", {2.0, 1.0, nan, 0, 0, 0, 1}}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "pose"},
      {"not a rotation", with({{"pose", {2.0, 1.0, 0.6, 0, 0, 0, 2}}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "norm 2"},
      {"unknown up with pointcloud2", with({{"up", "sideways"}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "\"up\" must be"},
      {"unknown sensor frame with pointcloud2", with({{"sensor_frame", "camera"}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "\"sensor_frame\" must be"},
      {"no pose", {{"op", "map.update"}}, {p::make_bytes_attachment("pointcloud2", good)},
       "needs \"pose\""},
      {"origin instead of pose", with({{"origin", {0, 0, 1}}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "not \"origin\""},
      {"another frame", with({{"frame", "camera"}}), {p::make_bytes_attachment("pointcloud2", good)},
       "'lidar'"},
      {"unknown encoding", with({{"encoding", "json"}}),
       {p::make_bytes_attachment("pointcloud2", good)}, "encoding"},
      {"float32 attachment", base, {p::make_float_attachment("pointcloud2", {3}, {1, 2, 3})},
       "must be uint8"},
      {"uint8 points", {{"op", "map.update"}, {"origin", {0, 0, 1}}},
       {p::make_bytes_attachment("points", "abc")}, "must be float32"},
      {"frame with points", with({{"frame", "lidar"}}),
       {p::make_float_attachment("points", {1, 3}, {1, 2, 3})}, "go with a \"pointcloud2\""},
      {"pose and origin with points", with({{"origin", {0, 0, 1}}}),
       {p::make_float_attachment("points", {1, 3}, {1, 2, 3})}, "give one"},
      {"unknown up", {{"op", "map.update"}, {"up", "sideways"}},
       {p::make_float_attachment("points", {1, 3}, {1, 2, 3})}, "\"up\" must be"},
      {"unknown sensor frame", with({{"sensor_frame", "camera"}}),
       {p::make_float_attachment("points", {1, 3}, {1, 2, 3})}, "\"sensor_frame\" must be"},
      {"points pose not a rotation", {{"op", "map.update"}, {"pose", {0, 0, 1, 0, 0, 0, 2}}},
       {p::make_float_attachment("points", {1, 3}, {1, 2, 3})}, "norm 2"},
      {"two sources", base,
       {p::make_bytes_attachment("pointcloud2", good), p::make_float_attachment("points", {1, 3}, {1, 2, 3})},
       "exactly one source"},
  };
  for (const Case& k : cases) {
    const p::Message m = c.call(k.header, k.attachments);
    EXPECT_EQ(error_code(m), "bad_request") << k.what << ": " << m.header.dump();
    EXPECT_NE(error_message(m).find(k.message_part), std::string::npos)
        << k.what << ": " << error_message(m);
    // The connection and the map are intact.
    EXPECT_NEAR(query()["height"].get<double>(), 0.1, 1e-3) << k.what;
  }
  // An attachment dtype the protocol does not know is a bad_frame reply, and the stream goes on.
  const std::string text = R"({"v":1,"id":7,"op":"map.update","pose":[0,0,0,0,0,0,1],)"
                           R"("attachments":[{"name":"pointcloud2","dtype":"int16","shape":[2]}]})";
  std::string frame(8, '\0');
  p::write_u32be(static_cast<std::uint32_t>(4 + text.size() + 4),
                 reinterpret_cast<unsigned char*>(&frame[0]));
  p::write_u32be(static_cast<std::uint32_t>(text.size()), reinterpret_cast<unsigned char*>(&frame[4]));
  c.send_raw(frame + text + "abcd");
  const p::Message m = c.receive();
  EXPECT_EQ(error_code(m), "bad_frame") << m.header.dump();
  EXPECT_NE(error_message(m).find("uint8"), std::string::npos) << error_message(m);
  EXPECT_NEAR(query()["height"].get<double>(), 0.1, 1e-3);
  const json hello = c.call_ok({{"op", "hello"}});
  EXPECT_EQ(hello["capabilities"]["attachment_dtypes"], json({"float32", "uint8"}));
}

}  // namespace
