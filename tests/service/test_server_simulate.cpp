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
  const json plan = c.call_ok(
      {{"op", "plan"}, {"terrain", "flat"}, {"duration", 2.4}, {"constraints", "baseline"}});

  // On the exact flat scene: the plan executes (the CLI's flat crawl figures).
  json r = c.call_ok({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}});
  EXPECT_EQ(r["verdict"], "pass") << r["reasons"].dump();
  EXPECT_LT(r["position_error_rms_m"].get<double>(), 0.02);
  EXPECT_NE(r["terrain"].get<std::string>().find("boxes"), std::string::npos);
  EXPECT_FALSE(r.contains("samples"));
  // With the constrained stance forces too (undisturbed, they are the clipped ones but where a
  // foot would leave its friction pyramid).
  r = c.call_ok(
      {{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}, {"force_distribution", "constrained"}});
  EXPECT_EQ(r["verdict"], "pass") << r["reasons"].dump();

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
  m = c.call(
      {{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}, {"force_distribution", "qp"}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("force_distribution"), std::string::npos) << error_message(m);
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

// What the simulation cannot judge is refused, naming the field, before a worker runs it; what
// cannot finish within the op's wall-time limit is refused up front (`too_large`). A plan ending at
// t = 1e9 "passed" after 0 steps, a base at 1e300 m "warned" with an infinite RMS, and a 120 s
// plan at dt 1e-4 ran 301 s until its connection closed without a reply (a margin search on it
// would have held the worker for an hour).
TEST(ServerSimulate, RefusesWhatItCannotJudgeOrFinish) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--workers", "1", "--queue", "4"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  const json plan = c.call_ok(
      {{"op", "plan"}, {"terrain", "flat"}, {"duration", 2.4}, {"constraints", "baseline"}});
  ASSERT_TRUE(plan["samples"].is_array());
  const auto call = [&](const json& p, json extra = json::object()) {
    json request = {{"op", "simulate"}, {"plan", p}, {"terrain", "flat"}};
    request.update(extra);
    return c.call(request);
  };

  json late = plan;
  late["samples"].back()["t"] = 1e9;
  auto m = call(late);
  EXPECT_EQ(error_code(m), "bad_request") << m.header.dump().substr(0, 400);
  EXPECT_NE(error_message(m).find("samples from t = 0 to 1e+09 s"), std::string::npos) << error_message(m);

  json far = plan;
  far["samples"][100]["base"]["position"][0] = 1e300;
  m = call(far);
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("samples[100].base.position is 1e+300 m"), std::string::npos)
      << error_message(m);

  m = call(plan, {{"pushes", {{{"t", 1.0}, {"force", {0.0, 5e5, 0.0}}, {"duration", 0.2}}}}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("pushes[0].force: 500000 N, more than the 100000 N"), std::string::npos)
      << error_message(m);
  m = call(plan, {{"pushes", {{{"t", 1.0}, {"force", {0.0, 100.0, 0.0}}, {"duration", 500}}}}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("pushes[0].duration"), std::string::npos) << error_message(m);

  // A 120 s plan (its first sample held for 120 s) at dt 1e-4: 1.2 M steps, and with the margin
  // up to 56 runs of them. Refused before it starts, naming the limit.
  json held = plan;
  held["samples"] = json::array({plan["samples"][0], plan["samples"][0]});
  held["samples"][1]["t"] = 120.0;
  held["duration"] = 120.0;
  m = call(held, {{"dt", 1e-4}, {"margin", true}});
  EXPECT_EQ(error_code(m), "too_large") << m.header.dump().substr(0, 400);
  EXPECT_NE(error_message(m).find("1200000 steps"), std::string::npos) << error_message(m);
  EXPECT_NE(error_message(m).find("56 margin runs"), std::string::npos) << error_message(m);
  EXPECT_NE(error_message(m).find("beyond the 240 s a simulate request may run"), std::string::npos)
      << error_message(m);
  // Half as long at twice the step: 300 k steps, 56 runs, 252 s at 15 us a step.
  held["samples"][1]["t"] = 60.0;
  held["duration"] = 60.0;
  m = call(held, {{"dt", 2e-4}, {"margin", true}});
  EXPECT_EQ(error_code(m), "too_large") << m.header.dump().substr(0, 400);
  EXPECT_NE(error_message(m).find("300000 steps"), std::string::npos) << error_message(m);

  // The worker is free: the plan itself still runs.
  const json r = c.call_ok({{"op", "simulate"}, {"plan", plan}, {"terrain", "flat"}});
  EXPECT_EQ(r["verdict"], "pass") << r["reasons"].dump();
  EXPECT_FALSE(r["unstable"].get<bool>());
  EXPECT_EQ(server.stop(SIGTERM), 0) << server.output;
}

}  // namespace
