// The socket's `simulate` (docs/protocol.md): a plan executed in MuJoCo on the published map, a
// scene or a map folder, as `terrastride simulate` does; bad fields name themselves; cancel stops it.
#include <gtest/gtest.h>

#include <csignal>
#include <string>
#include <vector>

#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;

std::string error_code(const terrastride::service::protocol::Message& m) {
  return m.header.contains("error") ? m.header["error"].value("code", "") : "";
}
std::string error_message(const terrastride::service::protocol::Message& m) {
  return m.header.contains("error") ? m.header["error"].value("message", "") : "";
}

TEST(ServerSimulate, ExecutesAPlanAndJudgesIt) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--workers", "2", "--queue", "4"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  const json hello = c.call_ok({{"op", "hello"}});
  EXPECT_NE(std::find(hello["ops"].begin(), hello["ops"].end(), "simulate"), hello["ops"].end());
  const json plan = c.call_ok({{"op", "plan"}, {"terrain", "flat"}, {"duration", 2.4}});

  // On the exact flat scene: the plan executes (the CLI's flat crawl figures).
  json r = c.call_ok({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}});
  EXPECT_EQ(r["verdict"], "pass") << r["reasons"].dump();
  EXPECT_LT(r["position_error_rms_m"].get<double>(), 0.02);
  EXPECT_NE(r["terrain"].get<std::string>().find("boxes"), std::string::npos);
  EXPECT_FALSE(r.contains("samples"));

  // On the wrong terrain (the 15 cm pallet, published as the current map) it falls: a verdict,
  // not an error.
  c.call_ok({{"op", "map.update"}, {"scene", "pallet_15"}});
  r = c.call_ok({{"op", "simulate"}, {"plan", plan}, {"samples", true}});
  EXPECT_EQ(r["verdict"], "fail") << r.dump();
  EXPECT_TRUE(r["fell"].get<bool>());
  ASSERT_TRUE(r.contains("samples"));
  EXPECT_GT(r["samples"].size(), 10u);

  // A push: a lateral 3 kN shove for 0.3 s in mid-stride topples it.
  r = c.call_ok({{"op", "simulate"},
                 {"plan", plan},
                 {"terrain", "flat"},
                 {"pushes", {{{"t", 1.0}, {"force", {0.0, 3000.0, 0.0}}, {"duration", 0.3}}}}});
  EXPECT_EQ(r["verdict"], "fail") << r.dump();

  // Bad fields name themselves.
  auto m = c.call({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}, {"dt", 0.5}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("dt"), std::string::npos);
  m = c.call({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}, {"pushes", {{{"t", 1}}}}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("pushes[0]"), std::string::npos) << error_message(m);
  m = c.call({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}, {"warp", 9}});
  EXPECT_EQ(error_code(m), "bad_request");
  m = c.call({{"op", "simulate"}, {"plan", json::object()}, {"terrain", "flat"}});
  EXPECT_EQ(error_code(m), "bad_request");
  m = c.call({{"op", "simulate"}, {"plan", plan}, {"terrain", "moon"}});
  EXPECT_EQ(error_code(m), "bad_request");

  // A margin search (about 50 runs) is stopped by its deadline.
  m = c.call({{"op", "simulate"},
              {"plan", plan},
              {"terrain", "flat"},
              {"margin", true},
              {"deadline_ms", 300}});
  EXPECT_EQ(error_code(m), "deadline_exceeded") << m.header.dump();
  EXPECT_EQ(server.stop(SIGTERM), 0) << server.output;
}

}  // namespace
