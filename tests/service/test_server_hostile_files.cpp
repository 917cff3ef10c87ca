// Hostile input to a server. Files under its terrain root: a terrain folder whose octomap.bt is
// corrupt (a body of 0xFF bytes made OctoMap's recursive reader overflow the stack, and `serve`
// died of SIGSEGV on map.update {"terrain_dir": "bad"}). The reply is an error naming the file,
// and the server keeps serving the same and other connections. A request header nested millions
// of levels deep is refused as bad JSON.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "support/run_command.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

namespace fs = std::filesystem;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
namespace p = terrastride::service::protocol;

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void write(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// Terrain folders under one root: "good" as `terrastride map` writes it from the committed
// OctoMap fixture, and copies of it whose octomap.bt is corrupted in the ways named below.
class HostileTerrainRoot : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::path(::testing::TempDir()) / ("ts_hostile_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    const auto r = terrastride::test_support::run_terrastride(
        "map " + std::string(TERRASTRIDE_SOURCE_DIR) + "/tests/fixtures/octomap/pallet_10.bt" +
        " --out " + (root_ / "good").string());
    ASSERT_EQ(r.code, 0) << r.err;
    const std::string bt = slurp(root_ / "good" / "octomap.bt");
    const size_t body = bt.find("\ndata\n") + 6;
    ASSERT_GT(body, 6u);
    std::string random(3000, '\0');
    std::srand(5);
    for (char& c : random) c = static_cast<char>(std::rand());
    // 4 MB of 0xFF: OctoMap's reader recursed until the stack overflowed and the server died.
    corrupt("ff", bt.substr(0, body) + std::string(1 << 22, '\xff'));
    corrupt("random", bt.substr(0, body) + random);
    corrupt("cut", bt.substr(0, body + (bt.size() - body) / 2));
    corrupt("trailing", bt + "trailing bytes");
  }
  void TearDown() override { fs::remove_all(root_); }

  void corrupt(const std::string& name, const std::string& bytes) {
    fs::copy(root_ / "good", root_ / name, fs::copy_options::recursive);
    write(root_ / name / "octomap.bt", bytes);
    names_.push_back(name);
  }

  fs::path root_;
  std::vector<std::string> names_;
};

TEST_F(HostileTerrainRoot, CorruptOctomapIsAnErrorReplyAndTheServerKeepsServing) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--terrain-root", root_.string()});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp(), 60.0);
  for (const std::string& name : names_) {
    const p::Message m = c.call({{"op", "map.update"}, {"terrain_dir", name}});
    ASSERT_FALSE(m.header.value("ok", true)) << name;
    EXPECT_EQ(m.header["error"].value("code", ""), "bad_request") << name;
    const std::string message = m.header["error"].value("message", "");
    EXPECT_NE(message.find(name + "/octomap.bt"), std::string::npos) << message;
    ASSERT_TRUE(server.running()) << name << ": " << server.output;
  }
  // The same connection, and a new one, still get answers; the good folder still loads.
  EXPECT_TRUE(c.call({{"op", "map.update"}, {"terrain_dir", "good"}}).header.value("ok", false));
  Client::connect(server.tcp()).call_ok({{"op", "status"}});
  EXPECT_EQ(server.stop(SIGTERM), 0) << server.output;
}

// A request nested 2 million levels deep inside the 4 MiB header cap: a `check` whose plan
// holds such an extra key parsed, and copying it into the plan overflowed the stack (`serve`
// died of SIGSEGV). It is refused as bad JSON at the frame, and the server keeps serving.
TEST(HostileRequests, DeeplyNestedHeaderIsBadJsonAndTheServerKeepsServing) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp(), 60.0);
  const std::size_t levels = 2'000'000;
  const std::string header = R"({"v":1,"id":7,"op":"check","terrain":"flat","plan":{"notes":)" +
                             std::string(levels, '[') + std::string(levels, ']') + "}}";
  ASSERT_LE(header.size(), p::kMaxHeaderBytes);
  const auto length = [](std::size_t n) {
    std::string prefix(4, '\0');
    p::write_u32be(static_cast<std::uint32_t>(n), reinterpret_cast<unsigned char*>(&prefix[0]));
    return prefix;
  };
  const std::string body = length(header.size()) + header;
  c.send_raw(length(body.size()) + body);
  const p::Message m = c.receive();
  ASSERT_FALSE(m.header.value("ok", true)) << m.header.dump();
  EXPECT_EQ(m.header["error"].value("code", ""), "bad_json");
  EXPECT_NE(m.header["error"].value("message", "").find("nested more than 100 levels deep"),
            std::string::npos)
      << m.header.dump();
  ASSERT_TRUE(server.running()) << server.output;
  Client::connect(server.tcp()).call_ok({{"op", "status"}});
  EXPECT_EQ(server.stop(SIGTERM), 0) << server.output;
}

}  // namespace
