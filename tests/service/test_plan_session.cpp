// Planning sessions through the socket (docs/protocol.md, "Planning sessions"): steps
// warm-started from the previous plan, a failed step leaves the session usable, per-step
// deadlines, sessions freed on close and on disconnect, 50 sessions within a memory bound.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
namespace p = terrastride::service::protocol;

std::string error_code(const p::Message& m) {
  return m.header.value("ok", false) ? "" : m.header["error"].value("code", "?");
}

// The flat 2.4 s crawl to x = 0.3 (a cold solve of some 0.1 s), with a 1 s horizon.
json open_request() {
  return {{"op", "plan.session.open"}, {"terrain", "flat"}, {"duration", 2.4},
          {"goal", {0.3, 0.0, 0.0}},   {"horizon", 1.0},     {"sample_dt", 0.02},
          {"constraints", "baseline"}};
}

double rss_kib(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6));
  return -1;
}

int open_sessions(Client& c) { return c.call_ok({{"op", "plan.session.status"}})["open"]; }

TEST(PlanSession, StepsFromAMeasuredStateThenAFailedStepLeavesItUsable) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  const json ref = c.call_ok(open_request());
  const std::string id = ref["session"];
  EXPECT_EQ(ref["solver"]["status"], "optimal");
  // 1 cm beside the plan and 0.05 m/s faster, 0.2 s in.
  json state = {{"base", {{"position", {0.0, 0.01, 0.0}}}}};
  const auto& s = ref["samples"];
  json at;
  for (const auto& smp : s)
    if (std::abs(smp["t"].get<double>() - 0.2) < 1e-9) at = smp;
  ASSERT_FALSE(at.is_null());
  state["base"]["position"] = at["base"]["position"];
  state["base"]["position"][1] = at["base"]["position"][1].get<double>() + 0.01;
  state["base"]["linear_velocity"] = at["base"]["linear_velocity"];
  state["base"]["linear_velocity"][0] = at["base"]["linear_velocity"][0].get<double>() + 0.05;
  const json step = c.call_ok({{"op", "plan.session.step"}, {"session", id}, {"time", 0.2},
                               {"start_state", state}, {"budget_ms", 0}});
  EXPECT_FALSE(step["fallback"].get<bool>());
  EXPECT_EQ(step["solver"]["status"], "optimal");
  EXPECT_DOUBLE_EQ(step["start_time"].get<double>(), 0.2);
  EXPECT_FALSE(step["to_goal"].get<bool>());
  // The plan starts where the robot is.
  EXPECT_NEAR(step["samples"][0]["base"]["position"][1].get<double>(),
              state["base"]["position"][1].get<double>(), 1e-9);
  // A state the robot cannot be in (its base 40 cm up and 40 cm aside of its feet): without a
  // budget a clear error, and the session goes on from its last plan.
  json bad = {{"base", {{"position", {0.3, 0.4, 0.9}}}}};
  const auto failed = c.call({{"op", "plan.session.step"}, {"session", id}, {"time", 0.3},
                              {"start_state", bad}, {"budget_ms", 0}});
  EXPECT_EQ(error_code(failed), "failed") << failed.header.dump();
  EXPECT_NE(failed.header["error"]["message"].get<std::string>().find("still violated"),
            std::string::npos);
  // With a budget (50 ms by default) the same step answers in time with the current plan from
  // 0.3 s, marked as the fallback (its solve failed, or had not finished by the deadline).
  const auto t_fallback = std::chrono::steady_clock::now();
  const json fallback = c.call_ok({{"op", "plan.session.step"}, {"session", id}, {"time", 0.3},
                                   {"start_state", bad}});
  const double fallback_ms = std::chrono::duration<double, std::milli>(
                                 std::chrono::steady_clock::now() - t_fallback).count();
  EXPECT_LT(fallback_ms, 50.0 + 250.0) << "generous slack for ASan and a loaded machine";
  EXPECT_TRUE(fallback["fallback"].get<bool>()) << fallback.dump().substr(0, 400);
  const std::string reason = fallback.value("fallback_reason", "");
  EXPECT_TRUE(reason == "solve_failed" || reason == "deadline") << reason;
  EXPECT_EQ(fallback["solver"]["status"], "fallback");
  for (int k : {0, 1})
    EXPECT_NEAR(fallback["samples"][0]["base"]["position"][k].get<double>(),
                step["samples"][5]["base"]["position"][k].get<double>(), 1e-4)
        << "the fallback is the last plan (from 0.2 s) shifted by 0.1 s (samples 20 ms apart), "
           "not a plan from the unreachable state";
  const json next = c.call_ok({{"op", "plan.session.step"}, {"session", id}, {"time", 0.3},
                               {"budget_ms", 0}});
  EXPECT_EQ(next["solver"]["status"], "optimal");
  // A deadline applies per step: 1 ms is too short for any solve; the session survives it.
  const auto late = c.call({{"op", "plan.session.step"}, {"session", id}, {"time", 0.4},
                            {"deadline_ms", 1}, {"budget_ms", 0}});
  EXPECT_EQ(error_code(late), "deadline_exceeded") << late.header.dump();
  EXPECT_EQ(c.call_ok({{"op", "plan.session.step"}, {"session", id}, {"time", 0.4},
                       {"budget_ms", 0}})["solver"]["status"],
            "optimal");
  EXPECT_EQ(error_code(c.call({{"op", "plan.session.step"}, {"session", id}, {"time", 0.5},
                               {"budget_ms", -1}})),
            "bad_request");
  // Bad requests name their field; another connection cannot use the session.
  EXPECT_EQ(error_code(c.call({{"op", "plan.session.step"}, {"session", id}, {"time", 9.0}})),
            "bad_request");
  Client other = Client::connect(server.tcp());
  EXPECT_EQ(error_code(other.call({{"op", "plan.session.step"}, {"session", id}, {"time", 0.5}})),
            "bad_request");
  EXPECT_EQ(open_sessions(c), 1);
  EXPECT_TRUE(c.call_ok({{"op", "plan.session.close"}, {"session", id}})["closed"].get<bool>());
  EXPECT_EQ(open_sessions(c), 0);
}

