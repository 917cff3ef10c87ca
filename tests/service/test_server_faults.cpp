// Faults and abuse of the plan path: plans at once on one server (Debian's MUMPS is
// not re-entrant: two concurrent plans crashed `serve` in 11 of 11 tries), cancelled and
// crashing plan processes, the request limits shared with `terrastride plan`, and file paths a
// client names; then the fault suite of the limits: session hogs, session requests in order, plans
// the server wrote sent back, and a soak of clients that never read, stalled huge frames and
// connection and session hogs after which the server's memory returns to its idle figure.
// Loopback only; every wait is bounded.
#include <gtest/gtest.h>
#include <signal.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "support/run_command.hpp"
#include "support/sanitizer.hpp"
#include "terrastride/service/client.hpp"
#include "terrastride/service/protocol.hpp"
#include "test_server_process.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using terrastride::service::Client;
using terrastride::test::ServerProcess;
using terrastride::test_support::kAddressSanitizer;
// How long a test waits for a reply (a plan among several at once).
constexpr double kReplyTimeout = 60.0 * terrastride::test_support::kTimeoutScale;
namespace p = terrastride::service::protocol;

// A client whose replies may take `timeout` s (Client::connect's timeout bounds the connection
// only; a reply waits Client::set_timeout's, 30 s unless set).
Client connect_client(const std::string& address, double timeout = kReplyTimeout) {
  Client c = Client::connect(address, timeout);
  c.set_timeout(timeout);
  return c;
}

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
  // Under AddressSanitizer a plan's forked child can wait forever on ASan's allocator mutex, which
  // another server thread held when it forked (gdb: SizeClassAllocator64::GetFromAllocator under
  // Ipopt's option registration); glibc's malloc, which the product runs on, takes its arena locks
  // around fork. With 4 and 8 plans at once it happened in each of three runs.
  if (kAddressSanitizer) GTEST_SKIP() << "forked plan children can deadlock in ASan's allocator";
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
          Client c = connect_client(address_);
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
  Client c = connect_client(address_);
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
  Client c = connect_client(address_);
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
  Client c = connect_client(address_);
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
  Client c = connect_client(address_);
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
  Client c = connect_client(address_);
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
  // A plan carries its robot file: a name that disagrees with it is refused, nothing is read.
  const p::Message carried = c.call({{"op", "check"}, {"plan", plan}});
  EXPECT_EQ(error_code(carried), "bad_request");
  EXPECT_NE(error_message(carried).find("robot_file it carries"), std::string::npos)
      << error_message(carried);
  // Without it (an older plan), the name is looked up among the shipped robots only.
  plan.erase("robot_file");
  const p::Message m = c.call({{"op", "check"}, {"plan", plan}});
  EXPECT_EQ(error_code(m), "bad_request");
  EXPECT_NE(error_message(m).find("robot name"), std::string::npos) << error_message(m);
  fs::remove_all(root);
}

