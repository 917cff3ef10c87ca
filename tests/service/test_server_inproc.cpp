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
