// The server in-process (so the sanitizer build covers the transport): operations, pipelining,
// cancel, busy, deadlines, malformed and oversized frames, the limits against clients that hold
// memory or connections (frame and idle timeouts, the connection limit and the eviction of the
// longest idle connection, the pre-hello frame cap, the request-byte budgets, the per-connection
// quotas, unsent replies and clients that take none), and a graceful shutdown with replies.
#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <functional>
#include <thread>

#include "terrastride/service/client.hpp"
#include "terrastride/service/server.hpp"
#include "backend.hpp"

namespace {

using nlohmann::json;
using namespace terrastride::service;
namespace p = terrastride::service::protocol;

std::string code_of(const p::Message& m) {
  return m.header.value("ok", true) ? "" : m.header["error"].value("code", "");
}

struct InProcessServer {
  InProcessServer(int workers, int queue, const std::function<void(ServerOptions&)>& tweak = {}) {
    ServerOptions so;
    so.listen = {"tcp://127.0.0.1:0"};
    so.workers = workers;
    so.queue = queue;
    so.max_frame_bytes = 1 << 20;
    so.handle_signals = false;
    so.drain_seconds = 0.2;
    if (tweak) tweak(so);
    OperationRegistry reg;
    BackendOptions bo;
    bo.debug_ops = true;
    backend = make_backend(bo, reg);
    auto b = backend;
    server = std::make_unique<Server>(
        so, std::move(reg), [b] { return backend_status(*b); }, [b] { return backend_hello(*b); });
    address = server->bind().front();
    thread = std::thread([this] { server->run(); });
  }
  ~InProcessServer() {
    server->shutdown();
    thread.join();
  }
  std::shared_ptr<Backend> backend;
  std::unique_ptr<Server> server;
  std::string address;
  std::thread thread;
};

// A frame prefix announcing `body_bytes`, followed by `have` bytes of it (a half-sent frame).
std::string half_frame(std::uint32_t body_bytes, std::size_t have) {
  std::string f(4, '\0');
  p::write_u32be(body_bytes, reinterpret_cast<unsigned char*>(&f[0]));
  return f + std::string(have, ' ');
}

// A frame with this header text (valid JSON or not) and raw tail bytes.
std::string raw_frame(const std::string& header_text, const std::string& tail = "") {
  std::string b(8, '\0');
  p::write_u32be(static_cast<std::uint32_t>(4 + header_text.size() + tail.size()),
                 reinterpret_cast<unsigned char*>(&b[0]));
  p::write_u32be(static_cast<std::uint32_t>(header_text.size()),
                 reinterpret_cast<unsigned char*>(&b[4]));
  return b + header_text + tail;
}

// The reply a closing server sends, then the end of the stream: a clean close (FIN after the
// reply), not a reset.
void expect_error_then_close(Client& c, const std::string& code, const std::string& says = "") {
  p::Message m;
  try {
    m = c.receive();
  } catch (const ClientError& e) {
    ADD_FAILURE() << "expected a " << code << " reply, got: " << e.what();
    return;
  }
  EXPECT_EQ(code_of(m), code) << m.header.dump();
  EXPECT_TRUE(m.header["id"].is_null()) << m.header.dump();
  if (!says.empty()) {
    EXPECT_NE(m.header["error"].value("message", "").find(says), std::string::npos)
        << m.header.dump();
  }
  try {
    c.receive();
    ADD_FAILURE() << "connection still open";
  } catch (const ClientError& e) {
    EXPECT_STREQ(e.what(), "connection closed by the server");
  }
}

TEST(ServerInProcess, OperationsPipeliningAndErrors) {
  InProcessServer s(2, 2);
  Client c = Client::connect(s.address);
  EXPECT_EQ(c.call_ok({{"op", "hello"}})["protocol"], 1);
  c.call_ok({{"op", "map.update"}, {"scene", "pallet_15"}});
  for (int i = 0; i < 50; ++i)
    c.send({{"op", "map.query"}, {"id", i}, {"points", {{1.0, 0.01 * i}}}});
  for (int i = 0; i < 50; ++i) {
    const p::Message m = c.receive();
    EXPECT_EQ(m.header["id"], i);
    EXPECT_DOUBLE_EQ(m.header["result"]["results"][0]["height"].get<double>(), 0.15);
  }
  EXPECT_EQ(code_of(c.call({{"op", "nope"}})), "unknown_op");
  EXPECT_EQ(code_of(c.call({{"op", "map.query"}, {"points", "x"}})), "bad_request");
  // Malformed frame with intact framing, then a valid request on the same connection.
  std::string junk(8, '\0');
  p::write_u32be(7, reinterpret_cast<unsigned char*>(&junk[0]));
  p::write_u32be(3, reinterpret_cast<unsigned char*>(&junk[4]));
  c.send_raw(junk + "{{{");
  EXPECT_EQ(code_of(c.receive()), "bad_json");
  EXPECT_TRUE(c.call_ok({{"op", "status"}}).contains("uptime_s"));
  // Oversized prefix closes only that connection.
  Client big = Client::connect(s.address);
  big.send_raw(std::string("\x01\x00\x00\x00", 4));
  EXPECT_EQ(code_of(big.receive()), "frame_too_large");
  EXPECT_THROW(big.receive(), ClientError);
  EXPECT_TRUE(c.call_ok({{"op", "status"}})["requests"]["malformed_frames"].get<int>() >= 2);
  // A large frame arriving in pieces (several reads and buffer growth).
  std::vector<float> xy(2 * 9000, 0.5f);
  const json r =
      c.call_ok({{"op", "map.query"}}, {p::make_float_attachment("points", {9000, 2}, xy)});
  EXPECT_EQ(r["results"].size(), 9000u);
}

// Operations declare the fields they read (Operation::fields); anything else is refused, with a
// suggestion when a known field is close. Built-in operations declare theirs too.
TEST(ServerInProcess, UnknownFieldsAreRefused) {
  InProcessServer s(1, 1);
  Client c = Client::connect(s.address);
  auto message = [](const p::Message& m) {
    return code_of(m) + ": " + m.header["error"].value("message", "");
  };
  EXPECT_EQ(message(c.call({{"op", "status"}, {"verbose", true}})),
            "bad_request: unknown field \"verbose\" for op status (it takes no fields besides v, "
            "id, op, deadline_ms, attachments)");
  EXPECT_EQ(message(c.call({{"op", "cancel"}, {"targte", 1}})),
            "bad_request: unknown field \"targte\" for op cancel (did you mean \"target\"?)");
  EXPECT_EQ(message(c.call({{"op", "hello"}, {"tokn", "x"}})),
            "bad_request: unknown field \"tokn\" for op hello (did you mean \"token\"?)");
  c.call_ok({{"op", "status"}, {"deadline_ms", 1000}});
  c.call_ok({{"op", "cancel"}, {"target", 5}});
}

// The socket's terrain names are the CLI's (terrain::is_scene_name): a pallet_NN scene plans,
// opens a session and simulates as an exact scene. Before, plan, plan.session.open and simulate
// knew only scene_names() and took "pallet_12" for a terrain directory ("this server reads no
// terrain directories").
TEST(ServerInProcess, PalletOfAnyHeightIsASceneForEveryOperation) {
  InProcessServer s(1, 2);
  Client c = Client::connect(s.address);
  // A short crawl that stays before the box (its edge at x = 0.55, HyQ's front feet at 0.41).
  const json request = {{"terrain", "pallet_12"},
                        {"duration", 2.4},
                        {"goal", {0.1, 0.0, 0.0}},
                        {"constraints", "baseline"}};
  json plan_request = request;
  plan_request["op"] = "plan";
  const p::Message planned = c.call(plan_request);
  ASSERT_EQ(code_of(planned), "") << planned.header.dump();
  const json plan = planned.header["result"];
  EXPECT_EQ(plan["solver"]["status"], "optimal");
  json open = request;
  open["op"] = "plan.session.open";
  const p::Message opened = c.call(open);
  ASSERT_EQ(code_of(opened), "") << opened.header.dump();
  c.call_ok({{"op", "plan.session.close"}, {"session", opened.header["result"]["session"]}});
  const p::Message simulated = c.call({{"op", "simulate"}, {"plan", plan}, {"terrain", "pallet_12"}});
  ASSERT_EQ(code_of(simulated), "") << simulated.header.dump();
  EXPECT_EQ(simulated.header["result"]["terrain"].get<std::string>().rfind("scene pallet_12 (", 0),
            0u)
      << simulated.header["result"]["terrain"];
  // A name no resolver knows is still refused naming the scenes (pallet_NN among them).
  const p::Message bad = c.call({{"op", "plan"}, {"terrain", "pallet_61"}});
  EXPECT_EQ(code_of(bad), "bad_request");
  const p::Message bad_check = c.call({{"op", "check"}, {"plan", plan}, {"terrain", "pallet_61"}});
  EXPECT_EQ(code_of(bad_check), "bad_request");
  EXPECT_NE(bad_check.header["error"].value("message", "").find("pallet_NN"), std::string::npos)
      << bad_check.header.dump();
}

TEST(ServerInProcess, SceneRasterCacheKeepsTheMostRecentlyUsed) {
  InProcessServer s(1, 2);
  Backend& b = *s.backend;
  const auto first = b.scene_raster("pallet_1");
  EXPECT_EQ(b.scene_raster("pallet_1"), first);  // a hit is the same raster
  // Four more scene names than the cache holds, pallet_1 used again when it is full: it stays,
  // the least recently used ones (pallet_2 first) go.
  std::shared_ptr<const SceneRaster> second;
  for (int cm = 2; cm <= static_cast<int>(kSceneRasterCacheEntries) + 4; ++cm) {
    const auto r = b.scene_raster("pallet_" + std::to_string(cm));
    if (cm == 2) second = r;
    if (cm == static_cast<int>(kSceneRasterCacheEntries)) b.scene_raster("pallet_1");
    EXPECT_LE(b.cached_scene_rasters(), kSceneRasterCacheEntries);
  }
  EXPECT_EQ(b.cached_scene_rasters(), kSceneRasterCacheEntries);
  EXPECT_EQ(b.scene_raster("pallet_1"), first);
  // pallet_2 was evicted and is built anew; the reference held to the old one stays valid.
  const auto rebuilt = b.scene_raster("pallet_2");
  EXPECT_NE(rebuilt, second);
  EXPECT_NEAR(second->smooth->height(1.1, 0.0), 0.02, 1e-4);
  EXPECT_NEAR(rebuilt->smooth->height(1.1, 0.0), 0.02, 1e-4);
  Client c = Client::connect(s.address);
  const json rasters = c.call_ok({{"op", "status"}})["scene_rasters"];
  EXPECT_EQ(rasters["cached"], kSceneRasterCacheEntries) << rasters;
  EXPECT_EQ(rasters["capacity"], kSceneRasterCacheEntries) << rasters;
}

TEST(ServerInProcess, RegisteredOperationsDeclareTheirFields) {
  ServerOptions so;
  so.handle_signals = false;
  OperationRegistry reg;
  auto echo = [](OpContext& ctx) {
    OpResult r;
    r.result = {{"got", ctx.request.header.value("optimize_timing", false)}};
    return r;
  };
  reg.add({"echo", OpKind::kInline, "test", echo, std::vector<std::string>{"optimize_timing"}});
  reg.add({"loose", OpKind::kWorker, "test: fields unchecked", echo});
  Server server(so, std::move(reg));
  const std::string address = server.bind().front();
  std::thread t([&] { server.run(); });
  {
    Client c = Client::connect(address);
    EXPECT_EQ(c.call_ok({{"op", "echo"}, {"optimize_timing", true}})["got"], true);
    const p::Message m = c.call({{"op", "echo"}, {"optimise_timing", true}});
    EXPECT_EQ(code_of(m), "bad_request");
    EXPECT_EQ(m.header["error"]["message"],
              "unknown field \"optimise_timing\" for op echo (did you mean \"optimize_timing\"?)");
    EXPECT_EQ(c.call_ok({{"op", "loose"}, {"anything", 1}})["got"], false);
  }
  server.shutdown();
  t.join();
}

TEST(ServerInProcess, CancelBusyDeadline) {
  InProcessServer s(1, 1);
  Client c = Client::connect(s.address);
  c.send({{"op", "debug.sleep"}, {"id", 1}, {"ms", 20000}});
  c.send({{"op", "debug.sleep"}, {"id", 2}, {"ms", 20000}});
  EXPECT_EQ(code_of(c.call({{"op", "debug.sleep"}, {"ms", 1}})), "busy");
  c.call_ok({{"op", "cancel"}, {"target", 2}});
  EXPECT_EQ(code_of(c.wait_for(2)), "cancelled");
  c.call_ok({{"op", "cancel"}, {"target", 1}});
  EXPECT_EQ(code_of(c.wait_for(1)), "cancelled");
  EXPECT_EQ(code_of(c.call({{"op", "debug.sleep"}, {"ms", 20000}, {"deadline_ms", 30}})),
            "deadline_exceeded");
}

TEST(ServerInProcess, ShutdownAnswersRunningWork) {
  auto s = std::make_unique<InProcessServer>(1, 1);
  Client c = Client::connect(s->address);
  c.send({{"op", "debug.sleep"}, {"id", 1}, {"ms", 20000}});
  c.call_ok({{"op", "status"}});
  std::thread stopper([&] { s.reset(); });  // shutdown: 0.2 s drain, then cancelled with a reply
  EXPECT_EQ(code_of(c.wait_for(1)), "shutting_down");
  stopper.join();
}

// A frame that stops half-way is answered `timeout` and closed once its allowance (frame timeout
// plus its received bytes at the minimum rate) is over; its buffer is given back, and others are
// served meanwhile.
TEST(ServerInProcess, HalfSentFrameIsClosedAfterTheFrameTimeout) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.frame_timeout_s = 0.3;
    o.min_receive_rate = 100e6;
  });
  Client other = Client::connect(s.address);
  Client slow = Client::connect(s.address);
  slow.set_timeout(10);
  slow.send_raw(half_frame(900000, 300000));  // beyond the 64 KiB connection buffer
  for (int i = 0; i < 500; ++i) {
    if (other.call_ok({{"op", "status"}})["memory"]["buffered_request_bytes"] >= 300004) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  EXPECT_EQ(other.call_ok({{"op", "status"}})["memory"]["buffered_request_bytes"], 300004);
  // A small frame that stalls inside its header is cut off as well.
  Client header = Client::connect(s.address);
  header.set_timeout(10);
  header.send_raw(half_frame(200, 10));
  expect_error_then_close(slow, "timeout", "300004 of 900004 bytes received");
  expect_error_then_close(header, "timeout", "14 of 204 bytes received");
  const json st = other.call_ok({{"op", "status"}});
  EXPECT_EQ(st["memory"]["buffered_request_bytes"], 0);
  EXPECT_EQ(st["connections"]["frame_timeouts"], 2);
  // A complete request with a pause shorter than the timeout is not affected.
  const std::string f = p::encode_frame(p::Message{{{"v", 1}, {"id", 1}, {"op", "status"}}, {}});
  other.send_raw(f.substr(0, 5));
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  other.send_raw(f.substr(5));
  EXPECT_EQ(code_of(other.receive()), "");
}