// Every operation refuses fields it does not read (a misspelt option used to be ignored), and
// the socket takes the constraint sets' settings as the CLI's --feasibility does.
TEST_F(ServerFaults, MisspeltFieldsAreRefusedAndFeasibilitySettingsAreRead) {
  start();
  Client c = connect_client(address_);
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

// A 2.4 s flat plan with JSON samples: the reference sessions open from (`init`, no solve).
json flat_reference(const std::string& address) {
  json r = connect_client(address).call_ok(flat_plan("baseline", "json"));
  return r;
}

json open_from(const json& reference) {
  return {{"op", "plan.session.open"}, {"terrain", "flat"}, {"init", reference}, {"horizon", 1.0}};
}

// Without a budget: these tests are about the session table, and wait for each step's solve.
json step_at(const std::string& session, double time) {
  return {{"op", "plan.session.step"}, {"session", session}, {"time", time},
          {"samples", "attachment"}, {"budget_ms", 0}};
}

// A connection holding its quota of planning sessions (8 by default) gets `busy` for another,
// while a second client opens a session and plans (one connection could take all 64 before).
TEST_F(ServerFaults, ASessionHogDoesNotKeepOthersOut) {
  start();
  const json reference = flat_reference(address_);
  Client hog = connect_client(address_);
  for (int i = 0; i < 8; ++i) hog.call_ok(open_from(reference));
  const p::Message refused = hog.call(open_from(reference));
  EXPECT_EQ(error_code(refused), "busy");
  EXPECT_NE(error_message(refused).find("--max-sessions-per-connection"), std::string::npos)
      << error_message(refused);
  Client other = connect_client(address_);
  const std::string mine = other.call_ok(open_from(reference))["session"];
  EXPECT_EQ(other.call_ok(step_at(mine, 0.1))["solver"]["status"], "optimal");
  const json st = other.call_ok({{"op", "plan.session.status"}});
  EXPECT_EQ(st["open"], 9);
  EXPECT_EQ(st["per_connection"], 8);
}

// When the server holds --max-sessions, opening one closes the longest idle session (not the
// one just stepped), and a step on the closed one says why it is gone.
TEST_F(ServerFaults, AFullSessionTableMakesRoomByClosingTheLongestIdle) {
  start({"--max-sessions", "4", "--max-sessions-per-connection", "2"});
  const json reference = flat_reference(address_);
  Client hog = connect_client(address_);
  const std::string first = hog.call_ok(open_from(reference))["session"];
  hog.call_ok(open_from(reference));
  Client other = connect_client(address_);
  const std::string mine = other.call_ok(open_from(reference))["session"];
  Client hog2 = connect_client(address_);
  hog2.call_ok(open_from(reference));
  EXPECT_EQ(other.call_ok(step_at(mine, 0.1))["solver"]["status"], "optimal");
  Client late = connect_client(address_);
  const std::string late_id = late.call_ok(open_from(reference))["session"];
  EXPECT_EQ(late.call_ok(step_at(late_id, 0.1))["solver"]["status"], "optimal");
  const json st = other.call_ok({{"op", "plan.session.status"}});
  EXPECT_EQ(st["open"], 4);
  EXPECT_EQ(st["evicted"], 1);
  const p::Message gone = hog.call(step_at(first, 0.1));
  EXPECT_EQ(error_code(gone), "bad_request");
  EXPECT_NE(error_message(gone).find("to make room"), std::string::npos) << error_message(gone);
  EXPECT_EQ(other.call_ok(step_at(mine, 0.2))["solver"]["status"], "optimal");
}

// Requests of one session are answered in the order they were sent: a close pipelined after two
// steps is answered after them (it used to overtake them); a malformed start_state is
// bad_request in a step as in plan.
TEST_F(ServerFaults, SessionRequestsAreAnsweredInOrder) {
  start();
  const json reference = flat_reference(address_);
  Client c = connect_client(address_);
  const std::string id = c.call_ok(open_from(reference))["session"];
  json a = step_at(id, 0.1), b = step_at(id, 0.2);
  a["id"] = 1;
  b["id"] = 2;
  c.send(a);
  c.send(b);
  c.send({{"op", "plan.session.close"}, {"id", 3}, {"session", id}});
  c.send({{"op", "plan.session.step"}, {"id", 4}, {"session", id}, {"time", 0.3}});
  std::vector<int> order;
  std::vector<std::string> codes;
  for (int i = 0; i < 4; ++i) {
    const p::Message m = c.receive();
    order.push_back(m.header["id"].get<int>());
    codes.push_back(error_code(m));
  }
  EXPECT_EQ(order, (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(codes, (std::vector<std::string>{"", "", "", "bad_request"}));

  const std::string next = c.call_ok(open_from(reference))["session"];
  for (const json& state : {json{{"base", {{"position", "up"}}}}, json{{"feet", {{"XX", {}}}}},
                            json{{"base", {{"position", {0, 0}}}}}, json("state")}) {
    json step = step_at(next, 0.1);
    step["start_state"] = state;
    const p::Message stepped = c.call(step);
    const json replan = {{"op", "plan"},         {"terrain", "flat"},  {"init", reference},
                         {"start_time", 0.1},     {"start_state", state}};
    const p::Message planned = c.call(replan);
    EXPECT_EQ(error_code(stepped), "bad_request") << state.dump() << " " << error_message(stepped);
    EXPECT_EQ(error_code(planned), "bad_request") << state.dump() << " " << error_message(planned);
    EXPECT_NE(error_message(stepped).find("start_state"), std::string::npos)
        << error_message(stepped);
  }
  EXPECT_EQ(c.call_ok(step_at(next, 0.1))["solver"]["status"], "optimal");  // still usable
}

// A plan the server wrote is accepted back: 6 s at 1 ms samples is some 10 MB of JSON, beyond the
// old 4 MiB header cap, sent back to check, as plan's init and as a session's reference.
TEST_F(ServerFaults, PlansTheServerWroteAreAcceptedBack) {
  start();
  Client c = connect_client(address_, 2 * kReplyTimeout);
  json request = flat_plan("baseline", "json");
  request["duration"] = 6.0;
  request["sample_dt"] = 0.001;
  const json plan = c.call_ok(request);
  EXPECT_GT(plan.dump().size(), std::size_t{4} << 20);
  EXPECT_TRUE(c.call_ok({{"op", "check"}, {"plan", plan}, {"terrain", "flat"}})["checks"].is_object());
  const p::Message replanned = c.call({{"op", "plan"},
                                        {"terrain", "flat"},
                                        {"init", plan},
                                        {"start_time", 0.5},
                                        {"samples", "attachment"}});
  EXPECT_EQ(error_code(replanned), "") << error_message(replanned);
  const json opened = c.call_ok(open_from(plan));
  EXPECT_EQ(opened["samples"].size(), plan["samples"].size());
}

// A frame prefix announcing `body_bytes`, followed by `have` bytes of it (a frame that stalls).
std::string half_frame(std::uint32_t body_bytes, std::size_t have) {
  std::string f(4, '\0');
  p::write_u32be(body_bytes, reinterpret_cast<unsigned char*>(&f[0]));
  return f + std::string(have, ' ');
}

// Polls status (bounded) until `done(status)`; returns the last status.
json wait_for_status(Client& monitor, const std::function<bool(const json&)>& done) {
  json st;
  for (int i = 0; i < 2000; ++i) {
    st = monitor.call_ok({{"op", "status"}});
    if (done(st)) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return st;
}

// Nothing held for clients any more: only the monitor connected, no request bytes, no unsent
// replies, no work, no session.
bool quiet(const json& st) {
  return st["connections"]["open"] == 1 && st["memory"]["buffered_request_bytes"] == 0 &&
         st["memory"]["unsent_reply_bytes"] == 0 && st["queue"]["running"] == 0 &&
         st["queue"]["length"] == 0;
}

// Quiet, and the heap's free pages returned after the last work (a second after it): resident
// memory is then what the server holds, not what glibc's arenas kept of the burst.
bool settled(const json& st) { return quiet(st) && st["memory"]["free_heap_returned"] == true; }

// Clients that ask for 12 MiB replies and never read them, 3 connections x 2 requests.
void non_readers(const std::string& address, Client& monitor) {
  const std::uint64_t drops_before =
      monitor.call_ok({{"op", "status"}})["connections"]["unsent_drops"];
  std::vector<Client> silent;
  for (int i = 0; i < 3; ++i) {
    silent.push_back(Client::connect(address));
    for (int k = 0; k < 2; ++k)
      silent.back().send({{"op", "debug.sleep"}, {"ms", 0}, {"reply_bytes", 12 << 20}});
  }
  const json st = wait_for_status(monitor, [&](const json& s) {
    return s["queue"]["running"] == 0 && s["queue"]["length"] == 0 &&
           s["connections"]["unsent_drops"].get<std::uint64_t>() > drops_before;
  });
  EXPECT_GT(st["connections"]["unsent_drops"].get<std::uint64_t>(), drops_before) << st.dump();
  EXPECT_LE(st["memory"]["unsent_reply_bytes"].get<std::size_t>(), std::size_t{32} << 20);
}

// Frames of 60 MiB that stop after 24 MiB: closed after the frame timeout, memory released.
void stalled_frames(const std::string& address) {
  std::vector<Client> stalled;
  for (int i = 0; i < 4; ++i) {
    stalled.push_back(Client::connect(address, 20.0));
    stalled.back().send_raw(half_frame(60u << 20, 24u << 20));
  }
  for (auto& c : stalled) {
    const p::Message m = c.receive();
    EXPECT_EQ(error_code(m), "timeout") << m.header.dump();
  }
}

// More idle connections than --max-connections (16): the longest idle make room.
void slot_hogs(const std::string& address, Client& monitor) {
  std::vector<Client> hogs;
  for (int i = 0; i < 20; ++i) {
    hogs.push_back(Client::connect(address));
    hogs.back().call({{"op", "status"}});
    monitor.call_ok({{"op", "status"}});  // the monitor is never the longest idle
  }
  const json st = monitor.call_ok({{"op", "status"}});
  EXPECT_LE(st["connections"]["open"].get<int>(), 16);
  EXPECT_GE(st["connections"]["evicted"].get<int>(), 4);
}

// The attacks a hostile or careless client can make, repeated: clients that never read their
// replies, stalled huge frames, connection and session hogs. The server serves a well-behaved
// client meanwhile, holds nothing afterwards, logs why it dropped the non-readers, and its
// resident memory returns to its idle figure.
TEST_F(ServerFaults, SoakOfHogsAndNonReadersLeavesTheServerAsIdle) {
  start({"--debug-ops", "--frame-timeout", "1", "--max-connections", "16", "--max-unsent-bytes",
         std::to_string(32 << 20)});
  const json reference = flat_reference(address_);
  Client monitor = connect_client(address_);
  auto round = [&] {
    non_readers(address_, monitor);
    stalled_frames(address_);
    slot_hogs(address_, monitor);
    {
      Client sessions = connect_client(address_);
      for (int i = 0; i < 8; ++i) sessions.call_ok(open_from(reference));
    }
    EXPECT_EQ(monitor.call_ok({{"op", "map.query"}, {"points", {{1.0, 0.0}}}})["results"].size(),
              1u);
    const json st = wait_for_status(monitor, settled);
    EXPECT_TRUE(settled(st)) << st.dump();
    return st["memory"];
  };
  {
    Client warm = connect_client(address_);  // a session's code paths, as a round has
    warm.call_ok(open_from(reference));
  }
  const json idle = wait_for_status(monitor, settled)["memory"];
  const auto mib = [](const json& bytes) { return bytes.get<double>() / (1 << 20); };
  json last = idle;
  for (int i = 0; i < 3; ++i) {
    last = round();
    std::fprintf(stderr, "soak: after round %d: heap in use %.1f MiB, rss %.1f MiB\n", i + 1,
                 mib(last["heap_in_use_bytes"]), mib(last["rss_bytes"]));
  }
  const json st = monitor.call_ok({{"op", "status"}});
  EXPECT_EQ(monitor.call_ok({{"op", "plan.session.status"}})["open"], 0);
  // Held: what the allocator has in use returns to its idle figure (a leak of a reply, a frame
  // or a session per round would add 12-60 MiB). Resident: within what glibc keeps at the top of
  // the worker threads' arenas (about twice the 12 MiB replies each), trimmed otherwise.
  // Not under AddressSanitizer: its quarantine keeps freed memory resident and mallinfo2 reads 0
  // (support/sanitizer.hpp); its leak check covers what the server holds at exit.
  if (!kAddressSanitizer) {
    EXPECT_LT(mib(last["heap_in_use_bytes"]), mib(idle["heap_in_use_bytes"]) + 4.0) << last.dump();
    EXPECT_LT(mib(last["rss_bytes"]), mib(idle["rss_bytes"]) + 64.0) << last.dump();
  }
  std::fprintf(stderr,
               "soak: heap in use idle %.1f MiB, after %.1f MiB; rss idle %.1f MiB, after %.1f MiB;"
               " evicted %d, unsent drops %d\n",
               mib(idle["heap_in_use_bytes"]), mib(last["heap_in_use_bytes"]),
               mib(idle["rss_bytes"]), mib(last["rss_bytes"]),
               st["connections"]["evicted"].get<int>(), st["connections"]["unsent_drops"].get<int>());
  ASSERT_EQ(server_->stop(SIGTERM), 0);
  EXPECT_NE(server_->output.find("dropped: "), std::string::npos) << server_->output;
  EXPECT_NE(server_->output.find("(--max-unsent-bytes)"), std::string::npos);
  server_.reset();
}

}  // namespace
