// The server in-process (so the sanitizer build covers the transport): operations, pipelining,
// cancel, busy, deadlines, malformed and oversized frames, and a graceful shutdown with replies.
#include <gtest/gtest.h>

#include <thread>

#include "terrastride/service/client.hpp"
#include "terrastride/service/server.hpp"

namespace {

using nlohmann::json;
using namespace terrastride::service;
namespace p = terrastride::service::protocol;

std::string code_of(const p::Message& m) {
  return m.header.value("ok", true) ? "" : m.header["error"].value("code", "");
}

struct InProcessServer {
  InProcessServer(int workers, int queue) {
    ServerOptions so;
    so.listen = {"tcp://127.0.0.1:0"};
    so.workers = workers;
    so.queue = queue;
    so.max_frame_bytes = 1 << 20;
    so.handle_signals = false;
    so.drain_seconds = 0.2;
    OperationRegistry reg;
    backend = make_backend({"hyq", /*debug_ops=*/true}, reg);
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

}  // namespace