// A step's samples as a float32 table ("samples": "attachment"), for clients that re-plan many
// times a second: the same plan as the JSON samples of the same step in a twin session.
TEST(PlanSession, StepSamplesAsATable) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  const std::string as_json = c.call_ok(open_request())["session"];
  const std::string as_table = c.call_ok(open_request())["session"];
  const json state = {{"base", {{"position", {0.05, 0.01, 0.55}}}}};
  const json j = c.call_ok({{"op", "plan.session.step"}, {"session", as_json}, {"time", 0.2},
                            {"start_state", state}, {"budget_ms", 0}});
  const auto reply = c.call({{"op", "plan.session.step"}, {"session", as_table}, {"time", 0.2},
                             {"start_state", state}, {"samples", "attachment"}, {"budget_ms", 0}});
  ASSERT_TRUE(reply.header.value("ok", false)) << reply.header.dump();
  const json& r = reply.header["result"];
  EXPECT_EQ(r["solver"]["iterations"], j["solver"]["iterations"]);
  ASSERT_EQ(reply.attachments.size(), 1u);
  const auto& a = reply.attachments[0];
  EXPECT_EQ(a.name, "samples");
  const auto columns = r["samples"]["columns"].get<std::vector<std::string>>();
  const std::size_t rows = r["samples"]["rows"];
  ASSERT_EQ(rows, j["samples"].size());
  ASSERT_EQ(a.data.size(), rows * columns.size() * sizeof(float));
  std::vector<float> v(rows * columns.size());
  std::memcpy(v.data(), a.data.data(), a.data.size());
  ASSERT_EQ(columns[0], "t");
  ASSERT_EQ(columns[2], "base.position.y");
  for (std::size_t i = 0; i < rows; ++i) {
    EXPECT_NEAR(v[i * columns.size()], j["samples"][i]["t"].get<double>(), 1e-6);
    EXPECT_NEAR(v[i * columns.size() + 2],
                j["samples"][i]["base"]["position"][1].get<double>(), 1e-6);
  }
  EXPECT_EQ(error_code(c.call({{"op", "plan.session.step"}, {"session", as_table}, {"time", 0.3},
                               {"samples", "yaml"}})),
            "bad_request");
}

