// Faults and abuse of the plan path (issue #13): plans at once on one server (Debian's MUMPS is
// not re-entrant: two concurrent plans crashed `serve` in 11 of 11 tries), cancelled and
// crashing plan processes, the request limits shared with `terrastride plan`, and file paths a
// client names. Loopback only; every wait is bounded.
#include <gtest/gtest.h>
#include <signal.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "support/run_command.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
namespace p = terrastride::service::protocol;

std::string error_code(const p::Message& m) {
  if (m.header.value("ok", true)) return "";
  return m.header["error"].value("code", "");
}
std::string error_message(const p::Message& m) {
  if (m.header.value("ok", true)) return "";
  return m.header["error"].value("message", "");
}

json flat_plan(const std::string& constraints = "baseline",
               const std::string& samples = "attachment") {
  return {{"op", "plan"},      {"terrain", "flat"},          {"duration", 2.4},
          {"goal", {1, 0, 0}}, {"constraints", constraints}, {"samples", samples}};
}

json status_of(const std::string& address) {
  return Client::connect(address).call_ok({{"op", "status"}});
}

// Waits (bounded) until the server reports no plan process running.
int running_plan_processes(const std::string& address) {
  int running = -1;
  for (int tries = 0; tries < 400; ++tries) {
    running = status_of(address)["plan_processes"]["running"].get<int>();
    if (running == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return running;
}

class ServerFaults : public ::testing::Test {
 protected:
  void start(std::vector<std::string> extra = {}) {
    std::vector<std::string> args{"--listen", "tcp://127.0.0.1:0", "--workers",
                                  "4",        "--queue",           "16"};
    args.insert(args.end(), extra.begin(), extra.end());
    server_ = std::make_unique<ServerProcess>(args);
    ASSERT_FALSE(server_->tcp().empty()) << server_->output;
    address_ = server_->tcp();
    Client::connect(address_).call_ok({{"op", "map.update"}, {"scene", "pallet_10"}});
  }
  void TearDown() override {
    if (server_) {
      EXPECT_EQ(server_->stop(SIGTERM), 0) << server_->output;
    }
  }
  std::unique_ptr<ServerProcess> server_;
  std::string address_;
};

// 2, 4 and 8 plans at once on separate connections, with checks and terrain queries between
// them: every plan solves, the server stays up, and no plan process is left behind.
TEST_F(ServerFaults, ConcurrentPlansMixedWithChecksAndQueries) {
  start();
  const json reference = Client::connect(address_).call_ok(flat_plan("baseline", "json"));
  ASSERT_EQ(reference["solver"]["status"], "optimal");
  for (int n : {2, 4, 8}) {
    std::atomic<int> optimal{0}, checks_ok{0}, queries_ok{0};
    std::vector<std::string> problems(n);
    std::vector<std::thread> threads;
    for (int i = 0; i < n; ++i)
      threads.emplace_back([&, i] {
        try {
          Client c = Client::connect(address_, 60.0);
          const json r = c.call_ok(flat_plan(i % 2 ? "baseline" : "foot"));
          if (r["solver"]["status"] == "optimal") optimal++;
          if (c.call_ok({{"op", "check"}, {"plan", reference}})["checks"].contains(
                  "torque_ratio_max"))
            checks_ok++;
          if (c.call_ok({{"op", "map.query"}, {"points", {{1.0, 0.0}}}})["results"].size() == 1)
            queries_ok++;
        } catch (const std::exception& e) {
          problems[i] = e.what();
        }
      });
    for (auto& t : threads) t.join();
    for (int i = 0; i < n; ++i) EXPECT_EQ(problems[i], "") << n << " at once, client " << i;
    EXPECT_EQ(optimal, n);
    EXPECT_EQ(checks_ok, n);
    EXPECT_EQ(queries_ok, n);
    ASSERT_TRUE(server_->running()) << server_->output;
  }
  // Two plans pipelined on one connection.
  Client c = Client::connect(address_, 60.0);
  json a = flat_plan(), b = flat_plan();
  a["id"] = "a";
  b["id"] = "b";
  c.send(a);
  c.send(b);
  EXPECT_EQ(error_code(c.wait_for("b")), "");
  EXPECT_EQ(error_code(c.wait_for("a")), "");
  const json st = status_of(address_);
  EXPECT_EQ(st["plan_processes"]["died"], 0) << st.dump();
  EXPECT_GE(st["plan_processes"]["started"].get<int>(), 2 + 4 + 8 + 2);
  EXPECT_EQ(running_plan_processes(address_), 0);
}

// A cancelled plan's process is killed at once, and the next plan runs normally.
TEST_F(ServerFaults, CancelKillsThePlanProcess) {
  start();
  Client c = Client::connect(address_, 60.0);
  c.send({{"op", "plan"}, {"id", "long"}, {"terrain", "pallet_15"}, {"constraints", "all"}});
  for (int tries = 0; tries < 400; ++tries) {
    if (status_of(address_)["plan_processes"]["running"] == 1) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(c.call_ok({{"op", "cancel"}, {"target", "long"}})["cancelled"], true);
  EXPECT_EQ(error_code(c.wait_for("long")), "cancelled");
  EXPECT_EQ(running_plan_processes(address_), 0);
  EXPECT_GE(status_of(address_)["plan_processes"]["stopped"].get<int>(), 1);
  EXPECT_EQ(c.call_ok(flat_plan())["solver"]["status"], "optimal");
}

// The server's child processes (plan processes), from /proc.
std::vector<int> children_of(int pid) {
  std::vector<int> out;
  for (const auto& task : fs::directory_iterator("/proc/" + std::to_string(pid) + "/task")) {
    std::ifstream in(task.path() / "children");
    int child;
    while (in >> child) out.push_back(child);
  }
  return out;
}

// A plan process that dies (here: killed, as the out-of-memory killer would) fails alone: its
// request gets an error reply naming the signal, and the server keeps serving.
TEST_F(ServerFaults, APlanProcessThatDiesFailsAlone) {
  start();
  Client c = Client::connect(address_, 60.0);
  c.send({{"op", "plan"}, {"id", "victim"}, {"terrain", "pallet_15"}, {"constraints", "all"}});
  std::vector<int> children;
  for (int tries = 0; tries < 400 && children.empty(); ++tries) {
    children = children_of(server_->pid());
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  ASSERT_EQ(children.size(), 1u);
  ::kill(children[0], SIGKILL);
  const p::Message m = c.wait_for("victim");
  EXPECT_EQ(error_code(m), "failed") << m.header.dump();
  EXPECT_NE(error_message(m).find("signal 9"), std::string::npos) << error_message(m);
  EXPECT_TRUE(server_->running());
  EXPECT_EQ(status_of(address_)["plan_processes"]["died"], 1);
  EXPECT_EQ(c.call_ok(flat_plan())["solver"]["status"], "optimal");
}

// One set of limits for the CLI and the socket, each refusal naming the field.
TEST_F(ServerFaults, RequestLimitsNameTheField) {
  start();
  Client c = Client::connect(address_, 60.0);
  const std::vector<std::pair<json, std::string>> cases = {
      {{{"duration", 1e9}}, "duration: "},   {{{"duration", 0}}, "duration: "},
      {{{"sample_dt", 2e-5}}, "sample_dt: "}, {{{"sample_dt", 1e-9}}, "sample_dt: "},
      {{{"cycles", 51}}, "cycles: "},         {{{"cycles", 2.5}}, "cycles: "},
      {{{"max_time", -1}}, "max_time: "},     {{{"goal", {1e7, 0, 0}}}, "goal: "},
      {{{"cycles", 50}, {"duration", nullptr}}, "cycles: "}};
  for (const auto& [fields, field] : cases) {
    json req = {{"op", "plan"}, {"terrain", "flat"}};
    req.update(fields);
    const p::Message m = c.call(req);
    EXPECT_EQ(error_code(m), "bad_request") << req.dump();
    EXPECT_NE(error_message(m).find(field), std::string::npos)
        << req.dump() << ": " << error_message(m);
  }
  // The same limits in `terrastride plan`, refused before anything is loaded or solved.
  const std::vector<std::pair<std::string, std::string>> cli = {
      {"--duration 1e9", "--duration"},    {"--duration 0", "--duration"},
      {"--sample-dt 2e-5", "--sample-dt"}, {"--sample-dt 1e-9", "--sample-dt"},
      {"--cycles 51", "--cycles"},         {"--cycles 50", "--cycles"}};
  const std::string out = (fs::path(::testing::TempDir()) / "limits_plan.json").string();
  for (const auto& [flags, field] : cli) {
    const auto r = terrastride::test_support::run_terrastride("plan --terrain flat " + flags +
                                                              " --out " + out);
    EXPECT_NE(r.code, 0) << flags;
    EXPECT_NE(r.all().find(field), std::string::npos) << flags << ": " << r.all();
    EXPECT_FALSE(fs::exists(out)) << flags;
  }
}

// The server opens no file a client names unless it was started with a terrain root, and then
// only terrain directories inside it; the replies do not reveal what exists elsewhere.
TEST_F(ServerFaults, ClientsCannotNameFilesOutsideTheDataFolders) {
  const fs::path root = fs::path(::testing::TempDir()) / ("ts_root_" + std::to_string(::getpid()));
  fs::create_directories(root / "empty");
  start({"--terrain-root", root.string()});
  Client c = Client::connect(address_, 60.0);
  for (const char* gait : {"/etc/shadow", "/etc/no-such-file", "../../etc/passwd", "x.yaml"}) {
    const p::Message m = c.call({{"op", "plan"}, {"terrain", "flat"}, {"gait", gait}});
    EXPECT_EQ(error_code(m), "bad_request") << gait;
    EXPECT_EQ(error_message(m).find("no such"), std::string::npos) << error_message(m);
    EXPECT_NE(error_message(m).find("crawl"), std::string::npos) << error_message(m);
  }
  // A directory outside the root and one that does not exist get the same answer.
  std::string first;
  for (const char* dir : {"/etc", "/no/such/dir", "../../..", "empty/../../.."}) {
    const p::Message m = c.call({{"op", "map.update"}, {"terrain_dir", dir}});
    EXPECT_EQ(error_code(m), "bad_request") << dir;
    std::string msg = error_message(m);
    msg.erase(msg.find(dir), std::string(dir).size());
    if (first.empty()) first = msg;
    EXPECT_EQ(msg, first) << dir;
  }
  // A robot file named by a plan in `check` is refused likewise.
  json plan = Client::connect(address_).call_ok(flat_plan("baseline", "json"));
  EXPECT_EQ(error_code(c.call({{"op", "check"}, {"plan", plan}})), "");
  plan["robot"] = "/etc/shadow";
  const p::Message m = c.call({{"op", "check"}, {"plan", plan}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("robot name"), std::string::npos) << error_message(m);
  fs::remove_all(root);
}

// Every operation refuses fields it does not read (a misspelt option used to be ignored), and
// the socket takes the constraint sets' settings as the CLI's --feasibility does.
TEST_F(ServerFaults, MisspeltFieldsAreRefusedAndFeasibilitySettingsAreRead) {
  start();
  Client c = Client::connect(address_, 60.0);
  json req = flat_plan();
  req["optimise_timing"] = true;
  p::Message m = c.call(req);
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("optimize_timing"), std::string::npos) << error_message(m);
  for (const json& bad : {json{{"op", "map.query"}, {"points", {{1, 0}}}, {"radius", 0.02}},
                          json{{"op", "map.update"}, {"scene", "flat"}, {"resolutoin", 0.02}},
                          json{{"op", "map.clear"}, {"all", true}},
                          json{{"op", "check"}, {"plan", json::object()}, {"terain", "flat"}}})
    EXPECT_EQ(error_code(c.call(bad)), "bad_request") << bad.dump();
  req = flat_plan("all");
  req["feasibility"] = {{"no_such_setting", 1.0}};
  m = c.call(req);
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("no_such_setting"), std::string::npos) << error_message(m);
  req["feasibility"] = {{"foot_margin", "wide"}};
  EXPECT_EQ(error_code(c.call(req)), "bad_request");
  req = flat_plan("foot");
  req["feasibility"] = {{"foot_margin", 0.01}};
  const json r = c.call_ok(req);
  EXPECT_EQ(r["solver"]["status"], "optimal");
  EXPECT_EQ(r["feasibility_settings"]["foot_margin"], 0.01) << r.dump().substr(0, 400);
}

}  // namespace
