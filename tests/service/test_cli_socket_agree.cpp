// The CLI and the socket give the same answers to the same questions: a cloud mapped by
// `terrastride map` and pushed with map.update is cleaned alike (the service skipped the outlier
// removal: heights 0.1485 vs 0.1533 for one cloud); a radius without a safety layer and a point
// outside a scanned map are refused by both; `query --foot-radius -1` is an error, not 0.02; and
// plans on an analytic scene carry no 1e9 "foothold margin" where no edge is in reach.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <octomap/OcTree.h>

#include "support/run_command.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
using terrastride::test_support::run_terrastride;
namespace p = terrastride::service::protocol;

class CliSocketAgree : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::path(::testing::TempDir()) / ("terrastride_agree_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    cloud_ = fs::path(TERRASTRIDE_TEST_DATA_DIR) / "scans" / "pallet_10.pcd";
    map_ = dir_ / "map";
    const auto r = run_terrastride("map " + cloud_.string() + " --out " + map_.string());
    ASSERT_EQ(r.code, 0) << r.all();
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  // `terrastride query MAP --at x,y` → its JSON line.
  static json cli_query(const std::string& at, const std::string& extra = "") {
    const auto r = run_terrastride("query " + map_.string() + " --at " + at + extra);
    EXPECT_EQ(r.code, 0) << r.all();
    return json::parse(r.out.substr(0, r.out.find('\n')), nullptr, false);
  }

  static fs::path dir_, cloud_, map_;
};
fs::path CliSocketAgree::dir_, CliSocketAgree::cloud_, CliSocketAgree::map_;

// Over a ceiling whose floor was never scanned both answer not safe, with the overhang's height and
// why; over the floor beneath a ceiling both give the overhead and the free height.
TEST_F(CliSocketAgree, OverhangsAreAnsweredAlike) {
  const fs::path root = dir_ / "root";
  fs::create_directories(root);
  octomap::OcTree tree(0.05);
  for (double x = 0.025; x < 2.0; x += 0.05)
    for (double y = 0.025; y < 1.0; y += 0.05) {
      if (x < 1.0) {  // a floor seen from above
        tree.updateNode(octomap::point3d(x, y, 0.025), true);
      }
      for (double z = x < 1.0 ? 0.075 : 1.025; z < 2.45; z += 0.05)
        tree.updateNode(octomap::point3d(x, y, z), false);
      tree.updateNode(octomap::point3d(x, y, 2.475), true);  // the ceiling
    }
  ASSERT_TRUE(tree.writeBinaryConst((dir_ / "room.bt").string()));
  const fs::path map = root / "room";
  auto r = run_terrastride("map " + (dir_ / "room.bt").string() + " --out " + map.string());
  ASSERT_EQ(r.code, 0) << r.all();
  r = run_terrastride("query " + map.string() + " --at 0.5,0.5 --at 1.5,0.5");
  ASSERT_EQ(r.code, 0) << r.all();
  std::istringstream lines(r.out);
  std::string line;
  std::vector<json> cli;
  while (std::getline(lines, line)) cli.push_back(json::parse(line));
  ASSERT_EQ(cli.size(), 2u);
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--terrain-root", root.string()});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp(), 60.0);
  c.call_ok({{"op", "map.update"}, {"terrain_dir", "room"}});
  const json sock =
      c.call_ok({{"op", "map.query"}, {"points", {{0.5, 0.5}, {1.5, 0.5}}}})["results"];
  ASSERT_EQ(sock.size(), 2u);
  for (size_t k = 0; k < 2; ++k)
    for (const char* key : {"safe", "observed", "overhead", "free_height", "margin"}) {
      if (sock[k][key].is_number() && cli[k][key].is_number()) {  // the socket rounds to 1 nm
        EXPECT_NEAR(sock[k][key].get<double>(), cli[k][key].get<double>(), 1e-8) << key << k;
      } else {
        EXPECT_EQ(sock[k][key], cli[k][key]) << key << " " << k;
      }
    }
  EXPECT_TRUE(cli[0]["safe"].get<bool>());
  EXPECT_NEAR(cli[0]["overhead"].get<double>(), 2.45, 1e-6);
  EXPECT_NEAR(cli[0]["free_height"].get<double>(), 2.425, 1e-6);
  EXPECT_FALSE(sock[1]["safe"].get<bool>());
  EXPECT_TRUE(sock[1]["free_height"].is_null());
  EXPECT_NE(sock[1]["unsafe_because"].get<std::string>().find("no walkable ground"),
            std::string::npos);
  EXPECT_EQ(sock[1]["unsafe_because"], cli[1]["unsafe_because"]);
}