// A connection with nothing in flight is closed after the idle timeout (with a `timeout` reply);
// one with a job running is not idle.
// --realtime-io: the I/O thread runs at SCHED_FIFO where the process may, and status says
// whether it does (a robot's operator must know); without the flag it never does.
TEST(ServerInProcess, RealtimeIoIsReportedAsItTookEffect) {
  bool permitted = false;
  std::thread probe([&permitted] {
    sched_param rt{};
    rt.sched_priority = 1;
    permitted = pthread_setschedparam(pthread_self(), SCHED_FIFO, &rt) == 0;
  });
  probe.join();
  {
    InProcessServer s(1, 1, [](ServerOptions& o) { o.realtime_io = true; });
    Client c = Client::connect(s.address);
    EXPECT_EQ(c.call_ok({{"op", "status"}})["realtime_io"].get<bool>(), permitted);
    if (permitted) {
      // The I/O thread's policy as the kernel has it.
      int policy = 0;
      sched_param param{};
      ASSERT_EQ(pthread_getschedparam(s.thread.native_handle(), &policy, &param), 0);
      EXPECT_EQ(policy, SCHED_FIFO);
    }
  }
  InProcessServer plain(1, 1);
  Client c = Client::connect(plain.address);
  EXPECT_FALSE(c.call_ok({{"op", "status"}})["realtime_io"].get<bool>());
  int policy = 0;
  sched_param param{};
  ASSERT_EQ(pthread_getschedparam(plain.thread.native_handle(), &policy, &param), 0);
  EXPECT_EQ(policy, SCHED_OTHER);
}