// The C++ client's session helper (client.hpp, PlanningSession), as the Python client's test
// uses its own: open, a step from a measured state, a failed step that leaves the session usable,
// a per-step deadline, and the destructor closing the session on the server.
TEST(PlanSession, TheClientsSessionHelperOpensStepsAndClosesOnScopeExit) {
  using terrastride::service::ClientError;
  using terrastride::service::PlanningSession;
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  {
    json fields = open_request();
    fields.erase("op");
    PlanningSession s = PlanningSession::open(c, fields);
    EXPECT_TRUE(s.is_open());
    EXPECT_EQ(s.reference()["solver"]["status"], "optimal");
    EXPECT_EQ(open_sessions(c), 1);
    json at;
    for (const auto& smp : s.reference()["samples"])
      if (std::abs(smp["t"].get<double>() - 0.2) < 1e-9) at = smp;
    ASSERT_FALSE(at.is_null());
    json pos = at["base"]["position"];
    pos[1] = pos[1].get<double>() + 0.01;
    const json step = s.step(0.2, {{"base", {{"position", pos}}}}, 0, 0);
    EXPECT_EQ(step["solver"]["status"], "optimal");
    EXPECT_NEAR(step["samples"][0]["base"]["position"][1].get<double>(), pos[1].get<double>(),
                1e-9);
    // A state the robot cannot be in: ClientError with the code first; the session goes on.
    try {
      s.step(0.3, {{"base", {{"position", {0.3, 0.4, 0.9}}}}}, 0, 0);
      ADD_FAILURE() << "an unreachable state was planned";
    } catch (const ClientError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind("plan.session.step: failed: ", 0), 0u) << what;
      EXPECT_NE(what.find("still violated"), std::string::npos) << what;
    }
    EXPECT_EQ(s.step(0.3, nullptr, 0, 0)["solver"]["status"], "optimal");
    try {
      s.step(0.4, nullptr, 1, 0);
      ADD_FAILURE() << "a 1 ms step deadline was met";
    } catch (const ClientError& e) {
      EXPECT_NE(std::string(e.what()).find("deadline_exceeded"), std::string::npos) << e.what();
    }
    EXPECT_EQ(s.step(0.4, nullptr, 0, 0)["solver"]["status"], "optimal");
    // Moved, the session is the new owner's to close.
    PlanningSession moved = std::move(s);
    EXPECT_FALSE(s.is_open());
    EXPECT_EQ(open_sessions(c), 1);
  }
  EXPECT_EQ(open_sessions(c), 0);
  // A bad open names the field.
  try {
    PlanningSession::open(c, {{"terrain", "flat"}, {"horizon", -1.0}});
    ADD_FAILURE() << "a negative horizon was accepted";
  } catch (const ClientError& e) {
    EXPECT_NE(std::string(e.what()).find("horizon"), std::string::npos) << e.what();
  }
  // Closed explicitly, a step is refused by the client.
  PlanningSession closed = PlanningSession::open(c, [] {
    json f = open_request();
    f.erase("op");
    return f;
  }());
  closed.close();
  closed.close();
  EXPECT_EQ(open_sessions(c), 0);
  EXPECT_THROW(closed.step(0.2), ClientError);
}

TEST(PlanSession, DisconnectFreesTheSession) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client watcher = Client::connect(server.tcp());
  {
    Client c = Client::connect(server.tcp());
    c.call_ok(open_request());
    EXPECT_EQ(open_sessions(watcher), 1);
  }  // the client leaves without closing its session
  int open = 1;
  for (int i = 0; i < 200 && open != 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    open = open_sessions(watcher);
  }
  EXPECT_EQ(open, 0);
}

// 50 sessions at once on one server: the server's resident memory grows by less than 100 MiB
// (each session holds its reference and last plans, about 0.1 MiB on the flat crawl at 20 ms
// samples; the 11 s pallet crawl at 10 ms holds 1.1 MB), and closing them all frees the table.
TEST(PlanSession, FiftySessionsStayWithinTheMemoryBound) {
  // All on one connection: beyond its default quota of 8.
  ServerProcess server({"--listen", "tcp://127.0.0.1:0", "--max-sessions-per-connection", "50"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  Client c = Client::connect(server.tcp());
  c.call_ok(open_request());  // the first loads the scene, the solver and MuJoCo-free code paths
  const double before = rss_kib(server.pid());
  std::size_t session_bytes = 0;
  for (int i = 1; i < 50; ++i) session_bytes += c.call_ok(open_request())["memory_bytes"].get<std::size_t>();
  EXPECT_EQ(open_sessions(c), 50);
  const double after = rss_kib(server.pid());
  EXPECT_LT(after - before, 100.0 * 1024) << "RSS " << before << " -> " << after << " KiB";
  EXPECT_LT(session_bytes, std::size_t{49} << 20);
  // Each still steps.
  EXPECT_EQ(c.call_ok({{"op", "plan.session.step"}, {"session", "s50"}, {"time", 0.1},
                       {"budget_ms", 0}})["solver"]["status"],
            "optimal");
  c.close();
  Client watcher = Client::connect(server.tcp());
  int open = 50;
  for (int i = 0; i < 200 && open != 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    open = open_sessions(watcher);
  }
  EXPECT_EQ(open, 0);
}

}  // namespace
