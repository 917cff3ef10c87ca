// Mixed load on one server at its default settings: plan clients (each plan a forked process)
// while other clients open and step planning sessions (solved in the server's threads), publish
// maps and simulate. A plan process forked while a session thread was inside the solver inherited
// the sequential MUMPS's state half-way through a factorisation and died of heap corruption
// ("double free or corruption", signal 6) in some of its own solves; plans alone never did. The
// server's `status` counts plan processes that died; under this load it must stay at zero.
//
// TERRASTRIDE_MIXED_LOAD_SECONDS sets the load's length (default 40 s; the soak in docs/design.md
// runs 600 s). Every request loop is bounded by that time and loopback only.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <map>
#include <mutex>
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
using Clock = std::chrono::steady_clock;

double load_seconds() {
  const char* s = std::getenv("TERRASTRIDE_MIXED_LOAD_SECONDS");
  return s ? std::max(1.0, std::atof(s)) : 40.0;
}

// Outcomes per kind of request: ok, or the error code.
class Tally {
 public:
  void add(const std::string& kind, const p::Message& m) {
    std::lock_guard<std::mutex> lock(mu_);
    const std::string code =
        m.header.value("ok", false) ? "ok" : m.header["error"].value("code", "?");
    counts_[kind + ":" + code]++;
    if (code != "ok" && messages_.size() < 20)
      messages_.push_back(kind + ": " + m.header["error"].value("message", std::string()));
  }
  int count(const std::string& key) const {
    std::lock_guard<std::mutex> lock(mu_);
    const auto it = counts_.find(key);
    return it == counts_.end() ? 0 : it->second;
  }
  std::string summary() const {
    std::lock_guard<std::mutex> lock(mu_);
    std::string s;
    for (const auto& [k, n] : counts_) s += k + "=" + std::to_string(n) + " ";
    for (const auto& m : messages_) s += "\n  " + m;
    return s;
  }

 private:
  mutable std::mutex mu_;
  std::map<std::string, int> counts_;
  std::vector<std::string> messages_;
};

// Cold plans (a flat crawl, and the pallet_10 crawl with every set), each in its own process.
void plan_client(const std::string& address, Clock::time_point until, int seed, Tally* tally) {
  Client c = Client::connect(address);
  for (int k = seed; Clock::now() < until; ++k) {
    json req = {{"op", "plan"}, {"sample_dt", 0.02}, {"deadline_ms", 60000}};
    if (k % 2) {
      req["terrain"] = "pallet_10";
      req["constraints"] = {"all"};
    } else {
      req.update({{"terrain", "flat"},
                  {"duration", 2.4},
                  {"goal", {0.3, 0.0, 0.0}},
                  {"constraints", "baseline"}});
    }
    tally->add("plan", c.call(req));
  }
}

// Sessions solved in the server's threads: open, step every 0.1 s from states 1 cm beside the
// reference (so every step iterates), close; again.
void session_client(const std::string& address, Clock::time_point until, Tally* tally) {
  Client c = Client::connect(address);
  while (Clock::now() < until) {
    // The benchmark's session: the pallet_15 crawl with every constraint set, 1 s horizon.
    const p::Message open = c.call({{"op", "plan.session.open"}, {"terrain", "pallet_15"},
                                    {"constraints", {"all"}}, {"horizon", 1.0},
                                    {"sample_dt", 0.02}});
    tally->add("session.open", open);
    if (!open.header.value("ok", false)) continue;
    const json& ref = open.header["result"];
    const std::string id = ref["session"];
    for (int s = 1; s <= 40 && Clock::now() < until; ++s) {
      const double t = 0.1 * s;
      json at;
      for (const auto& smp : ref["samples"])
        if (std::abs(smp["t"].get<double>() - t) < 1e-9) at = smp;
      if (at.is_null()) break;
      json pos = at["base"]["position"];
      pos[1] = pos[1].get<double>() + ((s % 2) ? 0.01 : -0.01);
      tally->add("session.step", c.call({{"op", "plan.session.step"},
                                         {"session", id},
                                         {"time", t},
                                         {"start_state", {{"base", {{"position", pos}}}}}}));
    }
    tally->add("session.close", c.call({{"op", "plan.session.close"}, {"session", id}}));
  }
}

// Maps published while the others plan: a scene, then a small cloud added to it.
void map_client(const std::string& address, Clock::time_point until, Tally* tally) {
  Client c = Client::connect(address);
  std::vector<Eigen::Vector3f> cloud;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) cloud.emplace_back(0.05f * i - 1.0f, 0.05f * j - 1.0f, 0.0f);
  while (Clock::now() < until) {
    tally->add("map.scene", c.call({{"op", "map.update"}, {"scene", "pallet_10"}}));
    tally->add("map.cloud", c.call({{"op", "map.update"}, {"mode", "replace"},
                                    {"origin", {0.0, 0.0, 1.0}}},
                                   {p::make_points_attachment("points", cloud)}));
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
}

// Simulations (MuJoCo, in the server's threads) of one short plan.
void simulate_client(const std::string& address, Clock::time_point until, Tally* tally) {
  Client c = Client::connect(address);
  const p::Message plan = c.call({{"op", "plan"}, {"terrain", "flat"}, {"duration", 2.4},
                                  {"goal", {0.3, 0.0, 0.0}}, {"sample_dt", 0.02}});
  tally->add("plan", plan);
  if (!plan.header.value("ok", false)) return;
  while (Clock::now() < until)
    tally->add("simulate", c.call({{"op", "simulate"}, {"plan", plan.header["result"]},
                                   {"terrain", "flat"}}));
}

TEST(MixedLoad, PlansBesideSessionsMapsAndSimulationsLoseNoPlanProcess) {
  ServerProcess server({"--listen", "tcp://127.0.0.1:0"});
  ASSERT_FALSE(server.tcp().empty()) << server.output;
  const std::string address = server.tcp();
  const auto until =
      Clock::now() + std::chrono::milliseconds(static_cast<long>(load_seconds() * 1000));
  Tally tally;
  std::vector<std::thread> clients;
  for (int k = 0; k < 3; ++k) clients.emplace_back(plan_client, address, until, k, &tally);
  for (int k = 0; k < 2; ++k) clients.emplace_back(session_client, address, until, &tally);
  clients.emplace_back(map_client, address, until, &tally);
  clients.emplace_back(simulate_client, address, until, &tally);
  for (auto& t : clients) t.join();

  ASSERT_TRUE(server.running()) << server.output;
  Client c = Client::connect(address);
  const json status = c.call_ok({{"op", "status"}});
  const json& processes = status["plan_processes"];
  std::printf("MIXED_LOAD seconds=%.0f plan_processes=%s %s\n", load_seconds(),
              processes.dump().c_str(), tally.summary().c_str());
  EXPECT_EQ(processes["died"].get<int>(), 0) << tally.summary();
  // The load did what it says: plans and steps ran at once, and every plan was answered.
  EXPECT_GT(tally.count("plan:ok"), 3) << tally.summary();
  EXPECT_GT(tally.count("session.step:ok"), 3) << tally.summary();
  EXPECT_EQ(tally.count("plan:failed"), 0) << tally.summary();
  EXPECT_GT(processes["started"].get<int>(), 3);
}

}  // namespace