TEST(ServerInProcess, IdleConnectionIsClosed) {
  InProcessServer s(1, 1, [](ServerOptions& o) { o.idle_timeout_s = 0.3; });
  Client idle = Client::connect(s.address);
  idle.set_timeout(10);
  idle.call_ok({{"op", "hello"}});
  Client working = Client::connect(s.address);
  working.send({{"op", "debug.sleep"}, {"id", 1}, {"ms", 600}});
  expect_error_then_close(idle, "timeout", "idle");
  EXPECT_EQ(code_of(working.wait_for(1)), "");  // 0.6 s running: not idle meanwhile
  EXPECT_EQ(working.call_ok({{"op", "status"}})["connections"]["idle_timeouts"], 1);
}

// At the connection limit a new client is told `busy` (id null) and the connection is closed
// cleanly, not reset; once the idle ones time out it gets in.
// A full server makes room for a new client by closing the connection idle longest (connections
// that only keep themselves alive cannot keep new clients out); with every connection busy (a
// frame arriving), a new client gets `busy` and is closed.
TEST(ServerInProcess, ConnectionLimitEvictsTheLongestIdleOrAnswersBusy) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.max_connections = 3;
    o.idle_timeout_s = 60;
    o.frame_timeout_s = 60;
  });
  std::vector<Client> idle;
  for (int i = 0; i < 3; ++i) {
    idle.push_back(Client::connect(s.address));
    idle.back().call_ok({{"op", "status"}});  // adopted, in this order of activity
  }
  idle[1].call_ok({{"op", "status"}});
  idle[0].call_ok({{"op", "status"}});  // idle[2] is now the longest idle
  Client late = Client::connect(s.address);
  late.set_timeout(10);
  EXPECT_EQ(late.call_ok({{"op", "hello"}})["protocol"], 1);
  idle[2].set_timeout(10);
  expect_error_then_close(idle[2], "busy", "idle longest");
  idle[0].call_ok({{"op", "status"}});
  idle[1].call_ok({{"op", "status"}});

  // Every connection busy (each has a frame arriving): the next one is refused.
  idle[0].send_raw(half_frame(1000, 10));
  idle[1].send_raw(half_frame(1000, 10));
  late.send_raw(half_frame(1000, 10));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  Client refused = Client::connect(s.address);
  refused.set_timeout(10);
  // Requests the server never reads: its close must still not be a reset (a reset can destroy
  // the reply before the client reads it, and fails the client's next send).
  refused.send({{"op", "hello"}});
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  refused.send({{"op", "status"}});
  expect_error_then_close(refused, "busy", "connection limit of 3");
  idle.clear();
  { Client gone = std::move(late); }
  json st;
  for (int i = 0; i < 500; ++i) {  // the closed clients' slots come back
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    Client again = Client::connect(s.address);
    p::Message m;
    try {
      m = again.call({{"op", "status"}});
    } catch (const ClientError&) {
      continue;  // refused while the server had not yet seen the others leave
    }
    if (!code_of(m).empty()) continue;
    st = m.header["result"];
    if (st["connections"]["open"] == 1) break;
  }
  EXPECT_GE(st["connections"]["rejected"], 1);
  EXPECT_EQ(st["connections"]["evicted"], 1);
  EXPECT_EQ(st["connections"]["open"], 1);
}