TEST_F(CliSocketAgree, ACloudIsCleanedAndAnsweredAlike) {
  const auto cloud = terrastride::perception::read_cloud(cloud_.string());
  ASSERT_TRUE(cloud.sensor_origin.has_value());
  p::Attachment points;
  points.name = "points";
  points.shape = {cloud.points.size(), 3};
  points.data.resize(cloud.points.size() * 3 * sizeof(float));
  for (std::size_t i = 0; i < cloud.points.size(); ++i)
    std::memcpy(&points.data[i * 3 * sizeof(float)], cloud.points[i].data(), 3 * sizeof(float));
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp(), 60.0);
  const Eigen::Vector3d o = *cloud.sensor_origin;
  c.call_ok({{"op", "map.update"}, {"origin", {o.x(), o.y(), o.z()}}}, {points});
  // Over the scanned area (pallet top, its edges, the floor): the same height and verdict from
  // both. Without the CLI's outlier removal 95 of 950 such points differed, by up to 0.1 m.
  std::string at;
  json xy = json::array();
  // The socket gets the numbers the CLI reads from its text ("0.300000" is 0.3, while 0.1 * 3 is
  // 0.30000000000000004): these points lie on cell boundaries, where one ulp moves a point into
  // the next cell.
  for (int i = -5; i <= 13; ++i)
    for (int j = -6; j <= 6; ++j) {
      const std::string x = std::to_string(0.1 * i), y = std::to_string(0.1 * j);
      at += " --at " + x + "," + y;
      xy.push_back({std::stod(x), std::stod(y)});
    }
  const auto q = run_terrastride("query " + map_.string() + at);
  ASSERT_EQ(q.code, 0) << q.all();
  std::istringstream lines(q.out);
  const json sock = c.call_ok({{"op", "map.query"}, {"points", xy}})["results"];
  std::string line;
  std::size_t k = 0;
  for (; std::getline(lines, line) && k < sock.size(); ++k) {
    const json cli = json::parse(line);
    EXPECT_NEAR(sock[k]["height"].get<double>(), cli["height"].get<double>(), 1e-6) << line;
    EXPECT_EQ(sock[k]["safe"], cli["safe"]) << line;
    EXPECT_EQ(sock[k]["observed"], cli["observed"]) << line;
  }
  EXPECT_EQ(k, xy.size());
  // Both refuse a radius the map holds no layer for, and a point outside the map.
  auto r = run_terrastride("query " + map_.string() + " --at 1,0 --foot-radius 0.07");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all().find("no safety layer"), std::string::npos) << r.all();
  p::Message m = c.call({{"op", "map.query"}, {"points", {{1.0, 0.0}}}, {"foot_radius", 0.07}});
  EXPECT_EQ(m.header["error"]["code"], "bad_request");
  r = run_terrastride("query " + map_.string() + " --at 40,0");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.all().find("outside the map"), std::string::npos) << r.all();
  m = c.call({{"op", "map.query"}, {"points", {{1.0, 0.0}, {40.0, 0.0}}}});
  EXPECT_EQ(m.header["error"]["code"], "bad_request");
  EXPECT_NE(m.header["error"]["message"].get<std::string>().find("points[1]"), std::string::npos)
      << m.header.dump();
}

TEST_F(CliSocketAgree, ANegativeFootRadiusIsAnError) {
  for (const char* radius : {"-1", "-0.001", "0.6", "nan"}) {
    const auto r = run_terrastride("query " + map_.string() + " --at 1,0 --foot-radius " + radius);
    EXPECT_NE(r.code, 0) << radius;
    EXPECT_NE(r.all().find("--foot-radius"), std::string::npos) << radius << ": " << r.all();
  }
  EXPECT_NEAR(cli_query("1,0")["foot_radius"].get<double>(), 0.02, 1e-12);  // the robot's
}

TEST_F(CliSocketAgree, NoFootholdMarginWhereNoEdgeIsInReach) {
  const fs::path out = dir_ / "flat.json";
  auto r = run_terrastride("plan --terrain flat --duration 2.4 --constraints baseline --out " +
                           out.string());
  ASSERT_EQ(r.code, 0) << r.all();
  std::ifstream in(out);
  const json plan = json::parse(in);
  EXPECT_TRUE(plan["checks"].contains("unsafe_footholds"));
  EXPECT_FALSE(plan["checks"].contains("foothold_margin_min_m")) << plan["checks"].dump();
  // Where an edge is in reach the figure is a distance.
  const fs::path out2 = dir_ / "pallet.json";
  r = run_terrastride("plan --terrain pallet_10 --constraints all --out " + out2.string());
  std::ifstream in2(out2);
  const json p2 = json::parse(in2);
  ASSERT_TRUE(p2["checks"].contains("foothold_margin_min_m")) << p2["checks"].dump();
  EXPECT_LT(p2["checks"]["foothold_margin_min_m"].get<double>(), 1.0);
}

}  // namespace