// Before hello on a token server frames are capped small; after it the normal cap applies. Any
// refusal before hello (here unsupported_version) ends the connection like unauthorized does.
TEST(ServerInProcess, TokenServerCapsFramesBeforeHello) {
  const std::string token = "0123456789abcdef-token";
  InProcessServer s(1, 1, [&](ServerOptions& o) {
    o.token = token;
    o.max_frame_bytes_before_hello = 64 << 10;
  });
  {
    Client c = Client::connect(s.address);
    c.set_timeout(10);
    c.send_raw(half_frame(100000, 0));
    expect_error_then_close(c, "frame_too_large", "before hello");
  }
  {
    Client c = Client::connect(s.address);
    c.set_timeout(10);
    c.send_raw(
        p::encode_frame(p::Message{{{"v", 2}, {"id", 1}, {"op", "hello"}, {"token", token}}, {}}));
    const p::Message m = c.receive();
    EXPECT_EQ(code_of(m), "unsupported_version");
    EXPECT_THROW(c.receive(), ClientError);  // closed
  }
  {
    Client c = Client::connect(s.address);
    c.set_timeout(10);
    c.send_raw(raw_frame("{oops"));  // intact framing, not JSON
    EXPECT_EQ(code_of(c.receive()), "bad_json");
    EXPECT_THROW(c.receive(), ClientError);
  }
  Client c = Client::connect(s.address);
  c.call_ok({{"op", "hello"}, {"token", token}});
  c.call_ok({{"op", "map.update"}, {"scene", "flat"}});
  std::vector<float> xy(2 * 9000, 0.5f);  // 72 kB: above the pre-hello cap
  EXPECT_EQ(c.call_ok({{"op", "map.query"}},
                      {p::make_float_attachment("points", {9000, 2}, xy)})["results"]
                .size(),
            9000u);
}

// The request-byte budget across connections: a large frame that does not fit in what is left
// gets `busy` and its connection is closed; once the bytes are consumed, it fits again.
TEST(ServerInProcess, BufferedBytesBudget) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.max_buffered_bytes = 1 << 20;
    o.frame_timeout_s = 30;
  });
  Client monitor = Client::connect(s.address);
  // A: a debug.sleep request carrying 700 kB of padding, sent all but its last byte.
  std::vector<float> pad(175000, 1.0f);
  const std::string full =
      p::encode_frame(p::Message{{{"v", 1}, {"id", 1}, {"op", "debug.sleep"}, {"ms", 0}},
                                 {p::make_float_attachment("pad", {175000}, pad)}});
  Client a = Client::connect(s.address);
  a.send_raw(full.substr(0, full.size() - 1));
  for (int i = 0; i < 500; ++i) {
    if (monitor.call_ok({{"op", "status"}})["memory"]["buffered_request_bytes"] >= 700000) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  // B: 600 kB more would exceed the 1 MiB budget.
  Client b = Client::connect(s.address);
  b.set_timeout(10);
  b.send_raw(half_frame(600000, 1000));
  expect_error_then_close(b, "busy", "--max-buffered-bytes");
  // A finishes and is served; then the same large frame fits.
  a.send_raw(full.substr(full.size() - 1));
  EXPECT_EQ(code_of(a.receive()), "");
  for (int i = 0; i < 500; ++i) {
    if (monitor.call_ok({{"op", "status"}})["memory"]["buffered_request_bytes"] == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  Client c = Client::connect(s.address);
  c.send_raw(full);
  EXPECT_EQ(code_of(c.receive()), "");
  const json st = monitor.call_ok({{"op", "status"}});
  EXPECT_EQ(st["memory"]["refused_frames"], 1);
  EXPECT_EQ(st["memory"]["max_buffered_bytes"], 1 << 20);
}

// Huge deadlines mean "no deadline" (1e13 ms used to overflow the clock and expire at once);
// negative ones are refused naming the field.
TEST(ServerInProcess, HugeDeadlinesDoNotExpire) {
  InProcessServer s(1, 1);
  Client c = Client::connect(s.address);
  c.call_ok({{"op", "map.update"}, {"scene", "flat"}});
  for (double d : {1e10, 1e13, 1e300}) {
    EXPECT_EQ(code_of(c.call({{"op", "debug.sleep"}, {"ms", 20}, {"deadline_ms", d}})), "") << d;
    EXPECT_EQ(code_of(c.call({{"op", "map.query"}, {"points", {{0, 0}}}, {"deadline_ms", d}})), "")
        << d;
  }
  const p::Message m = c.call({{"op", "status"}, {"deadline_ms", -1}});
  EXPECT_EQ(code_of(m), "bad_request");
  EXPECT_NE(m.header["error"]["message"].get<std::string>().find("deadline_ms"), std::string::npos);
}

TEST(ServerInProcess, DuplicateAttachmentNamesAreRefused) {
  InProcessServer s(1, 1);
  Client c = Client::connect(s.address);
  c.call_ok({{"op", "map.update"}, {"scene", "flat"}});
  const p::Message m = c.call({{"op", "map.query"}, {"id", 9}},
                              {p::make_float_attachment("points", {1, 2}, {0, 0}),
                               p::make_float_attachment("points", {1, 2}, {5, 5})});
  EXPECT_EQ(code_of(m), "bad_request");
  EXPECT_EQ(m.header["id"], 9);
  EXPECT_NE(m.header["error"]["message"].get<std::string>().find("duplicate name \"points\""),
            std::string::npos)
      << m.header.dump();
  EXPECT_EQ(c.call_ok({{"op", "map.query"}},
                      {p::make_float_attachment("points", {1, 2}, {0, 0})})["results"]
                .size(),
            1u);
}

// While draining, status still answers and shows it; other requests are refused.
TEST(ServerInProcess, StatusWhileDrainingShowsDraining) {
  auto s = std::make_unique<InProcessServer>(1, 1, [](ServerOptions& o) { o.drain_seconds = 5; });
  Client c = Client::connect(s->address);
  c.send({{"op", "debug.sleep"}, {"id", 1}, {"ms", 800}});
  // Running, not queued (queued work is answered shutting_down at once).
  for (int i = 0; i < 500 && c.call_ok({{"op", "status"}})["queue"]["running"] != 1; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  s->server->shutdown();
  json st;
  for (int i = 0; i < 500; ++i) {
    const p::Message m = c.call({{"op", "status"}});
    ASSERT_EQ(code_of(m), "") << m.header.dump();
    st = m.header["result"];
    if (st["draining"] == true) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  EXPECT_EQ(st["draining"], true);
  EXPECT_EQ(code_of(c.call({{"op", "map.query"}, {"points", {{0, 0}}}})), "shutting_down");
  EXPECT_EQ(code_of(c.wait_for(1)), "");  // the running job drains
  s.reset();
}

}  // namespace

// Attachments an operation does not read are refused naming them, rather than silently ignored
// (a cloud sent as "pointz" would otherwise be a map.update without points).
TEST(ServerInProcess, UnknownAttachmentNamesAreRefused) {
  InProcessServer s(1, 1);
  Client c = Client::connect(s.address);
  c.call_ok({{"op", "map.update"}, {"scene", "flat"}});
  const std::vector<float> xy{0.5f, 0.5f};
  p::Message m = c.call({{"op", "map.query"}, {"points", {{0.5, 0.5}}}},
                        {p::make_float_attachment("pointz", {1, 2}, xy)});
  EXPECT_EQ(code_of(m), "bad_request");
  EXPECT_EQ(m.header["error"].value("message", ""),
            "attachments[0]: unknown attachment \"pointz\" for op map.query (it takes: points)");
  m = c.call({{"op", "status"}}, {p::make_float_attachment("extra", {1, 2}, xy)});
  EXPECT_EQ(code_of(m), "bad_request");
  EXPECT_NE(m.header["error"].value("message", "").find("\"extra\" for op status (it takes none)"),
            std::string::npos)
      << m.header.dump();
  m = c.call({{"op", "map.update"}, {"mode", "replace"}},
             {p::make_float_attachment("points", {1, 3}, {0.f, 0.f, 0.f}),
              p::make_float_attachment("colours", {1, 3}, {0.f, 0.f, 0.f})});
  EXPECT_NE(m.header["error"].value("message", "").find("attachments[1]: unknown attachment "
                                                         "\"colours\" for op map.update"),
            std::string::npos)
      << m.header.dump();
  // The connection stays usable, and the named attachment works.
  EXPECT_EQ(c.call_ok({{"op", "map.query"}}, {p::make_float_attachment("points", {1, 2}, xy)})
                ["results"]
                    .size(),
            1u);
}

// A large frame that stops arriving is closed after --frame-timeout of silence, however many
// bytes came before it (at --min-receive-rate they would earn it minutes), and its memory is
// released.
TEST(ServerInProcess, StalledLargeFrameIsClosedAfterTheFrameTimeout) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.frame_timeout_s = 0.5;
    o.min_receive_rate = 1000;  // 800 kB received would allow 800 s more
    o.idle_timeout_s = 0;
  });
  Client monitor = Client::connect(s.address);
  Client c = Client::connect(s.address);
  c.set_timeout(20);
  c.send_raw(half_frame(900000, 800000));
  expect_error_then_close(c, "timeout", "none for the last");
  json st;
  for (int i = 0; i < 500; ++i) {
    st = monitor.call_ok({{"op", "status"}});
    if (st["memory"]["buffered_request_bytes"] == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  EXPECT_EQ(st["memory"]["buffered_request_bytes"], 0);
  EXPECT_EQ(st["connections"]["frame_timeouts"], 1);
}

// One connection's request bytes (its frame arriving, its requests waiting) are capped below the
// server's budget: it cannot take all of it, and other clients' frames still fit.
TEST(ServerInProcess, RequestBytesPerConnection) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.max_buffered_bytes = 4 << 20;
    o.max_buffered_bytes_per_connection = 300000;
    o.frame_timeout_s = 30;
  });
  std::vector<float> pad(50000, 1.0f);  // 200 kB
  auto padded_sleep = [&](int id, double ms) {
    return p::encode_frame(p::Message{{{"v", 1}, {"id", id}, {"op", "debug.sleep"}, {"ms", ms}},
                                      {p::make_float_attachment("pad", {50000}, pad)}});
  };
  Client hog = Client::connect(s.address);
  hog.set_timeout(10);
  hog.send_raw(padded_sleep(1, 20000));  // held while it runs
  Client monitor = Client::connect(s.address);
  for (int i = 0; i < 500; ++i) {
    if (monitor.call_ok({{"op", "status"}})["queue"]["running"] == 1) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  hog.send_raw(padded_sleep(2, 0));  // 400 kB in all: beyond its 300 kB
  expect_error_then_close(hog, "busy", "--max-buffered-bytes-per-connection");
  Client other = Client::connect(s.address);
  other.send_raw(padded_sleep(3, 0));
  EXPECT_EQ(code_of(other.receive()), "");
}

// One connection cannot take the whole worker queue: beyond its quota of requests queued or
// running it gets `busy`, and another client's request still finds a place.
TEST(ServerInProcess, WorkerRequestsPerConnection) {
  InProcessServer s(1, 2, [](ServerOptions& o) { o.max_jobs_per_connection = 1; });
  Client hog = Client::connect(s.address);
  EXPECT_EQ(hog.call_ok({{"op", "hello"}})["capabilities"]["max_jobs_per_connection"], 1);
  hog.send({{"op", "debug.sleep"}, {"id", 1}, {"ms", 20000}});
  const p::Message m = hog.call({{"op", "debug.sleep"}, {"id", 2}, {"ms", 20000}});
  EXPECT_EQ(code_of(m), "busy");
  EXPECT_NE(m.header["error"].value("message", "").find("--max-jobs-per-connection"),
            std::string::npos)
      << m.header.dump();
  Client other = Client::connect(s.address);
  other.send({{"op", "debug.sleep"}, {"id", 3}, {"ms", 1}});
  hog.call_ok({{"op", "cancel"}, {"target", 1}});
  EXPECT_EQ(code_of(hog.wait_for(1)), "cancelled");
  EXPECT_EQ(code_of(other.wait_for(3)), "");
  // The cancelled request's place is free again.
  EXPECT_EQ(code_of(hog.call({{"op", "debug.sleep"}, {"id", 4}, {"ms", 1}})), "");
}

// Clients that ask for large replies and never read them: the unsent replies of all connections
// stay within --max-unsent-bytes (the connection holding the most, stalled ones first, is dropped:
// never the monitor, whose status replies are small), and
// a client that reads is served meanwhile.
TEST(ServerInProcess, UnsentRepliesAreBoundedAcrossConnections) {
  constexpr std::size_t kBudget = 32u << 20, kReply = 12u << 20;
  InProcessServer s(2, 8, [](ServerOptions& o) {
    o.max_unsent_bytes = kBudget;
    o.max_write_queue_bytes = 64u << 20;
  });
  std::vector<Client> silent;
  for (int i = 0; i < 3; ++i) {
    silent.push_back(Client::connect(s.address));
    for (int k = 0; k < 2; ++k)
      silent.back().send({{"op", "debug.sleep"}, {"ms", 0}, {"reply_bytes", kReply}});
  }
  Client monitor = Client::connect(s.address);
  json st;
  for (int i = 0; i < 1000; ++i) {
    st = monitor.call_ok({{"op", "status"}});
    if (st["queue"]["running"] == 0 && st["queue"]["length"] == 0 &&
        st["connections"]["unsent_drops"] >= 1)
      break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_GE(st["connections"]["unsent_drops"].get<int>(), 1) << st.dump();
  EXPECT_LE(st["memory"]["unsent_reply_bytes"].get<std::size_t>(), kBudget) << st.dump();
  EXPECT_EQ(st["memory"]["max_unsent_bytes"], kBudget);
  Client reader = Client::connect(s.address);
  const p::Message m = reader.call({{"op", "debug.sleep"}, {"ms", 0}, {"reply_bytes", 1 << 20}});
  EXPECT_EQ(code_of(m), "");
  ASSERT_EQ(m.attachments.size(), 1u);
  EXPECT_EQ(m.attachments[0].data.size(), 1u << 20);
}

// A client that takes none of its replies for --frame-timeout is dropped then, however large
// they are (at --min-receive-rate, 12 MiB would earn it hours), and their memory is released.
TEST(ServerInProcess, ClientThatTakesNoRepliesIsDroppedAfterTheFrameTimeout) {
  InProcessServer s(1, 1, [](ServerOptions& o) {
    o.frame_timeout_s = 0.5;
    o.min_receive_rate = 1000;
    o.idle_timeout_s = 0;
  });
  Client silent = Client::connect(s.address);
  silent.send({{"op", "debug.sleep"}, {"ms", 0}, {"reply_bytes", 12 << 20}});
  Client monitor = Client::connect(s.address);
  json st;
  for (int i = 0; i < 1000; ++i) {
    st = monitor.call_ok({{"op", "status"}});
    if (st["connections"]["write_timeouts"] == 1 && st["memory"]["unsent_reply_bytes"] == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(st["connections"]["write_timeouts"], 1) << st.dump();
  EXPECT_EQ(st["memory"]["unsent_reply_bytes"], 0) << st.dump();
  EXPECT_EQ(st["connections"]["open"], 1) << st.dump();
}
